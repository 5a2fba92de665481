"""The maze tasks and their Gymnasium environment: ``aerohrl/QuadrotorMaze-v0``.

**Tasks** (docs/spec.md "Maze tasks"; frozen with the maze's ``tasks_version``). Each maze of
:mod:`aerohrl.worlds.maze` has five tasks, a start cell and a goal cell each. An episode of
task ``k`` starts in hover above the start cell's centre at flight altitude, perturbed:
horizontal position ``+ U(-0.2, 0.2)`` m per axis (x, y), velocity ``+ U(-0.1, 0.1)`` m/s
per axis, attitude level (``R = I``) and body rates 0. Its goal is hover at the goal cell's
centre ``[p_goal, v = 0, R = I]``, reached by the toolkit's goal-reached test
(:func:`aerohrl.task.goal_reached`: ``0.15`` m, ``0.35`` m/s, ``0.15`` rad). The horizon
is ``SECONDS_PER_CELL`` (2 s) per cell of the task's shortest path plus ``SETTLE_SECONDS``
(2 s), at the simulator's rate: an expert that stops at every corner flies a straight run
of ``L`` cells rest to rest in about ``1.5 sqrt(L)`` s (a minimum-jerk leg at 5 m/s^2),
well inside it. A collision (:meth:`aerohrl.worlds.maze.Maze.collides` of the vehicle's
position, a sphere of 0.25 m against walls, floor and ceiling) at any step ends the
episode as a failure. :func:`maze_episodes` draws the episodes of any of the five tasks,
seeded per (seed, task): the same seed always gives the same episodes.

**Environment**. :class:`QuadrotorMazeVectorEnv` is the reach env
(:class:`~aerohrl.envs.reach.QuadrotorReachVectorEnv`: dict observations ``observation``
(18), ``achieved_goal`` (15), ``desired_goal`` (15), CTBR actions, sparse reward) in a
maze: ``maze=`` (``medium`` | ``large`` | ``giant``, or a :class:`~aerohrl.worlds.maze.Maze`),
``task=`` (1-5) pick the episodes a reset (and an autoreset) draws; a collision
*terminates* the episode with ``info["collision"]`` True and ``info["is_success"]``
False, reward 0. :class:`QuadrotorMazeEnv` is the one-vehicle ``gymnasium.Env``.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, Sequence

import numpy as np

from aerohrl import task as T
from aerohrl.envs import MAZE_ID
from aerohrl.envs.episodes import EpisodeSet, hover_states
from aerohrl.envs.reach import QuadrotorReachEnv, QuadrotorReachVectorEnv
from aerohrl.sim.perturb import Perturbation
from aerohrl.errors import UserError

if TYPE_CHECKING:
    from aerohrl.worlds.maze import Maze

ENV_ID = MAZE_ID  # registered by aerohrl.envs.register
N_TASKS = 5
START_POS_NOISE = 0.2  # m, half-width of the uniform horizontal start offset per axis
START_VEL_NOISE = 0.1  # m/s, half-width of the uniform start velocity per axis
SECONDS_PER_CELL = 2.0  # s of horizon per cell of the task's shortest path
SETTLE_SECONDS = 2.0  # s of horizon on top, to come to rest at the goal
MAZE_SEED_OFFSET = 4_000_037  # the task episodes' seed stream, apart from every dataset's and eval set's


def get_maze(maze: str | Maze) -> Maze:
    """A :class:`~aerohrl.worlds.maze.Maze` from its name (UserError for an unknown one) or itself."""
    from aerohrl.worlds.maze import Maze, load_maze

    return maze if isinstance(maze, Maze) else load_maze(str(maze))


def check_task(maze: Maze, k: Any) -> int:
    """Task number ``k`` (1-based) of ``maze``; UserError unless it is an integer 1..5."""
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not 1 <= int(k) <= len(maze.tasks):
        raise UserError(f"maze task must be an integer 1..{len(maze.tasks)}, got {k!r}")
    return int(k)


def task_goal(maze: Maze, k: int) -> np.ndarray:
    """(15,) the goal of task ``k``: hover at the goal cell's centre ``[p, v = 0, R = I]``."""
    g = np.zeros(T.GOAL_DIM)
    g[T.POS] = maze.cell_center(np.array(maze.tasks[check_task(maze, k) - 1][1]))
    g[T.ROT] = np.eye(3).ravel()
    return g


def task_horizon(maze: Maze, k: int, fps: int = 100) -> int:
    """Steps of task ``k`` (module docstring): 2 s per cell of its shortest path + 2 s, at ``fps``."""
    s, g = maze.tasks[check_task(maze, k) - 1]
    cells = len(maze.shortest_path(s, g)) - 1
    return int(math.ceil((SECONDS_PER_CELL * cells + SETTLE_SECONDS) * fps))


def task_starts(maze: Maze, k: int, n: int, rng: np.random.Generator) -> np.ndarray:
    """(n, 18) start states of task ``k``: hover above the start cell's centre with the
    start noise of the module docstring. UserError when a start lies in a wall."""
    s = hover_states(n)
    s[:, T.POS] = maze.cell_center(np.array(maze.tasks[check_task(maze, k) - 1][0]))
    s[:, 0:2] += rng.uniform(-START_POS_NOISE, START_POS_NOISE, (n, 2))
    s[:, 3:6] = rng.uniform(-START_VEL_NOISE, START_VEL_NOISE, (n, 3))
    if maze.collides(s[:, T.POS]).any():
        raise UserError(f"maze {maze.name} task {k}: its start {tuple(maze.tasks[k - 1][0])} lies in a wall")
    return s


