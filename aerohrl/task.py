"""The reach task's vocabulary, shared by datagen, algorithms and eval (docs/spec.md).

Layouts (SI units, world frame z-up, rotation matrices flattened row-major):

* state ``s = [p(3), v(3), R(9), w(3)]`` (18), absolute, ``w`` in the body frame;
* goal ``g = [p(3), v(3), R(9)]`` (15), absolute; the *achieved goal* of a step is the
  ``[p, v, R]`` part of the next state;
* action ``a = [c, wx, wy, wz]`` (4): CTBR, mass-normalised collective thrust (m/s^2)
  and commanded body rates (rad/s).

Translation invariance (thesis §3.4.2): the networks see the state without its
position, ``o = [v, R, w]`` (15), and the goal relative to the current position,
``[p_g - p, v_g, R_g]`` (15).

Goal reached (thesis §3.4.2, docs/spec.md): ``||p - p_g|| <= 0.15 m``,
``||v - v_g|| <= 0.35 m/s`` and the geodesic angle between ``R`` and ``R_g``
``<= 0.15 rad``; near success scales every tolerance by 2.5.

Every function works on NumPy arrays and on torch tensors alike (leading batch
dimensions are free), so the same test decides expert success, relabelled rewards
and evaluation outcomes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, TypeVar

if TYPE_CHECKING:
    import numpy as np
    import torch

    # every function takes NumPy arrays or torch tensors (module docstring) and returns the same kind
    Array = TypeVar("Array", np.ndarray, torch.Tensor)

STATE_DIM = 18
GOAL_DIM = 15
OBS_DIM = 15
ACTION_DIM = 4

POS = slice(0, 3)
VEL = slice(3, 6)
ROT = slice(6, 15)
RATE = slice(15, 18)

STATE_NAMES = ["px", "py", "pz", "vx", "vy", "vz"] + [f"R{i}{j}" for i in range(3) for j in range(3)] + ["wx", "wy", "wz"]
GOAL_NAMES = STATE_NAMES[:GOAL_DIM]
ACTION_NAMES = ["c", "wx_cmd", "wy_cmd", "wz_cmd"]

NEAR_SUCCESS_SCALE = 2.5

# Reach-Novel's goals: fresh draws from the dataset's own ranges, on the seed stream
# NOVEL_SEED_OFFSET + seed (apart from any dataset's goal seeds); `aerohrl eval` and the
# trainer's periodic hook draw the same set
NOVEL_SEED_OFFSET = 2_000_003


@dataclass(frozen=True)
class GoalTolerance:
    """Tolerances of the goal-reached test (thesis §3.4.2: eps_p, eps_v, eps_r)."""

    pos: float = 0.15
    vel: float = 0.35
    rot: float = 0.15

    def scaled(self, k: float) -> "GoalTolerance":
        """Every tolerance multiplied by ``k`` (near success: ``k = 2.5``)."""
        return GoalTolerance(self.pos * k, self.vel * k, self.rot * k)


TOLERANCE = GoalTolerance()


def _is_torch(x) -> bool:
    return type(x).__module__.startswith("torch")


def _cat(parts, axis=-1):
    if _is_torch(parts[0]):
        import torch

        return torch.cat(parts, dim=axis)
    import numpy as np

    return np.concatenate(parts, axis=axis)


def achieved_goal(state: Array) -> Array:
    """``[p, v, R]`` of a state (18) -> goal (15)."""
    return state[..., :GOAL_DIM]


def policy_inputs(state: Array, goal: Array) -> tuple[Array, Array]:
    """Translation-invariant network inputs: ``([v, R, w], [p_g - p, v_g, R_g])``."""
    obs = state[..., 3:STATE_DIM]
    rel = _cat([goal[..., POS] - state[..., POS], goal[..., 3:GOAL_DIM]])
    return obs, rel


def rotation_cosine(R_flat: Array, Rg_flat: Array) -> Array:
    """cos of the geodesic angle between two flattened rotations: (tr(R^T R_g) - 1) / 2."""
    return (((R_flat * Rg_flat).sum(-1)) - 1.0) * 0.5


def goal_errors(achieved: Array, goal: Array) -> tuple[Array, Array, Array]:
    """Position error (m), velocity error (m/s) and geodesic rotation angle (rad)."""
    dp = ((achieved[..., POS] - goal[..., POS]) ** 2).sum(-1) ** 0.5
    dv = ((achieved[..., VEL] - goal[..., VEL]) ** 2).sum(-1) ** 0.5
    c = rotation_cosine(achieved[..., ROT], goal[..., ROT]).clip(-1.0, 1.0)
    if _is_torch(c):
        ang = c.arccos()  # type: ignore[attr-defined]  # (mypy checks this branch for arrays too)
    else:
        import numpy as np

        ang = np.arccos(c)  # type: ignore[assignment]
    return dp, dv, ang


def goal_reached(achieved: Array, goal: Array, tol: GoalTolerance = TOLERANCE) -> Array:
    """The goal-reached test (boolean per leading index).

    The rotation condition is checked as ``cos(angle) >= cos(eps_r)``, equivalent to
    ``angle <= eps_r`` and free of arccos's poor conditioning near zero.
    """
    dp2 = ((achieved[..., POS] - goal[..., POS]) ** 2).sum(-1)
    dv2 = ((achieved[..., VEL] - goal[..., VEL]) ** 2).sum(-1)
    c = rotation_cosine(achieved[..., ROT], goal[..., ROT])
    return (dp2 <= tol.pos**2) & (dv2 <= tol.vel**2) & (c >= math.cos(tol.rot))


def near_success(achieved: Array, goal: Array, tol: GoalTolerance = TOLERANCE) -> Array:
    """The goal-reached test with every tolerance x 2.5 (thesis §3.5)."""
    return goal_reached(achieved, goal, tol.scaled(NEAR_SUCCESS_SCALE))
