"""Episode sets of the evaluation tasks (docs/spec.md "Evaluation tasks", thesis §3.5).

Each task maker returns an :class:`~aerohrl.envs.episodes.EpisodeSet`: everything a
closed-loop evaluation needs, fixed before any policy runs (per episode a start state,
a goal, a horizon and where they came from). Sets are a function of the dataset and the
seed alone, so every checkpoint of every algorithm flies the same episodes.

* ``reach-desired``: hover at the origin, a desired goal of rho_D (the dataset's
  episodes' goals), horizon 500. With ``n`` equal to the dataset's goal count (250)
  every goal is flown once, in order; otherwise a seeded draw (without replacement
  while possible).
* ``reach-intermediate``: a seeded expert episode and a start frame ``j`` uniform on it;
  the start state is that frame's state. One third of the episodes (``round(n/3)``, the
  first ones) aim at the trajectory's desired goal with horizon 500; the other two
  thirds at the achieved goal ``d`` steps ahead, ``d`` uniform in ``1..min(45, steps
  left)`` (the achieved goal of frame ``j+d-1`` = the state at ``j+d``), horizon 100.
* ``ood``: hover at the origin, goals outside rho_D: ``|p_i| ~ U(2, 3.5)`` m per axis
  with a random sign, velocity and acceleration from the dataset's spec ranges (the
  SPEC defaults when the dataset has none), attitude by flatness, drawn with
  :func:`aerohrl.datagen.goals.sample_goals` from seed ``OOD_SEED_OFFSET + seed`` (a
  different stream from any dataset seed). Horizon 1000 steps (two legs of 500: the
  thesis flies to one intermediate goal, then to G) for every variant, with or without
  planner, so that they are compared at equal flight time (see eval/README.md).
* ``reach-novel`` (a diagnostic beyond the SPEC): hover at the origin, *new* goals drawn
  from rho_D itself (the dataset spec's position, velocity and acceleration ranges) with
  seed stream ``NOVEL_SEED_OFFSET + seed``, horizon 500: Reach-Desired on goals the
  policy was not trained on, i.e. generalisation within the training distribution
  rather than recall of the dataset's 250 trajectories.
* ``fast`` (free space): hover at the origin, goals with fast velocities, ``|v_i| ~ U(3.5,
  7)`` m/s per axis with a random sign (beyond rho_D's 2.5 m/s), position and acceleration
  from the dataset's ranges, attitude by flatness: a custom ring of the ``velocity`` family
  (:func:`aerohrl.eval.families.sample_ring`, its own seed stream), horizon 1000 steps (the
  velocity family's).
* ``maze`` (maze datasets only): the five frozen tasks of the dataset's maze
  (:func:`aerohrl.envs.maze.maze_episodes`: start hover at the start cell's centre with
  +-0.2 m horizontal and +-0.1 m/s start noise, goal hover at the goal cell's centre,
  horizon 2 s per cell of the shortest path + 2 s); ``n`` episodes split evenly among
  the five tasks (a multiple of 5; the default 250 gives 50 per task). A collision ends
  an episode as a failure.

Every task but ``maze`` is a free-space task: :func:`check_fits` refuses a free-space task
on a maze dataset and ``maze`` on a free-space one (one-line errors).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from aerohrl import task
from aerohrl.envs.episodes import EpisodeSet, hover_states
from aerohrl.errors import UserError

if TYPE_CHECKING:
    from aerohrl.algorithms.data import Dataset
    from aerohrl.eval.families import Ring
    from aerohrl.worlds.maze import Maze

TASKS = ("reach-desired", "reach-intermediate", "ood", "reach-novel", "fast", "maze")
FAST_VEL_RANGE = (3.5, 7.0)  # m/s, |v_i| of the fast task's goals
FAST_HORIZON = 1000  # steps: the velocity family's horizon (eval/families.py)
HORIZON_DESIRED = 500
HORIZON_INTERMEDIATE = 100
MAX_AHEAD = 45
OOD_POS_RANGE = (2.0, 3.5)
OOD_SEED_OFFSET = 1_000_003
NOVEL_SEED_OFFSET = task.NOVEL_SEED_OFFSET
DEFAULT_POS_RANGE = (1.0, 2.0)
DEFAULT_VEL_RANGE = (-2.5, 2.5)
DEFAULT_ACC_RANGE = (-5.0, 5.0)


def _check_n(n) -> int:
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise UserError(f"the number of episodes must be a positive integer, got {n!r}")
    return int(n)


def _episode_bounds(data) -> tuple[np.ndarray, np.ndarray]:
    """(starts, ends) global frame indices (ends inclusive) of every dataset episode."""
    ends = np.unique(data.episode_end.cpu().numpy())
    starts = np.concatenate([[0], ends[:-1] + 1])
    return starts, ends


def _pick(rng: np.random.Generator, pool: int, n: int) -> np.ndarray:
    if pool < 1:
        raise UserError("the goal set is empty (the dataset holds no episodes)")
    if n == pool:
        return np.arange(pool)
    if n < pool:
        return np.sort(rng.choice(pool, size=n, replace=False))
    return np.concatenate([np.arange(pool), rng.choice(pool, size=n - pool, replace=True)])


def reach_desired(data: Dataset, n: int = 250, seed: int = 0) -> EpisodeSet:
    """Reach-Desired (docs/spec.md): origin -> a desired goal of the dataset, 500 steps.

    The goals are those of the episodes the expert flew from rest at the origin (all of
    a default dataset; continuation episodes start elsewhere, so theirs are not
    demonstrated from this start)."""
    n = _check_n(n)
    rest = data.rest_start_episodes().cpu().numpy()
    goals = data.desired_goals().cpu().numpy().astype(np.float64)[rest]
    idx = _pick(np.random.default_rng([seed, 1]), len(goals), n)
    return EpisodeSet(
        "reach-desired",
        hover_states(n),
        goals[idx],
        np.full(n, HORIZON_DESIRED, np.int64),
        rest[idx].astype(np.int64),
        np.zeros(n, np.int64),
        np.zeros(n, np.int64),
        seed,
    )


def reach_intermediate(data: Dataset, n: int = 250, seed: int = 0, max_ahead: int = MAX_AHEAD) -> EpisodeSet:
    """Reach-Intermediate (docs/spec.md): start on an expert trajectory; 1/3 to its desired
    goal (500 steps), 2/3 to the achieved goal <= ``max_ahead`` steps ahead (100 steps)."""
    n = _check_n(n)
    starts, ends = _episode_bounds(data)
    if len(starts) < 1:
        raise UserError("the goal set is empty (the dataset holds no episodes)")
    rng = np.random.default_rng([seed, 2])
    ep = rng.integers(0, len(starts), size=n)
    length = ends[ep] - starts[ep] + 1
    j = np.floor(rng.random(n) * length).astype(np.int64)  # frame within the episode
    left = length - j  # achieved goals at frames j..end: 1..left steps ahead
    d = 1 + np.floor(rng.random(n) * np.minimum(max_ahead, left)).astype(np.int64)
    n_desired = int(round(n / 3))
    d[:n_desired] = 0
    frame = starts[ep] + j
    state = data.state.cpu().numpy().astype(np.float64)[frame]
    desired = data.goal.cpu().numpy().astype(np.float64)[frame]
    achieved = task.achieved_goal(data.next_state.cpu().numpy().astype(np.float64)[np.maximum(frame + d - 1, frame)])
    goals = np.where((d > 0)[:, None], achieved, desired)
    horizons = np.where(d > 0, HORIZON_INTERMEDIATE, HORIZON_DESIRED).astype(np.int64)
    return EpisodeSet(
        "reach-intermediate",
        state,
        goals,
        horizons,
        ep.astype(np.int64),
        j,
        d,
        seed,
        meta={"max_ahead": int(max_ahead), "n_desired": n_desired},
    )


def ood_goals(
    n: int,
    seed: int = 0,
    *,
    pos_range: tuple[float, float] = OOD_POS_RANGE,
    vel_range: tuple[float, float] | None = None,
    acc_range: tuple[float, float] | None = None,
    stream: int = OOD_SEED_OFFSET,
) -> np.ndarray:
    """(n, 15) out-of-distribution goals (docs/spec.md "ood"); another ``pos_range`` and
    ``stream`` give other goal sets (``reach-novel``)."""
    from aerohrl.datagen.goals import goal_vectors, sample_goals

    n = _check_n(n)
    g = sample_goals(
        np.random.default_rng(stream + int(seed)),
        n,
        pos_range=pos_range,
        vel_range=vel_range or DEFAULT_VEL_RANGE,
        acc_range=acc_range or DEFAULT_ACC_RANGE,
    )
    return goal_vectors(g)


def reach_novel(data: Dataset | None, n: int = 250, seed: int = 0) -> EpisodeSet:
    """Reach-Novel (diagnostic): origin -> a *new* goal from the dataset's own ranges, 500 steps."""
    spec = (data.info.get("spec") or {}) if data is not None else {}
    pos = tuple(spec.get("pos_range") or DEFAULT_POS_RANGE)
    goals = ood_goals(
        n, seed, pos_range=pos, vel_range=spec.get("vel_range"), acc_range=spec.get("acc_range"), stream=NOVEL_SEED_OFFSET
    )
    n = len(goals)
    return EpisodeSet(
        "reach-novel",
        hover_states(n),
        goals,
        np.full(n, HORIZON_DESIRED, np.int64),
        np.full(n, -1, np.int64),
        np.full(n, -1, np.int64),
        np.zeros(n, np.int64),
        seed,
        meta={"pos_range": list(pos), "seed_stream": NOVEL_SEED_OFFSET + int(seed)},
    )


