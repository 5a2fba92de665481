r"""The expert: Lee/Mellinger geometric controller with a CTBR output (thesis §3.4.1).

Tracks a flat-output reference ``(p, v, a, j)(t)`` with yaw ``psi`` and returns the
simulator's action ``[c, wx, wy, wz]`` (docs/spec.md "Vehicle and simulator"). Batched over
N vehicles; float64 NumPy.

Equations (Lee, Leok & McClamroch, CDC 2010; Mellinger & Kumar, ICRA 2011):

* position loop (per-axis gains)::

      e_p = p - p_ref,  e_v = v - v_ref
      a_des = -k_p e_p - k_v e_v + a_ref + g e3           (F_des = m a_des)
      c     = a_des . b3,   b3 = R e3                       (mass-normalised thrust)

  the feedback part ``-k_p e_p - k_v e_v`` is limited to ``a_fb_max`` (norm) so that a
  large error cannot ask for a flip;

* desired attitude (same map as :func:`aerohrl.datagen.goals.flat_attitude`)::

      z_d = a_des / |a_des|,  x_c = [cos psi, sin psi, 0]
      y_d = z_d x x_c / |z_d x x_c|,  x_d = y_d x z_d,  R_d = [x_d y_d z_d]

* attitude error ``e_R = 1/2 (R_d^T R - R^T R_d)^vee``;

* flatness feed-forward rates of the desired frame (in that frame)::

      h_w = (j_des - (z_d . j_des) z_d) / |a_des|          (= dz_d/dt)
      p_ff = -h_w . y_d,   q_ff = h_w . x_d
      r_ff = -((h_w x x_c) + psi_dot (z_d x x_c')) . x_d / |z_d x x_c|,  x_c' = [-sin psi, cos psi, 0]

  ``j_des = j_ref - k_p e_v - k_v e_a`` with ``e_a = c b3 - g e3 - a_ref`` (the time
  derivative of a_des; the feedback terms are dropped when ``feedback_jerk=False``).
  ``r_ff`` is the exact yaw rate of the Lee construction of R_d above; Mellinger's
  ``r = psi_dot z_W . z_B`` belongs to his Z-X-Y Euler construction and would leave a
  yaw error here;

* rate command ``w_cmd = R^T R_d w_ff - k_R e_R``, clipped to ``rate_max`` (roll,
  pitch) and ``yaw_rate_max``; ``c`` clipped to ``[c_min, c_max]``.

**Disturbance observer** (``disturbance=`` of ``__call__``, :class:`DisturbanceObserver`):
an unmodelled acceleration ``d`` (a mass or thrust-coefficient error, drag, wind) is
estimated from the observed velocity and cancelled, ``a_des = ... + g e3 - d_hat``; the
geometric controller alone has no integral action and holds a steady offset under it.
With :class:`ThrustGainObserver` (``thrust_gain=``) a thrust-coefficient or mass error is
estimated as a gain ``kappa`` on the collective, ``c = (a_des - d_hat) . b3 / kappa_hat``, and
only the horizontal rest as an acceleration.

The inner rate loop of the simulator (k_w = 40 1/s for the Hummingbird, a ~25 ms rate
response) makes ``k_R`` the attitude bandwidth; the gains below keep a factor of ~4
between the loops (position ~3 rad/s, attitude 10 1/s, rate 40 1/s).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from aerohrl.sim.params import GRAVITY, QuadrotorParams


@dataclass(frozen=True)
class ControllerGains:
    """Gains and output limits of :class:`GeometricController` (SI units)."""

    k_p: tuple[float, float, float] = (10.0, 10.0, 12.0)  # 1/s^2
    k_v: tuple[float, float, float] = (6.0, 6.0, 7.0)  # 1/s
    k_R: tuple[float, float, float] = (10.0, 10.0, 6.0)  # 1/s, attitude error -> rate command
    a_fb_max: float = 10.0  # m/s^2, norm limit of the position/velocity feedback acceleration
    feedback_jerk: bool = True  # include d/dt of the feedback terms in the rate feed-forward
    c_min: float = 0.5  # m/s^2, collective thrust limits of the action
    c_max: float = 30.0
    rate_max: float = 10.0  # rad/s, roll and pitch rate command limit
    yaw_rate_max: float = 5.0  # rad/s

    def to_dict(self) -> dict:
        """The gains as a JSON-ready dict (the gain vectors as lists)."""
        d = asdict(self)
        for k in ("k_p", "k_v", "k_R"):
            d[k] = list(d[k])
        return d


def _cross(a, b):
    """Row-wise cross product of (N, 3) arrays (np.cross has a large per-call overhead)."""
    return np.stack(
        [
            a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1],
            a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
            a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0],
        ],
        axis=1,
    )


def _dot(a, b):
    return np.einsum("ni,ni->n", a, b)


class GeometricController:
    """``ctrl(state, ref_pos, ref_vel, ref_acc, ref_jerk, yaw=0.0, yaw_rate=0.0) -> ctbr (N, 4)``."""

    def __init__(self, params: QuadrotorParams, gains: ControllerGains | None = None):
        self.params = params
        self.gains = gains if gains is not None else ControllerGains()
        g = self.gains
        self._kp = np.asarray(g.k_p, dtype=np.float64)
        self._kv = np.asarray(g.k_v, dtype=np.float64)
        self._kR = np.asarray(g.k_R, dtype=np.float64)
        self._c_max = min(g.c_max, params.max_collective)
        self._rate_lim = np.array([g.rate_max, g.rate_max, g.yaw_rate_max])

    @property
    def action_box(self) -> tuple[np.ndarray, np.ndarray]:
        """``(low, high)`` (4,) of the actions this controller emits (its output clip)."""
        lo = np.concatenate([[self.gains.c_min], -self._rate_lim])
        hi = np.concatenate([[self._c_max], self._rate_lim])
        return lo, hi

    def desired(
        self, state: np.ndarray, ref_pos: np.ndarray, ref_vel: np.ndarray, ref_acc: np.ndarray, yaw: float | np.ndarray = 0.0
    ) -> tuple[np.ndarray, np.ndarray]:
        """``(a_des, e_v)`` (N, 3) each: desired acceleration incl. gravity, and velocity error."""
        s = np.asarray(state, dtype=np.float64)
        e_p = s[:, 0:3] - ref_pos
        e_v = s[:, 3:6] - ref_vel
        fb = -self._kp * e_p - self._kv * e_v
        n = np.linalg.norm(fb, axis=1, keepdims=True)
        fb *= np.minimum(1.0, self.gains.a_fb_max / np.maximum(n, 1e-12))
        a_des = fb + ref_acc
        a_des[:, 2] += GRAVITY
        return a_des, e_v

    def __call__(
        self, state, ref_pos, ref_vel, ref_acc, ref_jerk, yaw=0.0, yaw_rate=0.0, disturbance=None, thrust_gain=None
    ) -> np.ndarray:
        """The CTBR command (N, 4); ``disturbance`` (N, 3): an estimate of the unmodelled
        acceleration (:class:`DisturbanceObserver`), cancelled in the desired acceleration;
        ``thrust_gain`` (N,): an estimate of the flown collective per commanded one
        (:class:`ThrustGainObserver`), divided out of the collective."""
        s = np.asarray(state, dtype=np.float64)
        if s.ndim != 2 or s.shape[1] != 18:
            raise ValueError(f"state must have shape (N, 18), got {s.shape}")
        N = s.shape[0]
        refs = [np.broadcast_to(np.asarray(r, dtype=np.float64), (N, 3)) for r in (ref_pos, ref_vel, ref_acc, ref_jerk)]
        ref_pos, ref_vel, ref_acc, ref_jerk = refs
        g = self.gains
        R = s[:, 6:15].reshape(N, 3, 3)
        b3 = R[:, :, 2]

        a_des, e_v = self.desired(s, ref_pos, ref_vel, ref_acc)
        if disturbance is not None:
            a_des = a_des - disturbance
        c = _dot(a_des, b3)

        # desired attitude: Lee construction with heading x_c (same as goals.flat_attitude)
        a_norm = np.linalg.norm(a_des, axis=1)
        z_d = a_des / a_norm[:, None]
        psi = np.broadcast_to(np.asarray(yaw, dtype=np.float64), (N,))
        x_c = np.stack([np.cos(psi), np.sin(psi), np.zeros(N)], axis=1)
        u = _cross(z_d, x_c)
        u_norm = np.linalg.norm(u, axis=1)
        y_d = u / u_norm[:, None]
        x_d = _cross(y_d, z_d)
        R_d = np.stack([x_d, y_d, z_d], axis=2)

        # attitude error e_R = 1/2 (R_d^T R - R^T R_d)^vee
        E = np.einsum("nki,nkj->nij", R_d, R)
        e_R = 0.5 * np.stack([E[:, 2, 1] - E[:, 1, 2], E[:, 0, 2] - E[:, 2, 0], E[:, 1, 0] - E[:, 0, 1]], axis=1)

        # flatness feed-forward: rates of R_d from the jerk of the desired acceleration
        j = ref_jerk
        if g.feedback_jerk:
            acc = c[:, None] * b3
            acc[:, 2] -= GRAVITY
            j = j - self._kp * e_v - self._kv * (acc - ref_acc)
        h = (j - _dot(z_d, j)[:, None] * z_d) / a_norm[:, None]
        p_ff = -_dot(h, y_d)
        q_ff = _dot(h, x_d)
        psi_dot = np.broadcast_to(np.asarray(yaw_rate, dtype=np.float64), (N,))
        x_c_dot = psi_dot[:, None] * np.stack([-np.sin(psi), np.cos(psi), np.zeros(N)], axis=1)
        r_ff = -_dot(_cross(h, x_c) + _cross(z_d, x_c_dot), x_d) / u_norm
        w_ff = np.stack([p_ff, q_ff, r_ff], axis=1)

        # w_cmd = R^T R_d w_ff - k_R e_R  (E^T = R^T R_d)
        w_cmd = np.einsum("nji,nj->ni", E, w_ff) - self._kR * e_R
        out = np.empty((N, 4))
        if thrust_gain is not None:  # command the collective that flies as c
            c = c / thrust_gain
        out[:, 0] = np.clip(c, g.c_min, self._c_max)
        out[:, 1:] = np.clip(w_cmd, -self._rate_lim, self._rate_lim)
        return out


def observer_gains(tau: float) -> tuple[float, float]:
    """``(l_1, l_2)`` of :class:`DisturbanceObserver` with both poles of its error dynamics at
    ``-1/tau`` (critically damped, bandwidth ``1/tau``): ``l_1 = 2/tau``, ``l_2 = 1/tau^2``."""
    return 2.0 / tau, 1.0 / tau**2


class _VelocityObserver:
    """What the observers below share: gains with both poles at ``-1/tau``, the velocity
    estimate ``v_hat`` (started at the first observed velocity), the acceleration estimate
    ``d_hat`` (N, 3, from 0) and the innovation of a step."""

    def __init__(self, n: int, tau: float, dt: float):
        if not tau > 0 or not dt > 0:
            raise ValueError(f"observer time constant and step must be > 0, got tau={tau}, dt={dt}")
        self.l1, self.l2 = observer_gains(tau)
        self.dt = dt
        self.v_hat: np.ndarray | None = None
        self.d_hat: np.ndarray = np.zeros((n, 3))

    def _innovation(self, state: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(e, thrust, v_hat)``: the innovation ``v - v_hat`` (N, 3), the commanded collective
        along the observed body z-axis ``c b3`` (N, 3) and the velocity estimate it is against."""
        s = np.asarray(state, dtype=np.float64)
        v, b3 = s[:, 3:6], s[:, 6:15].reshape(-1, 3, 3)[:, :, 2]
        if self.v_hat is None:
            self.v_hat = v.copy()
        return v - self.v_hat, c[:, None] * b3, self.v_hat


