"""The episodes a closed-loop flight needs: :class:`EpisodeSet` and hover start states.

An :class:`EpisodeSet` is everything a closed-loop evaluation needs, fixed before any
policy runs: per episode a start state (18), a goal (15) and a horizon (steps), plus
where they came from (dataset episode, start frame, steps ahead). The evaluation tasks
that build them from a dataset are :mod:`aerohrl.eval.tasks`; the batched closed loop
that flies them is :func:`aerohrl.envs.rollout.rollout`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from aerohrl import task


@dataclass
class EpisodeSet:
    """The episodes of one task (all arrays have ``n`` rows)."""

    task: str
    start_states: np.ndarray  # (n, 18) float64
    goals: np.ndarray  # (n, 15) float64
    horizons: np.ndarray  # (n,) int64, steps
    source_episode: np.ndarray  # (n,) int64, dataset episode (-1: none)
    start_frame: np.ndarray  # (n,) int64, frame within that episode (-1: none)
    steps_ahead: np.ndarray  # (n,) int64, achieved goal this many steps ahead (0: desired goal / none)
    seed: int = 0
    meta: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.goals)

    def kind(self) -> np.ndarray:
        """Per episode: 'desired', 'intermediate', 'ood', 'fast' or, for the maze tasks, 'task<k>' (k = 1..5)."""
        if self.task in ("ood", "fast"):
            return np.full(len(self), self.task)
        if self.task == "maze":
            return np.char.add("task", np.asarray(self.meta["maze_task"]).astype(str))
        return np.where(self.steps_ahead > 0, "intermediate", "desired")


def hover_states(n: int) -> np.ndarray:
    """``n`` hover states at the origin (n, 18): zero position, velocity and rates, ``R = I``."""
    s = np.zeros((n, task.STATE_DIM))
    s[:, task.ROT] = np.eye(3).ravel()
    return s


__all__ = ["EpisodeSet", "hover_states"]