def ood(data: Dataset | None, n: int = 250, seed: int = 0, leg_horizon: int = HORIZON_DESIRED, legs: int = 2) -> EpisodeSet:
    """OOD (docs/spec.md): origin -> a goal with |p_i| in [2, 3.5] m; ``legs * leg_horizon`` steps in all."""
    spec = (data.info.get("spec") or {}) if data is not None else {}
    goals = ood_goals(n, seed, vel_range=spec.get("vel_range"), acc_range=spec.get("acc_range"))
    n = len(goals)
    return EpisodeSet(
        "ood",
        hover_states(n),
        goals,
        np.full(n, leg_horizon * legs, np.int64),
        np.full(n, -1, np.int64),
        np.full(n, -1, np.int64),
        np.zeros(n, np.int64),
        seed,
        meta={
            "leg_horizon": int(leg_horizon),
            "legs": int(legs),
            "pos_range": list(OOD_POS_RANGE),
            "seed_stream": OOD_SEED_OFFSET + int(seed),
        },
    )


def ood_family(data: Dataset | None, n: int = 250, seed: int = 0, *, ring: Ring, horizon: int | None = None) -> EpisodeSet:
    """OOD goals of a family ring (eval/families.py): origin -> a goal that leaves rho_D
    along the ring's dimensions, the others from the dataset's ranges; ``horizon`` steps
    (default: the ring's, scaled to the distance)."""
    from aerohrl.datagen.goals import goal_vectors
    from aerohrl.eval.families import sample_ring

    spec = (data.info.get("spec") or {}) if data is not None else {}
    g = sample_ring(
        ring,
        n,
        seed,
        pos_range=tuple(spec.get("pos_range") or DEFAULT_POS_RANGE),
        vel_range=tuple(spec.get("vel_range") or DEFAULT_VEL_RANGE),
        acc_range=tuple(spec.get("acc_range") or DEFAULT_ACC_RANGE),
    )
    goals = goal_vectors(g)
    n = len(goals)
    h = int(horizon or ring.horizon())
    return EpisodeSet(
        "ood",
        hover_states(n),
        goals,
        np.full(n, h, np.int64),
        np.full(n, -1, np.int64),
        np.full(n, -1, np.int64),
        np.zeros(n, np.int64),
        seed,
        meta={
            "leg_horizon": h,
            "legs": 1,
            "family": ring.family,
            "ring": ring.index,
            "ranges": {k: list(v) for k, v in ring.ranges.items()},
            "goal_acc": g["acc"],
        },
    )