def maze_episodes(
    maze: str | Maze, n_per_task: int = 50, seed: int = 0, *, tasks: Sequence[int] | None = None, fps: int = 100
) -> EpisodeSet:
    """The episodes of the maze tasks (all five, or ``tasks``), ``n_per_task`` each, in task
    order: an :class:`~aerohrl.envs.episodes.EpisodeSet` named ``maze`` whose ``meta``
    holds the maze's layout (``maze``), ``maze_task`` (E,) (1-based) and the horizons per task."""
    m = get_maze(maze)
    if isinstance(n_per_task, bool) or not isinstance(n_per_task, (int, np.integer)) or n_per_task < 1:
        raise UserError(f"episodes per maze task must be a positive integer, got {n_per_task!r}")
    ks = [check_task(m, k) for k in (tasks if tasks is not None else range(1, len(m.tasks) + 1))]
    n = int(n_per_task)
    starts, goals, hz = [], [], []
    for k in ks:  # five tasks: a loop over tasks, each drawn in one batch
        starts.append(task_starts(m, k, n, np.random.default_rng([MAZE_SEED_OFFSET, int(seed), k])))
        goals.append(np.broadcast_to(task_goal(m, k), (n, T.GOAL_DIM)))
        hz.append(np.full(n, task_horizon(m, k, fps), np.int64))
    E = n * len(ks)
    which = np.repeat(np.asarray(ks, np.int64), n)
    return EpisodeSet(
        "maze",
        np.concatenate(starts),
        np.concatenate(goals).astype(np.float64),
        np.concatenate(hz),
        np.full(E, -1, np.int64),
        np.full(E, -1, np.int64),
        np.zeros(E, np.int64),
        int(seed),
        meta={
            "maze": m.to_dict(),
            "maze_task": which,
            "task_horizons": {int(k): task_horizon(m, k, fps) for k in ks},
            "start_pos_noise": START_POS_NOISE,
            "start_vel_noise": START_VEL_NOISE,
            "fps": int(fps),
        },
    )


class QuadrotorMazeVectorEnv(QuadrotorReachVectorEnv):
    """``num_envs`` quadrotors in a maze on one of its tasks; see the module docstring.

    ``maze``: a name or a :class:`~aerohrl.worlds.maze.Maze`; ``task``: 1..5. Resets (and
    autoresets) start at the task's start with its noise and aim at its goal over its
    horizon; ``options`` ``start_states``, ``goals``, ``horizons`` override them as in the
    reach env (the evaluation's batched closed loop flies every task at once that way)."""

    def __init__(
        self,
        num_envs: int = 1,
        *,
        maze: str | Maze = "medium",
        task: int = 1,
        vehicle: str | None = None,
        fps: int | None = None,
        substeps: int | None = None,
        horizon: int | None = None,
        autoreset: bool = True,
        tolerance_scale: float = 1.0,
        render_mode=None,
        perturbation: Perturbation | None = None,
        perturb_seed: int = 0,
    ):
        self.maze = get_maze(maze)
        self.task = check_task(self.maze, task)
        fps_ = int(fps or 100)
        super().__init__(
            num_envs,
            goals=task_goal(self.maze, self.task)[None],
            vehicle=vehicle,
            fps=fps_,
            substeps=substeps,
            horizon=int(horizon or task_horizon(self.maze, self.task, fps_)),
            autoreset=autoreset,
            tolerance_scale=tolerance_scale,
            render_mode=render_mode,
            perturbation=perturbation,
            perturb_seed=perturb_seed,
        )

    def _new_episodes(self, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        starts = task_starts(self.maze, self.task, k, self.np_random)
        goals = np.broadcast_to(task_goal(self.maze, self.task), (k, T.GOAL_DIM)).copy()
        return starts, goals, np.full(k, self.default_horizon, np.int64)

    def _crashed(self, state: np.ndarray) -> np.ndarray:
        return self.maze.collides(state[:, T.POS])


class QuadrotorMazeEnv(QuadrotorReachEnv):
    """One quadrotor in a maze (``gymnasium.make("aerohrl/QuadrotorMaze-v0", maze="large", task=2)``)."""

    def __init__(self, **kw):
        import gymnasium as gym

        kw.pop("num_envs", None)
        gym.Env.__init__(self)
        self._vec = QuadrotorMazeVectorEnv(1, autoreset=False, **kw)
        self.observation_space = self._vec.single_observation_space
        self.action_space = self._vec.single_action_space

    @property
    def maze(self) -> Maze:
        """The maze flown in."""
        return self._vec.maze


__all__ = [
    "QuadrotorMazeVectorEnv",
    "QuadrotorMazeEnv",
    "maze_episodes",
    "task_goal",
    "task_horizon",
    "task_starts",
    "get_maze",
    "check_task",
    "ENV_ID",
    "N_TASKS",
    "START_POS_NOISE",
    "START_VEL_NOISE",
    "SECONDS_PER_CELL",
    "SETTLE_SECONDS",
]
