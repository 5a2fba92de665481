r"""Expert-data recipes beyond the thesis: action noise (DART), perturbed start states
and the replanning expert (docs/spec.md "Expert-data recipes"; datagen/README.md "Recipes").

Pure, batched functions over N vehicles; the rollout loop in
:func:`aerohrl.datagen.build.rollout_expert` calls them once per control step.

Action noise (DART, Laskey et al., CoRL 2017)
---------------------------------------------
The vehicle flies ``a_flown = clip(a_expert(s) + eta, box)`` where ``eta`` is an
Ornstein-Uhlenbeck process per CTBR dimension with stationary standard deviation
``sigma`` and correlation time ``tau``, sampled exactly at the control period ``dt``::

    eta_0     ~ N(0, sigma^2)                                   (stationary start)
    eta_{k+1} = rho eta_k + sigma sqrt(1 - rho^2) xi_k,  rho = exp(-dt / tau),  xi_k ~ N(0, 1)

so ``Var[eta_k] = sigma^2`` and ``Corr[eta_k, eta_{k+m}] = rho^m = exp(-m dt / tau)``.
The dataset's ``action`` is ``a_flown`` (transitions stay consistent for TD learning)
and ``action.expert`` is ``a_expert(s)``, the clean command at the flown state: what
the learner should imitate (DART's point: the expert's corrections from the states its
own noisy execution visits).

Perturbed start states
----------------------
At the origin with ``v_i ~ U(-v_max, v_max)``, an attitude ``R = exp([r]_x)`` whose
rotation vector has components ``r_i ~ U(-tilt, tilt)`` (scipy's ``Rotation.from_rotvec``)
and body rates ``w_i ~ U(-w_max, w_max)``. The reference starts from ``(p, v, a) =
(0, v_0, 0)``: the expert first recovers the attitude and rates, as it must from any
state off its reference.

Replanning expert (shrinking horizon)
-------------------------------------
Every ``K`` steps the reference is re-planned from the flown position and velocity and
the current reference acceleration (the commanded one, continuous for the thrust
command) to the goal, keeping the take-off plan's end time ``T`` (the minimum-time
search runs once, at take-off): the new quintic spans ``T - t`` and is the
unconstrained minimum-jerk solution (the closed form of
:func:`aerohrl.datagen.reference.min_jerk_closed_form`). Re-planning stops ``endgame``
seconds before ``T``; the last plan is tracked with feedback to the end. (Recomputing
the minimum time at every re-plan, or re-planning to the very end, fails: the horizon
collapses and the demanded jerk saturates the body rates; shared/reference/trials.)
"""

from __future__ import annotations

import numpy as np

from aerohrl import task
from aerohrl.datagen import reference


class OUNoise:
    """Batched Ornstein-Uhlenbeck noise, N processes x D dimensions (module docstring)."""

    def __init__(self, sigma, tau: float, dt: float, n: int, rng: np.random.Generator):
        self.sigma = np.asarray(sigma, dtype=np.float64)
        self.rho = float(np.exp(-dt / tau))
        self.kick = self.sigma * np.sqrt(1.0 - self.rho**2)
        self.rng = rng
        self.eta = self.sigma * rng.standard_normal((n, self.sigma.shape[0]))

    def __call__(self) -> np.ndarray:
        """The current noise (N, D), then advance one step."""
        out = self.eta
        self.eta = self.rho * self.eta + self.kick * self.rng.standard_normal(self.eta.shape)
        return out


def sample_start_states(
    rng: np.random.Generator, n: int, v_max: float, tilt: float, w_max: float
) -> tuple[np.ndarray, np.ndarray]:
    """``(state (n, 18), x0 (n, 3, 3))``: perturbed starts at the origin and the
    reference's initial ``[axis, (p, v, a)]`` = ``(0, v_0, 0)`` (module docstring)."""
    from scipy.spatial.transform import Rotation

    v = rng.uniform(-v_max, v_max, size=(n, 3))
    rotvec = rng.uniform(-tilt, tilt, size=(n, 3))
    w = rng.uniform(-w_max, w_max, size=(n, 3))
    state = np.zeros((n, task.STATE_DIM))
    state[:, task.VEL] = v
    state[:, task.ROT] = Rotation.from_rotvec(rotvec).as_matrix().reshape(n, 9)
    state[:, task.RATE] = w
    x0 = np.zeros((n, 3, 3))
    x0[:, :, 1] = v
    return state, x0


def replan(
    coeffs: np.ndarray,
    t0: np.ndarray,
    due: np.ndarray,
    t: float,
    state: np.ndarray | None,
    xf: np.ndarray,
    T: np.ndarray,
) -> None:
    """Shrinking-horizon re-plan, in place, of the references ``due`` (bool (N,)) at time ``t``.

    ``coeffs`` (N, 3, 6) are in each plan's own time (from ``t0`` (N,)); a re-planned
    reference starts at the flown ``p, v`` and the current reference acceleration and
    ends at the goal ``xf`` (N, 3, 3) at the take-off plan's end ``T`` (N,). With
    ``state=None`` it starts at the reference's own ``p, v, a`` instead: only the end
    moves (a retarget; the expert's endgame).
    """
    i = np.flatnonzero(due)
    if i.size == 0:
        return
    ref = [reference.evaluate(coeffs[i], t - t0[i], order=o) for o in range(3)]
    if state is not None:
        ref[:2] = state[i, task.POS], state[i, task.VEL]
    x0 = np.stack(ref, axis=-1)  # (m, axis, (p, v, a))
    c = reference.min_jerk_closed_form(x0, xf[i], T[i] - t)
    coeffs[i] = 0.0  # a degree > 5 reference: the quintic in its first 6 coefficients
    coeffs[i, :, : c.shape[2]] = c
    t0[i] = t


__all__ = ["OUNoise", "sample_start_states", "replan"]