def fast(data: Dataset | None, n: int = 250, seed: int = 0) -> EpisodeSet:
    """Fast (free space): origin -> a goal with ``|v_i|`` in [3.5, 7] m/s, 1000 steps."""
    from aerohrl.eval.families import Ring

    ring = Ring("velocity", 0, {"vel": FAST_VEL_RANGE})
    eps = ood_family(data, n, seed, ring=ring, horizon=FAST_HORIZON)
    eps.task = "fast"
    eps.meta.pop("leg_horizon", None)
    return eps


def dataset_maze(data: Dataset | None) -> Maze | None:
    """The maze a dataset was flown in (its spec's ``world``, the recorded layout), None for free space."""
    from aerohrl.worlds.maze import world_maze

    info = data.info if data is not None else {}
    return world_maze(info.get("spec") or {}, info)


def check_fits(name: str, data: Dataset | None) -> Maze | None:
    """UserError (one line) when task ``name`` does not fit the dataset's world (``maze`` on
    free space, a free-space task in a maze); returns the dataset's maze (None: free space)."""
    maze = dataset_maze(data)
    if name == "maze" and maze is None:
        spec = (data.info.get("spec") or {}) if data is not None else {}
        raise UserError(
            f"--task maze needs a run trained on a maze dataset (world maze-*); "
            f"dataset {spec.get('name') or (data.info.get('path') if data is not None else None)} flies in free space"
        )
    if name != "maze" and maze is not None:
        raise UserError(f"--task {name} is a free-space task; the run's dataset flies in maze {maze.name}: use --task maze")
    return maze


