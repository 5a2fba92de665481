r"""Which goals the vehicle can reach at all: the expert, directly and through one run-up.

A planner is judged on the goals the vehicle can reach. For a goal set
(``eval/families.py``) this module flies the project's expert — a minimum-time
minimum-jerk reference (:mod:`aerohrl.datagen.reference`, closed form) tracked by the
geometric controller (:class:`aerohrl.datagen.expert.GeometricController`, clean: no
action noise) in the batched simulator — and records whether the goal-reached test
(:func:`aerohrl.task.goal_reached`: 0.15 m, 0.35 m/s, 0.15 rad) and its near version
(tolerances x 2.5, :func:`aerohrl.task.near_success`) hold at any 100 Hz step of the
ring's horizon.

Two ways to a goal ``G = (p, v, a, R)``:

* **direct**: one reference from rest at the origin (``x0 = 0``) to ``(p, v, a)`` of G,
  minimum time by bisection on ``T`` in ``[0, horizon]`` (thesis Alg. 1, tolerance
  0.02 s). After ``T`` the reference is held at its end (``t = min(k dt, T)``, as
  ``datagen/build.py:rollout_expert`` does), and the flight goes on to the horizon.
  A goal without a reference within the bound inside the horizon is not flown (the
  expert has no plan for it; ``datagen build`` resamples such goals) and counts as not
  directly feasible. Note that a minimum-jerk quintic from rest to a fast goal close by
  already swings away and comes back: given the time, "direct" includes run-ups of
  that shape.

  Besides the minimum-time reference (``direct_min_time``), the same quintic is flown
  slower, its duration ``T`` times each factor of :data:`STRETCH` (if it keeps the bound
  and fits the horizon); ``direct`` is any of them. Why: a minimum-time reference that
  must *end* at a large acceleration ramps it up at the last moment, and the vehicle's
  attitude (the goal's ``R`` follows from its acceleration) lags behind: on the
  ``acceleration`` family's ring 2 (|a_i| in [7, 10] m/s^2) the minimum-time flights
  reach 65 % of the goals, mostly missing the 0.15 rad attitude tolerance, the same
  quintics over 2 T reach 98 %. The expert is the same, only its plan is slower.
* **run-up**: one waypoint ``w`` at rest (``v = a = 0``), two references concatenated —
  rest at the origin -> rest at ``w``, then rest at ``w`` -> G (the second planned from
  w's nominal state, not from the flown one) — flown as one closed-loop flight.
  Candidate waypoints lie behind G along its velocity, ``p_w = p - d v_hat + l d u``,
  for the distances ``d = d0 * f``, ``f`` in :data:`DISTANCE_FACTORS`, and the lateral
  offsets ``l`` in :data:`LATERAL` along ``u``, the unit part of the goal acceleration
  perpendicular to ``v_hat`` (a path that ends with acceleration ``a`` curves towards
  it: ``p(-s) ~ p - v s + a s^2 / 2``). ``d0 = |v| max_i |v_i| / (2 a_max)`` is the
  shortest straight run-up that reaches ``v`` at constant acceleration within the
  per-axis bound (axis i covers ``d |v_i| / |v|`` and needs ``|v_i| |v| / (2 d)``);
  a minimum-jerk leg needs more, hence the factors. The second leg is also flown
  slower (durations x :data:`RUNUP_STRETCH`, as for the direct flight). A goal at rest (``|v| < 1e-6``)
  takes ``v_hat`` along ``p`` (the approach direction). An option counts only if both
  legs exist within the horizon together (``T1 + T2 <= horizon``). A goal is run-up
  feasible if any option reaches it; the reported waypoint is the option that reaches
  it first (earliest step; ties by grid order).

Acceleration bound. The dataset's bound (``a_max = 5`` m/s^2 per axis,
:data:`aerohrl.datagen.reference.A_MAX`) cannot end at goal accelerations of 7-10
m/s^2. Each goal gets its own bound (:func:`goal_bounds`)::

    a_max_i = min(a_cap, max(a_spec, margin * max_j |a_G,j|)),   a_spec = 5, margin = 1.2

``a_cap`` (:data:`A_CAP` = 12 m/s^2) keeps every corner of the per-axis box within the
controller's collective-thrust limit ``c_max = 30`` m/s^2 (the rotors could give
~100 m/s^2; the expert clips at 30): ``|(a, a, a + g)| <= 30`` for ``a <= 13.4``,
less ~1.4 m/s^2 of room for feedback. A fixed ``a_max`` (one number) replaces the rule.
The bisection is thesis Alg. 1 (the closed-form solver of
:func:`aerohrl.datagen.reference.min_time`) with a per-reference bound, built from the
public :func:`~aerohrl.datagen.reference.min_jerk_closed_form` and
:func:`~aerohrl.datagen.reference.max_acceleration`; with one bound for all it gives
``min_time``'s result (tests/test_eval_feasibility.py).

Everything is batched over goals (and run-up options): one time loop over all flights,
each flight's outcome a function of its own inputs only. The loop stops early once
every flight has reached its goal.

:func:`ring_feasibility` applies it to the test goals of a ring of an OOD goal family
(eval/families.py), as the reach study reports it. One ring's rates from the command
line (``experiments/feasibility_study.py``)::

    python experiments/feasibility_study.py --family velocity --ring 3 --n 250
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Sequence, cast

import numpy as np

from aerohrl import task
from aerohrl.datagen import reference
from aerohrl.datagen.expert import GeometricController
from aerohrl.datagen.goals import goal_vectors
from aerohrl.errors import UserError
from aerohrl.sim import BatchedQuadrotor, get_preset

if TYPE_CHECKING:
    from aerohrl.eval.families import Ring

A_SPEC = reference.A_MAX  # the dataset's per-axis bound (m/s^2)
A_MARGIN = 1.2  # bound = margin x the goal's largest acceleration component (if above A_SPEC)
A_CAP = 12.0  # m/s^2 per axis: the box corners stay within the expert's 30 m/s^2 thrust clip (module docstring)
BISECTION_TOL = reference.TOL  # 0.02 s
DISTANCE_FACTORS = (1.0, 1.5, 2.0, 3.0)  # run-up distance / d0
LATERAL = (0.0, 0.5)  # run-up waypoint offset along the goal's perpendicular acceleration, x d
STRETCH = (1.0, 1.5, 2.0)  # direct reference durations / its minimum time
RUNUP_STRETCH = (1.0, 2.0)  # run-up second leg's durations / its minimum time
MIN_RUNUP = 0.25  # m: shortest run-up distance d0
RUNUP_MODES = ("all", "failed", "none")


@dataclass
class Feasibility:
    """Per goal (E,) outcomes of :func:`feasibility`. ``runup*`` are False for goals whose
    run-up was not flown (``runup="failed"`` on a directly feasible goal, or ``"none"``)."""

    direct: np.ndarray  # bool: a direct expert flight (any duration of ``stretch``) reaches G (thesis tolerances)
    direct_near: np.ndarray  # bool: ... within the near-success tolerances (x 2.5)
    direct_min_time: np.ndarray  # bool: the minimum-time direct flight alone reaches G
    direct_min_time_near: np.ndarray  # bool
    runup: np.ndarray  # bool: some run-up option reaches G
    runup_near: np.ndarray  # bool
    feasible: np.ndarray  # direct | runup
    feasible_near: np.ndarray  # direct_near | runup_near
    T_direct: np.ndarray  # s: the direct reference's duration (the horizon if it has none)
    direct_ref: np.ndarray  # bool: a direct reference within the bound exists inside the horizon
    direct_stretch: np.ndarray  # the duration factor of the direct flight that reaches G first (NaN: none)
    direct_step: np.ndarray  # int: first step (1-based: state after k actions) at which G is reached, -1 never
    runup_waypoint: np.ndarray  # (E, 3): the run-up option that reaches G first (NaN: none)
    runup_option: np.ndarray  # int: its index in the grid, (factor, lateral, stretch) row-major (-1: none)
    runup_T: np.ndarray  # (E, 2) s: its two leg durations (NaN: none)
    runup_step: np.ndarray  # int: its first step reaching G (-1: none)
    a_max: np.ndarray  # (E,) m/s^2: the per-axis bound each goal's references were planned with
    horizon: int  # steps
    seconds: float = 0.0  # wall time
    positions_direct: np.ndarray | None = None  # (K, E, 3) every record_every-th position (record_every > 0) of
    # the direct flight that reaches G first (else the minimum-time one; NaN: not flown, or after the
    # time loop stopped because every flight of its batch had reached its goal)
    positions_runup: np.ndarray | None = None  # (K, E, 3) the chosen run-up option's flight (NaN: none)
    options: dict = field(default_factory=dict)  # the grid: distance factors, lateral offsets

    def rates(self) -> dict[str, float]:
        """Fractions of goals: direct_min_time, direct, runup, feasible and their near versions."""
        return {
            k: float(np.mean(getattr(self, k)))
            for k in (
                "direct_min_time",
                "direct_min_time_near",
                "direct",
                "direct_near",
                "runup",
                "runup_near",
                "feasible",
                "feasible_near",
            )
        }


# ------------------------------------------------------------------------ inputs


def _goals(goals: dict) -> tuple[np.ndarray, np.ndarray]:
    """(xf (E, 3, 3) [n, axis, (p, v, a)], goal vectors (E, 15)); UserError on bad goals."""
    if not isinstance(goals, dict):
        raise UserError(f"goals must be a dict with pos, vel, acc, R, got {type(goals).__name__}")
    gv = goal_vectors(goals)
    if "acc" not in goals:
        raise UserError("goals lack the key 'acc' (need pos, vel, acc, R)")
    acc = np.asarray(goals["acc"], dtype=np.float64)
    if acc.shape != (gv.shape[0], 3):
        raise UserError(f"goal accelerations must have shape ({gv.shape[0]}, 3), got {acc.shape}")
    if gv.shape[0] < 1:
        raise UserError("no goals given")
    if not (np.isfinite(gv).all() and np.isfinite(acc).all()):
        raise UserError("goals contain NaN or inf")
    R = gv[:, task.ROT].reshape(-1, 3, 3)
    if np.abs(R @ np.swapaxes(R, 1, 2) - np.eye(3)).max() > 1e-6:
        raise UserError("goal attitudes R are not rotation matrices")
    xf = np.stack([gv[:, 0:3], gv[:, 3:6], acc], axis=-1)
    return xf, gv


def _pos_int(name: str, x) -> int:
    if isinstance(x, bool) or not isinstance(x, (int, np.integer)) or x < 1:
        raise UserError(f"{name} must be a positive integer, got {x!r}")
    return int(x)


_pos_float = reference.positive_number  # a finite number > 0, else a one-line error


# ------------------------------------------------------------------- references


def goal_bounds(
    acc: np.ndarray, a_max: float | None = None, *, a_spec: float = A_SPEC, margin: float = A_MARGIN, a_cap: float = A_CAP
) -> np.ndarray:
    """Per-goal per-axis acceleration bound (E,): ``min(a_cap, max(a_spec, margin max_j |acc_j|))``,
    or the fixed ``a_max`` for every goal when given."""
    acc = np.asarray(acc, dtype=np.float64)
    if a_max is not None:
        return np.full(acc.shape[0], _pos_float("a_max", a_max))
    a_spec, margin, a_cap = _pos_float("a_spec", a_spec), _pos_float("margin", margin), _pos_float("a_cap", a_cap)
    return np.minimum(a_cap, np.maximum(a_spec, margin * np.abs(acc).max(axis=1)))


def min_time(
    x0: np.ndarray, xf: np.ndarray, a_max: np.ndarray, t_hi: float, tol: float = BISECTION_TOL
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Minimum-time quintics with a per-reference bound ``a_max`` (N,) -> ``(T, coeffs, feasible)``.

    Thesis Alg. 1 on ``[0, t_hi]`` exactly as :func:`aerohrl.datagen.reference.min_time`
    (closed form): ``t_hi`` is checked first (infeasible -> ``feasible = False``,
    ``T = t_hi`` and the unconstrained quintic), then the bracket is halved until narrower
    than ``tol`` and its feasible end returned. Feasible at T: the quintic's exact
    ``max |a_i| <= a_max (1 + 1e-9)`` on every axis.
    """
    x0 = np.asarray(x0, dtype=np.float64)
    xf = np.asarray(xf, dtype=np.float64)
    n = x0.shape[0]
    bound = (np.asarray(a_max, dtype=np.float64) * (1.0 + reference.CF_RTOL))[:, None]

    def ok(T):
        return (reference.max_acceleration(reference.min_jerk_closed_form(x0, xf, T), T) <= bound).all(axis=1)

    hi: np.ndarray
    lo: np.ndarray
    hi, lo = np.full(n, float(t_hi)), np.zeros(n)
    feasible = ok(hi)
    w, steps = float(t_hi), 0
    while w >= tol:
        w *= 0.5
        steps += 1
    for _ in range(steps):
        mid = 0.5 * (lo + hi)
        f = ok(mid)
        hi = np.where(f, mid, hi)
        lo = np.where(f, lo, mid)
    hi[~feasible] = t_hi
    return hi, reference.min_jerk_closed_form(x0, xf, hi), feasible


