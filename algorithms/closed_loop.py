"""The trainer's periodic closed-loop evaluation hooks (Reach-Desired or Reach-Novel; the maze tasks on a maze dataset).

The rollout itself is the evaluation harness's (:func:`aerohrl.envs.rollout.rollout`,
through the Gymnasium vector environment), so training-time and ``aerohrl eval``
numbers come from the same code. Reach-Desired (docs/spec.md "Evaluation tasks"): every
vehicle starts at hover at the origin, gets one of the dataset's desired goals and
flies the policy for ``horizon`` steps; success = the goal-reached test holds at some
step (the episode ends there), near success = the same with every tolerance x 2.5.

Reach-Novel (``--eval-task reach-novel``) flies the same way to ``eval_episodes`` *new*
goals drawn from the dataset's own ranges on the task's seed stream
(``task.NOVEL_SEED_OFFSET``, episode-set seed 0): with 250 episodes they are the goals of
``aerohrl eval --task reach-novel``.

On a dataset flown in a maze, the hook flies the maze's five frozen tasks instead
(``aerohrl eval --task maze``, envs/maze.py), ``eval_episodes / 5`` episodes each (at
least one), with collisions ending episodes as failures.

A Reach-Intermediate hook needs the evaluation tasks, so it sits above, with them
(:func:`aerohrl.eval.harness.make_reach_intermediate_evaluator`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Callable

import numpy as np

from aerohrl import task
from aerohrl.envs.rollout import rollout_reach

if TYPE_CHECKING:
    from aerohrl.algorithms.base import Algorithm
    from aerohrl.algorithms.config import TrainConfig
    from aerohrl.algorithms.data import Dataset


def make_reach_desired_evaluator(data: Dataset, cfg: TrainConfig) -> Callable[[Algorithm, int], dict[str, float]]:
    """Reach-Desired on ``cfg.eval_episodes`` of the dataset's desired goals (a fixed,
    seeded subset of those flown from rest at the origin), with the dataset's vehicle and rates."""
    goals = data.desired_goals()[data.rest_start_episodes()].cpu().numpy()
    rng = np.random.default_rng(cfg.seed + 12345)
    pick = rng.choice(len(goals), size=min(cfg.eval_episodes, len(goals)), replace=False)
    return _reach_evaluator(goals[np.sort(pick)], data, cfg)


def make_reach_novel_evaluator(data: Dataset, cfg: TrainConfig) -> Callable[[Algorithm, int], dict[str, float]]:
    """Reach-Novel on ``cfg.eval_episodes`` new goals from the dataset's own goal ranges
    (the task's seed stream, episode-set seed 0, as ``aerohrl eval --task reach-novel``)."""
    from aerohrl.datagen.goals import goal_vectors, sample_goals

    spec = data.info.get("spec") or {}
    ranges = {k: tuple(spec[k]) for k in ("pos_range", "vel_range", "acc_range") if spec.get(k)}
    goals = goal_vectors(sample_goals(np.random.default_rng(task.NOVEL_SEED_OFFSET), cfg.eval_episodes, **ranges))
    return _reach_evaluator(goals, data, cfg)


def _reach_evaluator(goals: np.ndarray, data: Dataset, cfg: TrainConfig) -> Callable[[Algorithm, int], dict[str, float]]:
    """Fly ``goals`` from hover at the origin for ``cfg.eval_horizon`` steps with the dataset's vehicle and rates."""
    spec = data.info.get("spec") or {}
    kw = {
        "vehicle": spec.get("vehicle", "hummingbird"),
        "fps": int(spec.get("fps", 100)),
        "substeps": int(spec.get("substeps", 5)),
    }

    def evaluate(algo, step):
        r = rollout_reach(algo, goals, horizon=cfg.eval_horizon, **kw)
        return {k: v for k, v in r.items() if np.isfinite(v)}

    return evaluate


def make_maze_evaluator(data: Dataset, cfg: TrainConfig) -> Callable[[Algorithm, int], dict[str, float]] | None:
    """The maze tasks of the dataset's maze (None for a free-space dataset): success,
    near success and collision rates over ``cfg.eval_episodes`` episodes spread over the five tasks."""
    from aerohrl.envs.maze import maze_episodes
    from aerohrl.envs.rollout import rollout
    from aerohrl.worlds.maze import world_maze

    maze = world_maze(data.info.get("spec") or {}, data.info)
    if maze is None:
        return None
    spec = data.info.get("spec") or {}
    kw = {
        "vehicle": spec.get("vehicle", "hummingbird"),
        "fps": int(spec.get("fps", 100)),
        "substeps": int(spec.get("substeps", 5)),
    }
    episodes = maze_episodes(maze, max(1, cfg.eval_episodes // 5), seed=cfg.seed, fps=kw["fps"])

    def evaluate(algo, step):
        r = rollout(algo, episodes, maze=maze, **kw)
        return {
            "success": float(r["success"].mean()),
            "near_success": float(r["near_success"].mean()),
            "collision": float(r["collision"].mean()),
        }

    return evaluate


__all__ = ["make_reach_desired_evaluator", "make_reach_novel_evaluator", "make_maze_evaluator"]
