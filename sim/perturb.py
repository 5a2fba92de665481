"""Model error for robustness tests: a perturbed plant behind the nominal flight controller.

A :class:`Perturbation` is the spec of the error (docs/spec.md "Perturbations"): scales on
the vehicle's constants, actuation latency, linear drag, wind (a constant mean plus
Ornstein-Uhlenbeck gusts) and noise and bias on what the policy or controller observes.
Every field is a number, or an array of one value per vehicle (shape (N,)); the defaults
are the nominal model, and a nominal perturbation leaves the simulator on its nominal
code path (the same bytes as without one).

The perturbed plant (what the physics integrates; primes are the perturbed constants)::

    m' = s_m m,  J' = s_J J,  k_eta' = s_f k_eta,  k_m' = s_M k_m,  tau_m' = s_tau tau_m
    v_dot     = (k_eta' / m') R e3 sum_i Omega_i^2 - g e3 - d (v - v_air)
    w_dot     = J'^-1 (tau_prop' - w x J' w),
                tau_prop' = sum_i r_i x (k_eta' Omega_i^2 e3) + dir_i k_m' Omega_i^2 e3
    Omega_dot = (Omega_cmd - Omega) / tau_m'
    v_air     = W (cos psi, sin psi, 0) + g_k,   the mean wind W toward azimuth psi plus a gust

The flight controller does not know the error: the CTBR rate loop and the allocation keep
the nominal m, J, k_eta and k_m (so a heavier vehicle commanded ``c = g`` sinks). A
uniform inertia scale leaves ``J'^-1 (w x J' w)`` equal to the nominal gyroscopic term.
``d`` is a mass-normalised linear drag (1/s; the force is ``m' d (v_air - v)``); wind acts
only through it, so wind needs ``drag > 0``.

Gusts: per axis an Ornstein-Uhlenbeck process of standard deviation ``gust`` (m/s) and
correlation time ``gust_tau`` (s), stepped exactly once per control step and held over it,
``g_{k+1} = phi g_k + gust sqrt(1 - phi^2) xi_k``, ``phi = exp(-dt / gust_tau)``, started
from its stationary law.

Latency ``L``: the CTBR command reaches the rate loop ``L`` later, rounded to the physics
substep ``h``: ``q = round(L / h)`` substeps, ``M = q // S`` whole control steps and ``r = q % S``
substeps (``S`` substeps per step). In substep ``j`` of step ``k`` the rate loop flies
``u_{k-M}`` if ``j >= r`` else ``u_{k-M-1}`` (a ring buffer of the last commands); before the
first command the vehicle was hovering, ``u = [g, 0, 0, 0]``.

Observation: ``p + b_p + sigma_p xi``, ``v + b_v + sigma_v xi``, ``R Exp(b_R + sigma_R xi)`` (a
small body-frame rotation), ``w + b_w + sigma_w xi``; ``xi`` standard normal per vehicle, axis
and step, each bias a fixed magnitude in a random direction per vehicle and episode. The
true state is never changed; the rate loop flies on the true body rates.

Randomness (gusts, noise, bias directions) comes from one generator seeded by the
simulator's ``seed``: the same seed and calls give the same bytes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace
from typing import Any

import numpy as np

from aerohrl.config import param
from aerohrl.errors import UserError
from aerohrl.sim import dynamics as dyn
from aerohrl.sim.params import GRAVITY

MAX_LATENCY = 0.2  # s, the longest delay line (20 control steps at 100 Hz)

Value = Any  # a float, or an array of one value per vehicle


@dataclass(frozen=True)
class Perturbation:
    """The model error of a batch of vehicles (module doc); defaults = the nominal model.

    ``NAME=VALUE[,NAME=VALUE...]`` strings (``aerohrl eval --perturb``) parse with :meth:`parse`.
    """

    mass: Value = param(1.0, "mass scale: true mass / nominal", gt=0)
    inertia: Value = param(1.0, "inertia scale (the three principal moments)", gt=0)
    thrust: Value = param(1.0, "thrust coefficient k_eta scale", gt=0)
    torque: Value = param(1.0, "yaw moment coefficient k_m scale", gt=0)
    motor_tau: Value = param(1.0, "motor time constant scale", gt=0)
    latency: Value = param(0.0, "actuation latency of the CTBR command (rounded to the physics substep)", unit="s", ge=0)
    drag: Value = param(0.0, "linear drag, mass-normalised: acceleration per m/s of airspeed", unit="1/s", ge=0)
    wind: Value = param(0.0, "mean wind speed (horizontal)", unit="m/s", ge=0)
    wind_dir: Value = param(0.0, "direction the mean wind blows toward, azimuth from +x toward +y", unit="deg")
    gust: Value = param(0.0, "gust intensity: standard deviation per axis of the OU gust", unit="m/s", ge=0)
    gust_tau: Value = param(1.0, "gust correlation time", unit="s", gt=0)
    pos_noise: Value = param(0.0, "observed position noise, std per axis and step", unit="m", ge=0)
    vel_noise: Value = param(0.0, "observed velocity noise, std per axis and step", unit="m/s", ge=0)
    att_noise: Value = param(0.0, "observed attitude noise, std per axis of a small body-frame rotation", unit="rad", ge=0)
    rate_noise: Value = param(0.0, "observed body-rate noise, std per axis and step", unit="rad/s", ge=0)
    pos_bias: Value = param(0.0, "observed position bias, magnitude (random direction per episode)", unit="m", ge=0)
    vel_bias: Value = param(0.0, "observed velocity bias, magnitude", unit="m/s", ge=0)
    att_bias: Value = param(0.0, "observed attitude bias, rotation angle", unit="rad", ge=0)
    rate_bias: Value = param(0.0, "observed body-rate bias, magnitude", unit="rad/s", ge=0)

    # ------------------------------------------------------------------ spec
    @classmethod
    def names(cls) -> tuple[str, ...]:
        """The field names, the axes of ``NAME=VALUE``."""
        return tuple(f.name for f in fields(cls))

    @classmethod
    def parse(cls, text: str | None) -> "Perturbation":
        """``NAME=VALUE[,NAME=VALUE...]`` (e.g. ``mass=1.2,latency=0.02``); an empty string or
        None is the nominal model. :class:`UserError` (one line) for an unknown name, a value
        that is not a number, or one out of its range."""
        kw: dict[str, float] = {}
        for name, value in assignments(text, "perturbation", "NAME=VALUE"):
            try:
                kw[name] = float(value)
            except ValueError:
                raise UserError(f"perturbation {name}={value!r}: not a number") from None
        p = cls(**kw)
        p.check()
        return p

    def check(self, n: int | None = None) -> None:
        """:class:`UserError` (one line) if a value is out of its field's range, is not
        finite, or (with ``n``) is not one number or ``n`` numbers; wind or gusts without drag."""
        for f in fields(self):
            v = np.asarray(getattr(self, f.name), dtype=np.float64)
            if v.ndim > 1 or (v.ndim == 1 and n is not None and v.shape[0] != n):
                raise UserError(f"perturbation {f.name}: one value or one per vehicle ({n}), got shape {v.shape}")
            if not np.isfinite(v).all():
                raise UserError(f"perturbation {f.name} must be finite")
            m = f.metadata
            for key, ok, word in (("ge", np.greater_equal, ">="), ("gt", np.greater, ">")):
                if m.get(key) is not None and not ok(v, m[key]).all():
                    bad = v.min()
                    raise UserError(f"perturbation {f.name} must be {word} {m[key]:g}, got {bad:g}")
        lat = np.asarray(self.latency, dtype=np.float64)
        if (lat > MAX_LATENCY + 1e-12).any():
            raise UserError(f"perturbation latency must be <= {MAX_LATENCY:g} s (the delay line), got {lat.max():g}")
        airless = np.asarray(self.drag) <= 0
        for name in ("wind", "gust"):
            if (airless & (np.asarray(getattr(self, name)) > 0)).any():
                raise UserError(f"perturbation {name} acts through the drag: give drag=D (1/s) > 0 too")

    def changed(self) -> dict[str, Value]:
        """The fields that differ from the nominal model, in declaration order."""
        out = {}
        for f in fields(self):
            v = getattr(self, f.name)
            if (np.asarray(v, dtype=np.float64) != f.default).any():
                out[f.name] = v
        return out

    @property
    def nominal(self) -> bool:
        """True when every field holds its nominal value (the simulator then takes its nominal path).
        The wind's direction and the gusts' correlation time are nothing without wind or gusts."""
        ch = self.changed()
        ch.pop("wind_dir", None)
        ch.pop("gust_tau", None)
        return not ch

    def text(self) -> str:
        """The ``NAME=VALUE,...`` form of the changed fields (scalars only; :meth:`parse` inverts it)."""
        return ",".join(f"{k}={_num(v)}" for k, v in self.changed().items())

    def slug(self) -> str:
        """A file-name form of the changed fields, e.g. ``mass1.2-latency0.02`` (``nominal`` if none)."""
        return "-".join(f"{k.replace('_', '')}{_num(v)}" for k, v in self.changed().items()) or "nominal"

    def to_dict(self) -> dict:
        """JSON-able record of the changed fields (lists for per-vehicle values)."""
        return {k: (np.asarray(v).tolist() if np.ndim(v) else float(v)) for k, v in self.changed().items()}

    def with_values(self, **changes: Value) -> "Perturbation":
        """A copy with some fields changed."""
        return replace(self, **changes)


def assignments(text: str | None, what: str, form: str) -> list[tuple[str, str]]:
    """The ``NAME=VALUE`` items of a comma-separated list over the :class:`Perturbation`
    fields, in the order given, values unparsed; UserError (one line) for an item without
    ``=`` (``what``, ``form`` name the list in the message), an unknown field or a field
    given twice."""
    out: list[tuple[str, str]] = []
    for item in (text or "").split(","):
        item = item.strip()
        if not item:
            continue
        name, eq, value = item.partition("=")
        name = name.strip()
        if not eq:
            raise UserError(f"{what} {item!r}: expected {form}")
        if name not in Perturbation.names():
            raise UserError(f"unknown perturbation {name!r} (choose from: {', '.join(Perturbation.names())})")
        if any(name == n for n, _ in out):
            raise UserError(f"{what} {name!r} given twice")
        out.append((name, value))
    return out


def parse_ranges(text: str | None) -> dict[str, tuple[float, float]]:
    """Domain-randomisation ranges ``AXIS=LO:HI[,AXIS=V...]`` (a single value is fixed) over the
    :class:`Perturbation` fields -> ``{axis: (lo, hi)}`` in the order given; UserError (one
    line) for an unknown axis, a number that is not one, an inverted range or an end out of
    the field's range."""
    out: dict[str, tuple[float, float]] = {}
    for name, value in assignments(text, "randomisation", "AXIS=LO:HI"):
        ends = value.split(":")
        try:
            lo, hi = (float(ends[0]), float(ends[-1])) if len(ends) in (1, 2) else (math.nan, math.nan)
        except ValueError:
            raise UserError(f"randomisation {name}={value!r}: not LO:HI numbers") from None
        if not lo <= hi:
            raise UserError(f"randomisation {name}={value!r}: need LO <= HI")
        out[name] = (lo, hi)
    for end in (0, 1):
        Perturbation(**{k: v[end] for k, v in out.items()}).check()  # both ends within the fields' ranges
    return out