def runup_waypoints(
    xf: np.ndarray,
    a_max: float | np.ndarray,
    factors: Sequence[float] = DISTANCE_FACTORS,
    lateral: Sequence[float] = LATERAL,
    min_runup: float = MIN_RUNUP,
) -> np.ndarray:
    """Candidate run-up waypoints (E, O, 3), O = len(factors) x len(lateral) (factor-major):
    ``p - d v_hat + l d u`` with ``d = max(d0, min_runup) f``, ``d0 = |v| max_i |v_i| / (2 a_max)``
    (module docstring)."""
    p, v, a = xf[..., 0], xf[..., 1], xf[..., 2]
    speed = np.linalg.norm(v, axis=1)
    still = speed < 1e-6
    dirn = np.where(still[:, None], p, v)
    dn = np.linalg.norm(dirn, axis=1)
    dirn = np.where((dn < 1e-9)[:, None], np.array([1.0, 0.0, 0.0]), dirn / np.maximum(dn, 1e-12)[:, None])
    # u: the goal acceleration's part perpendicular to v_hat; else a horizontal perpendicular
    a_perp = a - (a * dirn).sum(1, keepdims=True) * dirn
    an = np.linalg.norm(a_perp, axis=1)
    alt = np.cross(dirn, np.array([0.0, 0.0, 1.0]))
    alt = np.where((np.linalg.norm(alt, axis=1) < 1e-6)[:, None], np.array([0.0, 1.0, 0.0]), alt)
    alt /= np.linalg.norm(alt, axis=1, keepdims=True)
    u = np.where((an < 1e-6)[:, None], alt, a_perp / np.maximum(an, 1e-12)[:, None])
    d0 = np.maximum(speed * np.abs(v).max(axis=1) / (2.0 * np.asarray(a_max)), min_runup)
    f = np.asarray(factors, dtype=np.float64)
    lat = np.asarray(lateral, dtype=np.float64)
    d = (d0[:, None] * f[None, :])[:, :, None, None]  # (E, F, 1, 1)
    w = p[:, None, None, :] - d * dirn[:, None, None, :] + d * lat[None, None, :, None] * u[:, None, None, :]
    return w.reshape(len(p), len(f) * len(lat), 3)


