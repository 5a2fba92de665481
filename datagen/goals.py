"""Desired goals rho_D of the reach task (thesis §3.4.1, docs/spec.md "Expert data").

A goal is a full flat state ``(p, v, a)`` plus the attitude the vehicle must have to
hold that acceleration (differential flatness, yaw 0). Per axis independently:

* position: ``|p_i| ~ U(pos_range)`` with a random sign (``pos_range = (1, 2)`` m for
  rho_D; the OOD evaluation set uses ``(2, 3.5)`` with another seed);
* velocity: ``v_i ~ U(vel_range)`` (default ``(-2.5, 2.5)`` m/s);
* acceleration: ``a_i ~ U(acc_range)`` (default ``(-5, 5)`` m/s^2).

The draws are made in a fixed order from the caller's ``numpy.random.Generator``
(|p|, sign, v, a; each ``(n, 3)``), so goals are a function of the seed and the call
sequence alone.

Attitude from flatness (:func:`flat_attitude`). The thrust must point along the
mass-normalised force ``f = a + g e3`` (world z up, ``g = 9.81``). With yaw ``psi``:

    z_B = f / |f|
    x_C = [cos psi, sin psi, 0]          (heading direction in the horizontal plane)
    y_B = (z_B x x_C) / |z_B x x_C|
    x_B = y_B x z_B
    R   = [x_B  y_B  z_B]                (columns; maps body to world)

``R`` is then a proper rotation (det +1) whose body x axis is the projection of
``x_C`` onto the plane orthogonal to ``z_B``. The map is singular when ``f = 0``
(free fall) or when ``z_B`` is parallel to ``x_C`` (thrust horizontal along the
heading); both raise :class:`~aerohrl.errors.UserError`. With the default
acceleration range ``f_z >= 9.81 - 5 > 0``, so neither happens for sampled goals.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from aerohrl import task
from aerohrl.errors import UserError
from aerohrl.sim.params import GRAVITY  # one value everywhere, docs/spec.md "Units and frames"

_SINGULAR = 1e-9  # |f| or |z_B x x_C| below this is treated as singular


def check_range(name: str, r: Any, *, non_negative: bool = False) -> tuple[float, float]:
    """``(low, high)`` of the range ``r`` named ``name``: two finite numbers, ``low < high``
    (and ``low >= 0`` with ``non_negative``); else a one-line UserError naming it."""
    try:
        lo, hi = (float(x) for x in r)
    except (TypeError, ValueError):
        raise UserError(f"{name} needs two numbers (LOW, HIGH), got {r!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi)):
        raise UserError(f"{name} needs two finite numbers, got ({lo}, {hi})")
    if not lo < hi:
        raise UserError(f"{name} is empty or inverted: {lo} .. {hi} (need LOW < HIGH)")
    if non_negative and lo < 0:
        raise UserError(f"{name} bounds |p_i| and must be non-negative, got ({lo}, {hi})")
    return lo, hi


def flat_attitude(acc: np.ndarray, yaw: float | np.ndarray = 0.0) -> np.ndarray:
    """Attitude that produces acceleration ``acc`` at yaw ``yaw`` (differential flatness).

    ``acc``: (..., 3) world-frame acceleration (m/s^2, gravity *not* included: the map
    uses ``f = acc + g e3``). ``yaw``: scalar or array broadcastable to ``acc.shape[:-1]``
    (rad). Returns ``R`` (..., 3, 3), float64, columns ``[x_B, y_B, z_B]`` (see the
    module docstring for the construction). Pure function; the expert's desired
    attitude uses the same map with its commanded acceleration.
    """
    a = np.asarray(acc, dtype=np.float64)
    if a.ndim == 0 or a.shape[-1] != 3:
        raise UserError(f"flat_attitude needs accelerations of shape (..., 3), got {a.shape}")
    psi = np.asarray(yaw, dtype=np.float64)
    if not (np.isfinite(a).all() and np.isfinite(psi).all()):
        raise UserError("flat_attitude got non-finite accelerations or yaw")
    f = a.copy()
    f[..., 2] += GRAVITY
    fn = np.linalg.norm(f, axis=-1, keepdims=True)
    if (fn < _SINGULAR).any():
        raise UserError(
            f"flat_attitude: {int((fn < _SINGULAR).sum())} acceleration(s) equal -g e3 (free fall); attitude undefined"
        )
    z_b = f / fn
    psi = np.broadcast_to(psi, a.shape[:-1])
    x_c = np.stack([np.cos(psi), np.sin(psi), np.zeros_like(psi)], axis=-1)
    y_b = np.cross(z_b, x_c)
    yn = np.linalg.norm(y_b, axis=-1, keepdims=True)
    if (yn < _SINGULAR).any():
        raise UserError(
            f"flat_attitude: {int((yn < _SINGULAR).sum())} thrust direction(s) parallel to the heading; attitude undefined"
        )
    y_b = y_b / yn
    x_b = np.cross(y_b, z_b)
    return np.stack([x_b, y_b, z_b], axis=-1)


def sample_goals(
    rng: np.random.Generator,
    n: int,
    *,
    pos_range: tuple[float, float] = (1.0, 2.0),
    vel_range: tuple[float, float] = (-2.5, 2.5),
    acc_range: tuple[float, float] = (-5.0, 5.0),
    yaw: float = 0.0,
) -> dict[str, np.ndarray]:
    """Sample ``n`` desired goals: ``{"pos", "vel", "acc"}`` (n, 3) and ``"R"`` (n, 3, 3).

    All float64. See the module docstring for the distribution and the attitude.
    Raises :class:`UserError` for ``n <= 0`` or an empty, inverted or non-finite range
    (``pos_range`` bounds ``|p_i|`` and must be non-negative).
    """
    if not isinstance(rng, np.random.Generator):
        raise UserError(f"sample_goals needs a numpy.random.Generator, got {type(rng).__name__}")
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n <= 0:
        raise UserError(f"number of goals must be a positive integer, got {n!r}")
    p_lo, p_hi = check_range("pos_range", pos_range, non_negative=True)
    v_lo, v_hi = check_range("vel_range", vel_range)
    a_lo, a_hi = check_range("acc_range", acc_range)
    yaw = float(yaw)
    if not math.isfinite(yaw):
        raise UserError(f"yaw must be finite, got {yaw}")
    n = int(n)
    mag = rng.uniform(p_lo, p_hi, size=(n, 3))
    sign = np.where(rng.integers(0, 2, size=(n, 3)) == 1, 1.0, -1.0)
    pos = mag * sign
    vel = rng.uniform(v_lo, v_hi, size=(n, 3))
    acc = rng.uniform(a_lo, a_hi, size=(n, 3))
    return {"pos": pos, "vel": vel, "acc": acc, "R": flat_attitude(acc, yaw)}


def goal_vectors(goals: dict) -> np.ndarray:
    """Goals as the task layout ``[p(3), v(3), R(9) row-major]`` -> (n, 15) float64."""
    try:
        pos, vel, R = (np.asarray(goals[k], dtype=np.float64) for k in ("pos", "vel", "R"))
    except KeyError as e:
        raise UserError(f"goals lack the key {e.args[0]!r} (need pos, vel, R)") from None
    n = pos.shape[0] if pos.ndim == 2 else -1
    if pos.shape != (n, 3) or vel.shape != (n, 3) or R.shape != (n, 3, 3):
        raise UserError(f"goal arrays disagree: pos {pos.shape}, vel {vel.shape}, R {R.shape} (need (n,3), (n,3), (n,3,3))")
    out = np.concatenate([pos, vel, R.reshape(n, 9)], axis=1)
    assert out.shape[1] == task.GOAL_DIM
    return out