class DisturbanceObserver(_VelocityObserver):
    r"""A Luenberger observer of an unmodelled acceleration ``d`` (N, 3), batched.

    Model: ``dv/dt = c b3 - g e3 + d`` with ``d`` slowly varying (``dd/dt = 0``), where ``c``
    is the commanded mass-normalised collective and ``b3 = R e3`` the observed body z-axis.
    One step of length ``dt`` with the observed velocity ``v`` (forward Euler)::

        e      = v - v_hat
        v_hat += dt (c b3 - g e3 + d_hat + l_1 e)
        d_hat += dt l_2 e

    The error dynamics have both poles at ``-1/tau`` (:func:`observer_gains`). The velocity
    enters through integration, not differentiation, so observation noise is low-passed
    rather than amplified. A steady ``d`` (a mass scale ``s`` at hover gives
    ``d = g (1/s - 1) e3``) is estimated exactly; ``d_hat`` starts at 0.
    """

    def update(self, state: np.ndarray, c: np.ndarray) -> np.ndarray:
        """Advance with the observed ``state`` (N, 18) and the collective ``c`` (N,) just
        commanded from it; returns ``d_hat`` (N, 3), the estimate for the next command."""
        e, acc, v_hat = self._innovation(state, c)
        acc[:, 2] -= GRAVITY
        self.v_hat = v_hat + self.dt * (acc + self.d_hat + self.l1 * e)
        self.d_hat = self.d_hat + self.dt * self.l2 * e
        return self.d_hat