# ------------------------------------------------------------------------ flying


def fly(
    goal_vec: np.ndarray,
    coeffs: np.ndarray,
    durations: np.ndarray,
    horizon: int,
    *,
    vehicle: str = "hummingbird",
    fps: int = 100,
    substeps: int = 5,
    record_every: int = 0,
    tol: task.GoalTolerance = task.TOLERANCE,
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Fly N multi-leg references with the clean geometric expert from hover at the origin.

    ``coeffs`` (N, L, 3, 6) and ``durations`` (N, L) s: leg l starts when legs 0..l-1 end;
    at time ``t = k / fps`` the reference is leg l at ``min(t - start_l, T_l)`` (the last
    leg is held at its end). Returns ``(step, near_step, positions)``: the first step
    (1-based: the state after k actions) at which ``goal_reached`` / ``near_success``
    holds, -1 if never within ``horizon`` steps, and every ``record_every``-th position
    (K, N, 3) (None if 0). Stops early once every flight has reached its goal.
    """
    n, L = durations.shape
    params = get_preset(vehicle)
    dt = 1.0 / fps
    ends = np.cumsum(durations, axis=1)
    starts = ends - durations
    sim = BatchedQuadrotor(params, n, dt=dt, substeps=substeps)
    ctrl = GeometricController(params)
    near_tol = tol.scaled(task.NEAR_SUCCESS_SCALE)
    step = np.full(n, -1)
    near_step = np.full(n, -1)
    pos = None
    if record_every:
        pos = np.full((horizon // record_every + 1, n, 3), np.nan)
    state = sim.reset()
    if pos is not None:
        pos[0] = state[:, 0:3]
    rows = np.arange(n)
    for k in range(horizon):
        t = k * dt
        leg = (t > ends[:, :-1]).sum(axis=1) if L > 1 else np.zeros(n, dtype=np.int64)
        tau = np.minimum(t - starts[rows, leg], durations[rows, leg])
        c = coeffs[rows, leg]
        ref = [reference.evaluate(c, tau, order=o) for o in range(4)]
        state = sim.step(ctrl(state, *ref, yaw=0.0))
        ach = task.achieved_goal(state)
        hit = task.goal_reached(ach, goal_vec, tol) & (step < 0)
        step[hit] = k + 1
        hit = task.goal_reached(ach, goal_vec, near_tol) & (near_step < 0)
        near_step[hit] = k + 1
        if pos is not None and (k + 1) % record_every == 0:
            pos[(k + 1) // record_every] = state[:, 0:3]
        if (step > 0).all():
            break
    sim.close()
    return step, near_step, pos


# ------------------------------------------------------------------ feasibility


def _stretched(x0, xf, T, coeffs, ok, bound, stretch):
    """Every reference of (T, coeffs, ok) slowed by each factor of ``stretch`` ->
    (T (N, S), coeffs (N, S, 3, 6), ok (N, S)); a stretched quintic must keep the bound."""
    Ts, cs, oks = [], [], []
    for f in stretch:
        Tf = T * f
        c = coeffs if f == 1.0 else reference.min_jerk_closed_form(x0, xf, Tf)
        keep = ok & (reference.max_acceleration(c, Tf) <= (bound * (1.0 + reference.CF_RTOL))[:, None]).all(axis=1)
        Ts.append(Tf)
        cs.append(c)
        oks.append(keep)
    return np.stack(Ts, axis=1), np.stack(cs, axis=1), np.stack(oks, axis=1)


def _first(step: np.ndarray):
    """Per row of (E, O) first-reach steps (-1 never): (any reached, the earliest option; ties -> lowest index)."""
    reached = step > 0
    return reached.any(axis=1), np.where(reached, step, np.iinfo(np.int64).max).argmin(axis=1)


def feasibility(
    goals: dict,
    horizon_steps: int,
    vehicle: str = "hummingbird",
    fps: int = 100,
    substeps: int = 5,
    a_max: float | None = None,
    *,
    a_spec: float = A_SPEC,
    margin: float = A_MARGIN,
    a_cap: float = A_CAP,
    stretch: Sequence[float] = STRETCH,
    factors: Sequence[float] = DISTANCE_FACTORS,
    lateral: Sequence[float] = LATERAL,
    runup_stretch: Sequence[float] = RUNUP_STRETCH,
    runup: str = "all",
    record_every: int = 0,
    tol: task.GoalTolerance = task.TOLERANCE,
) -> Feasibility:
    """Which of ``goals`` (``{"pos", "vel", "acc"}`` (E, 3), ``"R"`` (E, 3, 3)) the expert reaches
    within ``horizon_steps`` at ``fps``: directly from rest at the origin, and through one
    run-up waypoint (module docstring). ``a_max``: one fixed per-axis bound (m/s^2) instead
    of the per-goal rule :func:`goal_bounds` (``a_spec``, ``margin``, ``a_cap``).
    ``stretch``: the direct reference's durations as multiples of its minimum time (the
    first must be 1); ``factors`` x ``lateral`` x ``runup_stretch``: the run-up grid
    (waypoint distance, lateral offset, second leg's duration / its minimum).
    ``runup``: ``"all"`` flies every goal's run-up options, ``"failed"`` only those of goals
    the direct flights miss (cheaper; the others report ``runup = False``), ``"none"`` none.
    ``record_every > 0`` keeps every that-many-th position of the reported flights.
    """
    t0 = time.perf_counter()
    xf, gv = _goals(goals)
    horizon = _pos_int("horizon_steps", horizon_steps)
    fps = _pos_int("fps", fps)
    substeps = _pos_int("substeps", substeps)
    get_preset(vehicle)
    if isinstance(record_every, bool) or not isinstance(record_every, (int, np.integer)) or record_every < 0:
        raise UserError(f"record_every must be a non-negative integer, got {record_every!r}")
    record_every = int(record_every)
    if runup not in RUNUP_MODES:
        raise UserError(f"runup must be one of {', '.join(RUNUP_MODES)}, got {runup!r}")

    def grid(name, x, positive=True, first_one=False):
        try:
            v = np.atleast_1d(np.asarray(x, dtype=np.float64))
        except (TypeError, ValueError):
            raise UserError(f"{name} must be numbers, got {x!r}") from None
        if v.ndim != 1 or len(v) == 0 or not np.isfinite(v).all() or (positive and not (v > 0).all()):
            raise UserError(f"{name} must be a non-empty list of finite{' positive' if positive else ''} numbers, got {x!r}")
        if first_one and (v[0] != 1.0 or (v < 1.0).any()):
            raise UserError(f"{name} must start at 1 (the minimum time) and not go below it, got {x!r}")
        return v

    stretch = grid("stretch", stretch, first_one=True)
    runup_stretch = grid("runup_stretch", runup_stretch, first_one=True)
    factors = grid("run-up distance factors", factors)
    lateral = grid("run-up lateral offsets", lateral, positive=False)
    E = len(gv)
    idx = np.arange(E)
    t_hi = horizon / fps
    bound = goal_bounds(xf[..., 2], a_max, a_spec=a_spec, margin=margin, a_cap=a_cap)
    fly_kw = dict(vehicle=vehicle, fps=fps, substeps=substeps, record_every=record_every, tol=tol)
    K = horizon // record_every + 1 if record_every else 0

    def fly_some(sel, goal_of, coeffs, durs, n_opt):
        """Fly the flights ``sel`` of an (E * n_opt)-grid -> (step, near) (E, n_opt), positions of sel."""
        step, near = np.full(E * n_opt, -1), np.full(E * n_opt, -1)
        pos = None
        if len(sel):
            step[sel], near[sel], pos = fly(gv[goal_of[sel]], coeffs[sel], durs[sel], horizon, **fly_kw)
        return step.reshape(E, n_opt), near.reshape(E, n_opt), pos

    def chosen_positions(pos, sel, n_opt, have, first):
        if not record_every:
            return None
        out = np.full((K, E, 3), np.nan)
        if len(sel):
            slot = np.full(E * n_opt, -1)
            slot[sel] = np.arange(len(sel))
            j = slot.reshape(E, n_opt)[idx, first]
            have = have & (j >= 0)
            out[:, have] = pos[:, j[have]]
        return out

    # direct: the min-time reference (T_d) and slower ones, each within the bound and the horizon
    x0 = np.zeros_like(xf)
    T_d, c_d, ok_d = min_time(x0, xf, bound, t_hi)
    S = len(stretch)
    Ts, cs, oks = _stretched(x0, xf, T_d, c_d, ok_d, bound, stretch)
    oks &= Ts <= t_hi + 1e-9  # no reference inside the horizon: the expert has no plan to fly
    goal_of = np.repeat(idx, S)
    sel = np.flatnonzero(oks.ravel())
    step_d, near_d, pos = fly_some(sel, goal_of, cs.reshape(E * S, 1, 3, 6), Ts.reshape(E * S, 1), S)
    direct, first_d = _first(step_d)
    pos_d = chosen_positions(pos, sel, S, direct | True, np.where(direct, first_d, 0))

    # run-up: options (E, O) = factors x lateral x second-leg stretch, kept if both legs fit the horizon
    W = runup_waypoints(xf, bound, factors, lateral)  # (E, P, 3)
    P, R = W.shape[1], len(runup_stretch)
    O = P * R
    xw = np.zeros((E * P, 3, 3))
    xw[:, :, 0] = W.reshape(E * P, 3)
    ge = np.repeat(idx, P)
    T1, c1, ok1 = min_time(np.zeros_like(xw), xw, bound[ge], t_hi)
    T2, c2, ok2 = min_time(xw, xf[ge], bound[ge], t_hi)
    T2s, c2s, ok2s = _stretched(xw, xf[ge], T2, c2, ok2, bound[ge], runup_stretch)  # (E * P, R)
    T1s, c1s = np.repeat(T1[:, None], R, axis=1), np.repeat(c1[:, None], R, axis=1)
    valid = (ok1[:, None] & ok2s & (T1s + T2s <= t_hi + 1e-9)).ravel()  # flights ordered (goal, waypoint, stretch)
    fly_goal = {"all": np.ones(E, bool), "failed": ~direct, "none": np.zeros(E, bool)}[runup]
    goal_of = np.repeat(idx, O)
    sel = np.flatnonzero(valid & fly_goal[goal_of])
    coeffs = np.stack([c1s.reshape(E * O, 3, 6), c2s.reshape(E * O, 3, 6)], axis=1)
    durs = np.stack([T1s.ravel(), T2s.ravel()], axis=1)
    step_r, near_r, pos = fly_some(sel, goal_of, coeffs, durs, O)
    any_r, first = _first(step_r)
    legs = durs.reshape(E, O, 2)[idx, first]
    res = Feasibility(
        direct=direct,
        direct_near=(near_d > 0).any(axis=1),
        direct_min_time=step_d[:, 0] > 0,
        direct_min_time_near=near_d[:, 0] > 0,
        runup=any_r,
        runup_near=(near_r > 0).any(axis=1),
        feasible=direct | any_r,
        feasible_near=(near_d > 0).any(axis=1) | (near_r > 0).any(axis=1),
        T_direct=T_d,
        direct_ref=ok_d & (T_d <= t_hi + 1e-9),
        direct_stretch=np.where(direct, stretch[first_d], np.nan),
        direct_step=np.where(direct, step_d[idx, first_d], -1),
        runup_waypoint=np.where(any_r[:, None], W[idx, first // R], np.nan),
        runup_option=np.where(any_r, first, -1),
        runup_T=np.where(any_r[:, None], legs, np.nan),
        runup_step=np.where(any_r, step_r[idx, first], -1),
        a_max=bound,
        horizon=horizon,
        positions_direct=pos_d,
        positions_runup=chosen_positions(pos, sel, O, any_r, first),
        # the four grids were rebound to grid()'s float64 arrays after validation
        options={
            "stretch": cast(np.ndarray, stretch).tolist(),
            "factors": cast(np.ndarray, factors).tolist(),
            "lateral": cast(np.ndarray, lateral).tolist(),
            "runup_stretch": cast(np.ndarray, runup_stretch).tolist(),
            "runup": runup,
        },
    )
    res.seconds = time.perf_counter() - t0
    return res


def ring_feasibility(ring: Ring, n: int, spec: dict, cache: str | Path | None = None) -> dict[str, np.ndarray]:
    """Expert feasibility of a ring's ``n`` test goals (episode-set seed 0, drawn with the
    dataset ``spec``'s goal ranges, vehicle and rates): per goal (E,) bool arrays
    ``direct``, ``runup`` (reached only through a run-up: run-ups are flown for the goals
    the direct flights miss) and ``feasible``. With ``cache`` (a folder) the result is kept
    as ``CACHE/feasibility-RING-nN.json`` and read back from there next time."""
    import json

    from aerohrl import atomic
    from aerohrl.eval.families import sample_ring
    from aerohrl.eval.tasks import DEFAULT_ACC_RANGE, DEFAULT_POS_RANGE, DEFAULT_VEL_RANGE

    f = Path(cache) / f"feasibility-{ring.slug}-n{n}.json" if cache is not None else None
    if f is not None and f.exists():
        return {k: np.array(v) for k, v in json.loads(f.read_text()).items()}
    g = sample_ring(
        ring,
        n,
        0,
        pos_range=tuple(spec.get("pos_range") or DEFAULT_POS_RANGE),
        vel_range=tuple(spec.get("vel_range") or DEFAULT_VEL_RANGE),
        acc_range=tuple(spec.get("acc_range") or DEFAULT_ACC_RANGE),
    )
    # run-ups only for the goals the direct flight misses: "run-up" then counts the goals that need one
    r = feasibility(
        g,
        ring.horizon(),
        vehicle=spec.get("vehicle", "hummingbird"),
        fps=int(spec.get("fps", 100)),
        substeps=int(spec.get("substeps", 5)),
        runup="failed",
    )
    keep = {
        "direct": np.asarray(r.direct).tolist(),
        "runup": (np.asarray(r.runup) & ~np.asarray(r.direct)).tolist(),
        "feasible": np.asarray(r.feasible).tolist(),
    }
    if f is not None:
        atomic.write_text(f, json.dumps(keep))
    return {k: np.array(v) for k, v in keep.items()}