def sample(ranges: dict[str, tuple[float, float]], n: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """``n`` values per axis, uniform in its range (drawn axis after axis, in the order of ``ranges``)."""
    return {k: rng.uniform(lo, hi, n) for k, (lo, hi) in ranges.items()}


def _num(v: Value) -> str:
    if np.ndim(v):
        raise ValueError("a per-vehicle perturbation has no one-line form")
    return f"{float(v):g}"


def hover_command() -> np.ndarray:
    """The CTBR command of hover, ``[g, 0, 0, 0]`` (4,)."""
    return np.array([GRAVITY, 0.0, 0.0, 0.0])


# ----------------------------------------------------------------------------- physics
def wrench_scale(mass: np.ndarray, inertia: np.ndarray, thrust: np.ndarray, torque: np.ndarray) -> np.ndarray:
    """(4, N) factors from the nominal rotor wrench ``[T/m, J^-1 tau_prop]`` to the perturbed one:
    ``[s_f / s_m, s_f / s_J, s_f / s_J, s_M / s_J]`` (thrust and its roll/pitch lever scale with
    k_eta, the yaw moment with k_m, the accelerations with 1/m and 1/J)."""
    return np.stack([thrust / mass, thrust / inertia, thrust / inertia, torque / inertia])


def drag_acceleration(v: np.ndarray, v_air: np.ndarray, drag: np.ndarray, out: np.ndarray) -> np.ndarray:
    """``out`` (3, N) = ``-d (v - v_air)``: linear drag on the airspeed (mass-normalised)."""
    np.subtract(v, v_air, out=out)
    np.multiply(out, -drag, out=out)
    return out


def ou_step(g: np.ndarray, phi: np.ndarray, sigma: np.ndarray, xi: np.ndarray) -> np.ndarray:
    """One exact step of the Ornstein-Uhlenbeck gust: ``phi g + sigma sqrt(1 - phi^2) xi`` (3, N)."""
    return phi * g + sigma * np.sqrt(1.0 - phi * phi) * xi


def mean_wind(speed: np.ndarray, direction_deg: np.ndarray) -> np.ndarray:
    """(3, N) mean wind velocity ``W (cos psi, sin psi, 0)`` (m/s), ``psi`` in degrees."""
    psi = np.deg2rad(direction_deg)
    return np.stack([speed * np.cos(psi), speed * np.sin(psi), np.zeros_like(speed)])


def latency_split(latency: np.ndarray, dt: float, substeps: int) -> tuple[np.ndarray, np.ndarray]:
    """Whole control steps ``M`` and remaining substeps ``r`` (both (N,) int) of ``latency`` (s):
    ``q = round(L / h)``, ``M = q // S``, ``r = q % S`` with ``h = dt / S``."""
    q = np.rint(np.asarray(latency, dtype=np.float64) * substeps / dt).astype(np.int64)
    return q // substeps, q % substeps


def random_directions(rng: np.random.Generator, n: int) -> np.ndarray:
    """(3, n) unit vectors, uniform on the sphere."""
    d = rng.standard_normal((3, n))
    return d / np.maximum(np.linalg.norm(d, axis=0), 1e-12)


def observe(
    state: np.ndarray,
    noise: dict[str, np.ndarray],
    bias: dict[str, np.ndarray],
    xi: dict[str, np.ndarray],
) -> np.ndarray:
    """The observed (N, 18) state: ``state`` plus bias and scaled noise ``xi`` (each (N, 3))
    on p, v and w, and R times the rotation ``Exp(b_R + sigma_R xi_R)`` (scipy's rotation
    vectors); the input is not changed. Keys: ``pos``, ``vel``, ``att``, ``rate``; a channel
    missing from ``xi`` is observed without noise or bias."""
    from scipy.spatial.transform import Rotation

    obs = np.array(state, dtype=np.float64, copy=True)
    for key, cols in (("pos", slice(0, 3)), ("vel", slice(3, 6)), ("rate", slice(15, 18))):
        if key in xi:
            obs[:, cols] += bias[key] + noise[key][:, None] * xi[key]
    if "att" in xi:
        delta = Rotation.from_rotvec(bias["att"] + noise["att"][:, None] * xi["att"]).as_matrix()
        R = state[:, 6:15].reshape(-1, 3, 3)
        obs[:, 6:15] = np.einsum("nij,njk->nik", R, delta).reshape(-1, 9)
    return obs


class PerturbedPlant:
    """The perturbation of a batch of ``n`` vehicles as per-vehicle arrays, with its state
    (the delay line, the gusts, the observation biases and the random generator). Used by
    :class:`aerohrl.sim.BatchedQuadrotor`; ``check`` errors are one line."""

    CHANNELS = ("pos", "vel", "att", "rate")

    def __init__(self, p: Perturbation, n: int, dt: float, substeps: int, seed: int | list[int] = 0):
        p.check(n)
        self.spec, self.n, self.dt, self.substeps = p, n, dt, substeps
        h = dt / substeps

        def arr(name: str) -> np.ndarray:
            return np.broadcast_to(np.asarray(getattr(p, name), dtype=np.float64), (n,)).copy()

        self.scale = wrench_scale(arr("mass"), arr("inertia"), arr("thrust"), arr("torque"))
        tau = arr("motor_tau")
        self.tau_scale = tau
        self.drag = arr("drag")
        self.wind_mean = mean_wind(arr("wind"), arr("wind_dir"))
        self.gust_sigma = arr("gust")
        self.gust_phi = np.exp(-dt / arr("gust_tau"))
        self.steps, self.sub = latency_split(arr("latency"), dt, substeps)
        self.delayed = bool(self.steps.any() or self.sub.any())
        self.noise = {c: arr(f"{c}_noise") for c in self.CHANNELS}
        self.bias_size = {c: arr(f"{c}_bias") for c in self.CHANNELS}
        self.observed_channels = tuple(c for c in self.CHANNELS if self.noise[c].any() or self.bias_size[c].any())
        self.h = h
        self.rng = np.random.default_rng(seed)
        self._decay: dict[tuple[float, float], tuple[np.ndarray, np.ndarray]] = {}
        # delay line: slot k % D holds the command of control step k
        self.depth = int(self.steps.max()) + 2
        self.buf = np.empty((self.depth, 4, n))
        self.k = -1  # the newest command's step
        self.gust = np.zeros((3, n))
        self.bias = {c: np.zeros((n, 3)) for c in self.CHANNELS}
        self.v_air = np.zeros((3, n))
        self.t3 = np.empty((3, n))
        self._ar = np.arange(n)
        self.reset(np.arange(n))

    def reseed(self, seed: int | list[int]) -> None:
        """Restart the random generator (gusts, noise, bias directions) from ``seed``."""
        self.rng = np.random.default_rng(seed)

    def reset(self, rows: np.ndarray) -> None:
        """New episodes for ``rows``: hover in the delay line, a fresh gust and fresh bias directions."""
        rows = np.asarray(rows, dtype=np.int64)
        self.buf[:, :, rows] = hover_command()[None, :, None]
        if self.gust_sigma.any():
            self.gust[:, rows] = self.gust_sigma[rows] * self.rng.standard_normal((3, len(rows)))
        for c in self.observed_channels:
            size = self.bias_size[c][rows]
            if size.any():
                self.bias[c][rows] = (size * random_directions(self.rng, len(rows))).T
        self._air()

    def _air(self) -> None:
        np.add(self.wind_mean, self.gust, out=self.v_air)

    def decay(self, h: float, inv_tau: float) -> tuple[np.ndarray, np.ndarray]:
        """``(e^{-h / (2 tau_m')}, e^{-h / tau_m'})`` (N,) for the exact motor solution over a
        substep, ``tau_m' = s_tau / inv_tau`` (``inv_tau``: the nominal 1 / tau_m)."""
        key = (h, inv_tau)
        if key not in self._decay:
            self._decay[key] = (np.exp(-0.5 * h * inv_tau / self.tau_scale), np.exp(-h * inv_tau / self.tau_scale))
        return self._decay[key]

    # ------------------------------------------------------------------ commands
    def push(self, u: np.ndarray) -> None:
        """Record the CTBR command ``u`` (4, N) of the coming control step."""
        self.k += 1
        self.buf[self.k % self.depth] = u

    def commands(self) -> tuple[np.ndarray, np.ndarray]:
        """``(u_{k-M}, u_{k-M-1})`` (4, N) per vehicle: the commands the rate loop flies this step
        from its substep ``r`` on, and before it."""
        k, D = self.k, self.depth
        a = self.buf[(k - self.steps) % D, :, self._ar].T
        b = self.buf[(k - self.steps - 1) % D, :, self._ar].T
        return np.ascontiguousarray(a), np.ascontiguousarray(b)

    def end_step(self) -> None:
        """Advance the gusts one control step (held over the next one)."""
        if self.gust_sigma.any():
            xi = self.rng.standard_normal((3, self.n))
            self.gust = ou_step(self.gust, self.gust_phi, self.gust_sigma, xi)
            self._air()

    # ------------------------------------------------------------------ physics
    def derivative(self, X: np.ndarray, wrench: np.ndarray, m: dyn.Model, out: np.ndarray, s: dyn.Scratch) -> np.ndarray:
        """Rows 3:18 of ``d/dt [p, v, R, w]`` of the perturbed plant (``p_dot = v`` is the
        integrator's, see :func:`aerohrl.sim.dynamics.body_derivative`): the nominal
        derivative of the perturbed wrench plus the drag on the airspeed."""
        dyn.body_derivative(X, wrench, m, out, s)
        if self.drag.any():
            drag_acceleration(X[dyn.V], self.v_air, self.drag, self.t3)
            np.add(out[dyn.V], self.t3, out=out[dyn.V])
        return out

    def wrench(self, omega: np.ndarray, m: dyn.Model, out: np.ndarray, s: dyn.Scratch) -> np.ndarray:
        """``out`` (4, N) = the perturbed ``[T/m', J'^-1 tau_prop']``: the nominal wrench times :func:`wrench_scale`."""
        dyn.rotor_wrench(omega, m, out, s)
        np.multiply(out, self.scale, out=out)
        return out

    def rk4_step(
        self,
        X: np.ndarray,
        omega_cmd: np.ndarray,
        h: float,
        m: dyn.Model,
        s: dyn.Scratch,
        out: np.ndarray,
        *,
        w0_ready: bool = False,
    ) -> np.ndarray:
        """:func:`aerohrl.sim.dynamics.rk4_step` on the perturbed plant: the same exact motor
        solution (per-vehicle time constant) and classical RK4 of the rigid body."""
        plant = dict(wrench=self.wrench, derivative=self.derivative, decay=self.decay(h, m.inv_tau))
        return dyn.rk4_step(X, omega_cmd, h, m, s, out, w0_ready=w0_ready, **plant)

    # ------------------------------------------------------------------ observation
    def observe(self, state: np.ndarray) -> np.ndarray:
        """The observed (N, 18) state of the true ``state`` (a new array; draws this step's noise)."""
        if not self.observed_channels:
            return np.array(state, copy=True)
        xi = {c: self.rng.standard_normal((self.n, 3)) for c in self.observed_channels}
        return observe(state, self.noise, self.bias, xi)
