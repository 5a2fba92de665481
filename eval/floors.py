"""Trivial floors a learned skill is read against (``aerohrl eval --floor hover|no-goal``).

* ``hover``: the constant CTBR command ``[g, 0, 0, 0]`` (thrust that carries the weight,
  zero body rates), whatever the goal. It "reaches" every goal the start state already
  meets or drifts into: on Reach-Intermediate the goals a few steps ahead (31.2 % of the
  thesis's episode mix), and some far ahead too (likely, not verified
  on the trajectories: from a moving, tilted start the held attitude and thrust keep
  accelerating the way the expert was, which extrapolates its path). The evaluation
  therefore also reports success on the goals this floor misses
  (``success_beyond_hover``, eval/results.py ``kind_rates``).
* ``no-goal``: the run's learned policy with its goal inputs held at the dataset's mean
  (the normalised relative-goal features set to 0), so it acts on the state alone: what
  the policy does without goal information, the floor of goal conditioning.

Both wrap a trained algorithm in the interface the closed loop uses (``act``,
``normalizer``, ``parameters``, ``train``/``eval``), so the harness, the tables and the
plots treat a floor like any other policy.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import torch
from torch import nn

from aerohrl import task
from aerohrl.sim.params import GRAVITY

if TYPE_CHECKING:
    from aerohrl.algorithms.base import Algorithm

FLOORS = ("none", "hover", "no-goal")


class _Floor(nn.Module):
    """A policy built on a trained algorithm ``inner``, sharing its normaliser (which the
    closed loop's action clip reads)."""

    def __init__(self, algo):
        super().__init__()
        self.inner = algo
        self.normalizer = algo.normalizer


class HoverPolicy(_Floor):
    """``act(s, g) = [g, 0, 0, 0]``, whatever the goal."""

    @torch.no_grad()
    def act(self, state: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
        """Hover thrust ``[g, 0, 0, 0]`` (B, 4) for every state (B, 18), whatever the goal (B, 15)."""
        a = torch.zeros(state.shape[0], task.ACTION_DIM, dtype=state.dtype, device=state.device)
        a[:, 0] = GRAVITY
        return a


class NoGoalPolicy(_Floor):
    """The wrapped policy with its normalised relative-goal inputs set to 0 (their mean)."""

    @torch.no_grad()
    def act(self, state: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
        """The wrapped policy's action (B, 4) with its normalised relative-goal inputs zeroed."""
        x = self.normalizer.inputs(state, goal)
        x[:, task.OBS_DIM :] = 0.0
        return self.normalizer.action_from_unit(self.inner.policy_unit(x))


def wrap(algo: Algorithm, floor: str) -> nn.Module:
    """``algo`` itself (``floor == "none"``) or the floor policy built on it."""
    if floor == "none":
        return algo
    return {"hover": HoverPolicy, "no-goal": NoGoalPolicy}[floor](algo)


__all__ = ["FLOORS", "HoverPolicy", "NoGoalPolicy", "wrap"]