# The thrust gain estimate is kept in this range, so that a noisy step cannot flip or blow
# up the collective it divides; a vehicle outside it could not fly the expert's references.
GAIN_RANGE = (0.25, 4.0)


class ThrustGainObserver(_VelocityObserver):
    r"""A Luenberger observer of a thrust gain ``kappa`` (N,) and a horizontal external
    acceleration ``d`` (N, 3, vertical part 0), batched.

    Model: ``dv/dt = kappa c b3 - g e3 + d`` with ``kappa`` (flown collective per commanded
    one: thrust scale / mass scale) and ``d = (d_x, d_y, 0)`` (wind on the drag) slowly
    varying. The additive observer (:class:`DisturbanceObserver`) lumps both into one
    acceleration ``(kappa - 1) c b3 + d``, which is steady only while ``c b3`` is; under a
    thrust error it lags every change of the collective, most in the final braking. Here
    the innovation ``e = v - v_hat`` is split in the basis ``(c b3, e_x, e_y)``::

        dkappa = e_z / (c b3_z),   dd_xy = e_xy - dkappa c b3_xy

        v_hat += dt (kappa_hat c b3 - g e3 + d_hat + l_1 e)
        kappa_hat += dt l_2 dkappa,   d_hat_xy += dt l_2 dd_xy

    For a constant ``c b3`` the estimated acceleration ``kappa_hat c b3 + d_hat`` moves by
    ``dt l_2 e`` a step, as the additive observer's does: the same error dynamics, both
    poles at ``-1/tau`` (:func:`observer_gains`). A vertical external force (vertical drag)
    is read as part of the gain. The controller divides the collective by ``kappa_hat`` and
    cancels ``d_hat`` (``GeometricController(..., disturbance=d_hat, thrust_gain=kappa_hat)``).
    """

    def __init__(self, n: int, tau: float, dt: float):
        super().__init__(n, tau, dt)
        self.kappa_hat: np.ndarray = np.ones(n)

    def update(self, state: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Advance with the observed ``state`` (N, 18) and the collective ``c`` (N,) just
        commanded from it; returns ``(kappa_hat (N,), d_hat (N, 3))`` for the next command."""
        e, thrust, v_hat = self._innovation(state, c)
        acc = self.kappa_hat[:, None] * thrust + self.d_hat
        acc[:, 2] -= GRAVITY
        self.v_hat = v_hat + self.dt * (acc + self.l1 * e)
        # e = dkappa c b3 + (dd_x, dd_y, 0); c b3_z > 0 for any collective the controller flies
        dkappa = e[:, 2] / np.maximum(thrust[:, 2], 1e-3)
        dd = e[:, :2] - dkappa[:, None] * thrust[:, :2]
        self.kappa_hat = np.clip(self.kappa_hat + self.dt * self.l2 * dkappa, *GAIN_RANGE)
        self.d_hat = self.d_hat.copy()  # a new array per step, as DisturbanceObserver's: callers may hold the last one
        self.d_hat[:, :2] += self.dt * self.l2 * dd
        return self.kappa_hat, self.d_hat