def maze(data: Dataset | None, n: int = 250, seed: int = 0) -> EpisodeSet:
    """Maze (module docstring): the five frozen tasks of the dataset's maze, ``n / 5`` episodes each."""
    from aerohrl.envs.maze import maze_episodes

    n = _check_n(n)
    m = check_fits("maze", data)
    assert m is not None  # check_fits refuses free space
    k = len(m.tasks)
    if n % k:
        raise UserError(f"--task maze flies its {k} tasks equally: --episodes must be a multiple of {k}, got {n}")
    spec = (data.info.get("spec") or {}) if data is not None else {}
    return maze_episodes(m, n // k, seed, fps=int(spec.get("fps", 100)))


def make_episodes(name: str, data: Dataset | None, n: int = 250, seed: int = 0, **kw: Any) -> EpisodeSet:
    """The episode set of task ``name`` (one of :data:`TASKS`); UserError when it does not fit the dataset's world."""
    if name not in TASKS:
        raise UserError(f"unknown task {name!r} (choose from {', '.join(TASKS)})")
    check_fits(name, data)
    fn = {
        "reach-desired": reach_desired,
        "reach-intermediate": reach_intermediate,
        "ood": ood,
        "reach-novel": reach_novel,
        "fast": fast,
        "maze": maze,
    }[name]
    return fn(data, n, seed, **kw)


__all__ = [
    "TASKS",
    "make_episodes",
    "fast",
    "maze",
    "check_fits",
    "dataset_maze",
    "reach_desired",
    "reach_intermediate",
    "ood",
    "ood_family",
    "reach_novel",
    "ood_goals",
]
