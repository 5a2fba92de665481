"""Evaluate a training run: the last K checkpoints x one episode set (thesis Table 3.1 protocol).

:func:`evaluate_run` loads the run's dataset (``config.json``; ``dataset=`` overrides the
path when the data moved), checks that every evaluated checkpoint was trained on
exactly that dataset (version, manifest checksum, feature shapes), builds the task's
episodes once (seeded: every checkpoint and algorithm flies the same ones), and for
each checkpoint runs the batched closed loop (:func:`aerohrl.envs.rollout.rollout`),
writing per-episode records and a summary under ``RUN/eval/<task>[-<planner>]/``
(:mod:`aerohrl.eval.results`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, fields
from pathlib import Path
from types import MappingProxyType
from typing import TYPE_CHECKING, Any, Callable

import numpy as np

from aerohrl import atomic
from aerohrl.config import param, validate
from aerohrl.errors import UserError
from aerohrl.eval.tasks import TASKS

if TYPE_CHECKING:
    from aerohrl.algorithms.base import Algorithm
    from aerohrl.datagen.dataset import DatasetHandle
    from aerohrl.algorithms.config import TrainConfig
    from aerohrl.algorithms.data import Dataset
    from aerohrl.algorithms.run import Run
    from aerohrl.eval.families import Ring
    from aerohrl.envs.episodes import EpisodeSet
    from aerohrl.planning.graph import GraphPlanner
    from aerohrl.planning.planner import ChainPlanner, Planner
    from aerohrl.planning.subgoals import SubgoalPlanner
    from aerohrl.sim.perturb import Perturbation

PLANNERS = ("none", "single", "multi", "graph", "subgoal")
# graph: a plan has as many intermediate goals as its shortest path needs, up to this many
# (a shorter plan repeats its last goal, reached at once), and each leg its own budget
GRAPH_WAYPOINTS = 32
GRAPH_LEG_HORIZON = 400  # steps (100 Hz): a leg of a few cells, with re-planning from the flown state
PLANNED_TASKS = ("ood", "maze")  # the tasks a planner may fly
OOD_HORIZON = 1000  # the thesis's OOD flight: two legs of 500 steps, planned or not


FLOORS = ("none", "hover", "no-goal")  # = eval/floors.py FLOORS (which loads torch)


def _perturb_part(text: str) -> str:
    """``-perturb-<slug>`` of a ``--perturb`` text; nothing for a nominal one (it flies the nominal model)."""
    from aerohrl.sim.perturb import Perturbation

    p = Perturbation.parse(text)
    return "" if p.nominal else "-perturb-" + p.slug()


def _in_name(f: Any, rank: int, part: str | Callable[[Any], str], planned: bool = False) -> Any:
    """The param field ``f`` whose value, when it differs from the default, adds
    ``part.format(value)`` (or ``part(value)`` for a function) to the result folder's name
    (:meth:`EvalOptions.name`) at position ``rank``; ``planned``: only when a planner flies
    (``planner`` is not none)."""
    f.metadata = MappingProxyType({**f.metadata, "name_part": (rank, part, planned)})
    return f


@dataclass
class EvalOptions:
    """The settings of one evaluation (``aerohrl eval`` flags). The result folder's name
    (:meth:`name`) is the task, the planner and every option marked with its name part
    that differs from its default, so that each variant has a folder of its own."""

    task: str = param("reach-desired", "evaluation task (eval/tasks.py)", choices=TASKS)
    episodes: int = param(250, "episodes per checkpoint", ge=1)
    checkpoints: int = param(10, "newest checkpoints evaluated", ge=1)
    planner: str = param(
        "none",
        "ood and maze: none (fly straight) | single (Eq. 3.7) | multi (Eq. 3.6, beam search) | graph (Eq. 3.6 exactly, "
        "shortest paths over the candidates, planning/graph.py) | subgoal (a hierarchical agent's high-level "
        "subgoals snapped to the candidates, planning/subgoals.py); in a maze over the free cells' centres",
        choices=PLANNERS,
    )
    waypoints: int = param(2, "multi: intermediate goals (Eq. 3.6 n)", ge=1)
    beam: int = param(8, "multi: beam width", ge=1)
    alpha: float = _in_name(param(1.0, "variance penalty of Eq. 3.6/3.7", ge=0), 3, "-a{:g}", planned=True)
    candidates: int = param(1024, "achieved goals scored by the planner (seeded subset; 0 = all)", ge=0)
    max_edge: float = _in_name(
        param(0.0, "graph: legs longer than this are no edges, a roadmap's connection radius (0: none)", unit="m", ge=0),
        4,
        "-edge{:g}",
        planned=True,
    )
    legs: str = _in_name(
        param(
            "any",
            "graph in a maze: any legs (within --max-edge) | corridor (only along straight free corridors, Maze.in_corridor)",
            choices=("any", "corridor"),
        ),
        4,
        "-{}",
        planned=True,
    )
    replan: bool = param(True, "multi: re-plan the remaining goals at each reached intermediate goal")
    replan_every: int = _in_name(
        param(
            0, "re-plan from the current state every K simulator steps during intermediate legs (0: never)", unit="steps", ge=0
        ),
        1,
        "-replan{}",
        planned=True,
    )
    # horizon None: 1000 steps in 2 legs of 500, or a family ring's own
    horizon: int | None = param(None, "ood: simulator steps per episode (100 Hz: 1000 = 10 s), every planner", unit="steps", ge=1)
    family: str | None = param(None, "ood: goals that leave rho_D along one axis (eval/families.py)")
    ring: str | None = param(None, "ood --family: step 1..K of the family, or a range LO:HI of |x_i| (m, m/s or m/s^2)")
    leg_horizon: int = param(
        0, "ood: budget to reach an intermediate goal (0: horizon / (intermediate goals + 1))", unit="steps", ge=0
    )
    waypoint_tol: float = _in_name(
        param(1.0, "an intermediate goal is reached with the goal tolerances x this (2.5: near success)", gt=0),
        2,
        "-tol{:g}",
        planned=True,
    )
    floor: str = _in_name(
        param(
            "none",
            "fly a trivial floor instead of the run's policy: hover (constant [g, 0, 0, 0]) | "
            "no-goal (the policy with its goal inputs at their mean); results go to <task>-floor-<floor>",
            choices=FLOORS,
        ),
        8,
        "-floor-{}",
    )
    goal_tol: float = _in_name(
        param(
            1.0,
            "the task goal's tolerances x this (0.5: 0.075 m, 0.175 m/s, 0.075 rad; results go to <task>-goaltol0.5)",
            gt=0,
            le=10,
        ),
        7,
        "-goaltol{:g}",
    )
    decline_margin: float | None = _in_name(
        param(
            None,
            "planner: fly straight to G where the plan's score <= V(s0, G) + M "
            "(flying straight stays a candidate; results go to "
            "ood-<planner>-decline<M>)",
        ),
        5,
        "-decline{:g}",
        planned=True,
    )
    min_leg: float = _in_name(
        param(0.0, "planner: skip candidates closer than this to the start as first goal (0: none skipped)", unit="m", ge=0),
        4,
        "-minleg{:g}",
        planned=True,
    )
    candidate_source: str = _in_name(
        param(
            "dataset",
            "planner: dataset achieved goals | synthetic offsets chained from the start (far goals, ChainPlanner)",
            choices=("dataset", "synthetic"),
        ),
        6,
        "-synth",
        planned=True,
    )
    waypoints_from: str = _in_name(
        param(
            "cells",
            "maze --planner graph: intermediate goals at hover over the free cells' centres (cells) | the "
            "dataset's achieved goals, a seeded subset of --candidates, joined by legs no wall crosses "
            "(data: search on the replay buffer, Eysenbach et al. 2019: waypoints the data flies through, "
            "at its speeds)",
            choices=("cells", "data"),
        ),
        0,
        "-{}",
        planned=True,
    )
    perturb: str | None = _in_name(
        param(
            None,
            'fly on a perturbed vehicle: NAME=VALUE[,NAME=VALUE...] of docs/spec.md "Perturbations" '
            "(e.g. mass=1.2,latency=0.02); results go to <task>-perturb-<mass1.2-latency0.02>",
        ),
        9,
        _perturb_part,
    )
    seed: int = param(0, "episode-set seed (and the perturbation's gusts and noise)", ge=0)
    device: str = param("cpu", "torch device")
    record: bool = param(True, "keep the trajectories of the newest checkpoint (for plots)", flag=False)
    mcap_episode: int | None = param(
        None,
        "also write episode N as the newest checkpoint flew it: OUT/flown-episode-N-step-S.mcap (Foxglove)",
        ge=0,
    )
    progress: bool = param(True, "progress bars", flag=False)
    dataset: str | None = param(None, "the run's dataset at another path (identity is checked)")
    out: str | None = param(None, "result folder (none: RUN/eval/<name>)")
    extra: dict = field(default_factory=dict, metadata={"help": "free-form notes", "flag": False})

    def ring_def(self) -> Ring | None:
        """The :class:`~aerohrl.eval.families.Ring` of ``family``/``ring`` (None: the thesis's OOD set)."""
        if self.family is None:
            return None
        from aerohrl.eval.families import parse_ring

        return parse_ring(self.family, self.ring if self.ring is not None else "1")

    def name(self) -> str:
        """The evaluation's folder name under ``RUN/eval/``: the task (for ood: ``ood``, a
        family ring's slug, the planner and, for multi, its waypoints), then the name part
        of every option that differs from its default, in rank order."""
        planned = self.task in PLANNED_TASKS and self.planner != "none"
        if self.task == "maze":
            head = "maze" + (f"-{self.planner}" + (f"{self.waypoints}" if self.planner == "multi" else "") if planned else "")
        elif self.task == "ood" and self.planner == "graph":
            ring = self.ring_def()
            head = "ood-" + (ring.slug + "-" if ring is not None else "") + "graph"
        elif self.task != "ood":
            head = self.task
        else:
            ring = self.ring_def()
            head = (
                "ood-"
                + (ring.slug + "-" if ring is not None else "")
                + self.planner
                + (f"{self.waypoints}" if self.planner == "multi" else "")
            )
        parts = []
        for f in fields(self):
            if "name_part" not in f.metadata:
                continue
            rank, part, needs_planner = f.metadata["name_part"]
            value = getattr(self, f.name)
            if value != f.default and (planned or not needs_planner):
                parts.append((rank, part(value) if callable(part) else part.format(value)))
        if planned and self.waypoints_from == "data":  # the candidate count names the waypoint set
            parts = [(r, f"-data{self.candidates}" if x == "-data" else x) for r, x in parts]
        return head + "".join(p for _, p in sorted(parts))


def perturbation(text: str | None) -> Perturbation | None:
    """The :class:`~aerohrl.sim.perturb.Perturbation` of ``--perturb`` (None: the nominal model);
    UserError (one line) for a bad one."""
    from aerohrl.sim.perturb import Perturbation

    if not text:
        return None
    p = Perturbation.parse(text)
    return None if p.nominal else p


def run_checkpoints(run_dir: str | Path | Run, k: int) -> list[Path]:
    """The last ``k`` checkpoints of a run, oldest first; UserError without a run or checkpoints."""
    from aerohrl.algorithms.run import Run

    run = Run.open(run_dir, kind="train")
    paths = run.checkpoints()
    if not paths:
        raise UserError(f"run {run.path} has no checkpoints ({run.layout.glob})")
    if k < 1:
        raise UserError(f"--checkpoints must be >= 1, got {k}")
    return paths[-k:]


def load_run_dataset(
    run_dir: str | Path | Run, override: str | Path | None = None, cache: dict[Path, Dataset] | None = None
) -> tuple[Dataset, dict]:
    """The run's dataset (``config.json``; found by version under ``datasets/`` when it
    moved), or ``override``; identity checked against the run. Returns (data, config.json).
    ``cache`` (path -> data): runs of one dataset share one copy in memory (seeds of a
    recipe; a 25,000-goal dataset holds about a gigabyte)."""
    from aerohrl.algorithms.data import load_dataset
    from aerohrl.algorithms.run import Run, check_same_dataset

    run = Run.open(run_dir, kind="train")
    meta = run.meta
    path = run.locate_dataset(override)  # the recorded path, else found by version, else "pass --dataset"
    if cache is None:
        data = load_dataset(path)
    else:
        key = Path(path).resolve()
        if key not in cache:
            cache[key] = load_dataset(path)
        data = cache[key]
    try:
        check_same_dataset(meta.get("dataset") or {}, data)
    except UserError as e:
        raise UserError(f"dataset {path} does not belong to run {run_dir}: {e}") from None
    return data, meta


def open_run_dataset(run_dir: str | Path | Run) -> DatasetHandle:
    """The run's dataset opened for its metadata only (spec, manifest; no frames read, no
    checksums): for tools that fly the run's world or expert rather than its data."""
    from aerohrl.algorithms.run import Run
    from aerohrl.datagen.dataset import open_dataset

    return open_dataset(Run.open(run_dir, kind="train").locate_dataset(), verify=False)


def check_checkpoint_dataset(ck: dict, data: Dataset, path: str | Path) -> None:
    """UserError (one line) when the checkpoint at ``path`` was trained on another dataset
    than ``data`` (feature shapes or version)."""
    from aerohrl.algorithms.run import check_same_dataset

    try:
        check_same_dataset(ck.get("dataset") or {}, data)
    except UserError as e:
        raise UserError(f"checkpoint {path} and dataset {data.info.get('path')} do not belong together: {e}") from None


def sim_kwargs(data: Dataset) -> dict:
    """The simulator settings of the dataset's spec: ``vehicle``, ``fps``, ``substeps``."""
    spec = data.info.get("spec") or {}
    return {
        "vehicle": spec.get("vehicle", "hummingbird"),
        "fps": int(spec.get("fps", 100)),
        "substeps": int(spec.get("substeps", 5)),
    }


def graph_waypoints(opt: EvalOptions) -> int:
    """The graph planner's bound on intermediate goals: ``--waypoints`` when given, else :data:`GRAPH_WAYPOINTS`."""
    default = next(f.default for f in fields(EvalOptions) if f.name == "waypoints")
    return opt.waypoints if opt.waypoints != default else GRAPH_WAYPOINTS


def make_planner(
    algo: Algorithm, data: Dataset, opt: EvalOptions
) -> tuple[Planner | ChainPlanner | GraphPlanner | SubgoalPlanner | None, int]:
    """The planner of ``opt.planner`` over ``data``'s achieved goals (or synthetic offsets,
    or a maze's free cells) and its number of intermediate goals; ``(None, 0)`` without one."""
    from aerohrl.planning.planner import Planner, candidates_from_dataset, candidates_from_maze

    if opt.planner == "none":
        return None, 0
    maze = None
    if opt.task == "maze":  # waypoints: hover at the free cells' centres of the dataset's maze
        from aerohrl.eval.tasks import dataset_maze

        maze = dataset_maze(data)
        assert maze is not None  # build_episodes refused --task maze on free space
    if opt.planner == "subgoal":  # the high level's own choice among the maze's free cells or the dataset's goals
        from aerohrl.planning.subgoals import SubgoalPlanner

        cand = candidates_from_maze(maze) if maze is not None else candidates_from_dataset(data, opt.candidates, seed=opt.seed)
        n = graph_waypoints(opt)
        try:
            return SubgoalPlanner(algo, cand, n=n, min_leg=opt.min_leg), n
        except ValueError as e:
            raise UserError(f"--planner subgoal: {e}") from None
    if maze is not None:
        if opt.planner == "graph":
            from aerohrl.planning.graph import GraphPlanner

            n = graph_waypoints(opt)
            if opt.waypoints_from == "data":
                cand, edge_filter = candidates_from_dataset(data, opt.candidates, seed=opt.seed), maze.segment_clear
            else:
                cand, edge_filter = candidates_from_maze(maze), (maze.in_corridor if opt.legs == "corridor" else None)
            return GraphPlanner(
                algo,
                cand,
                n=n,
                alpha=opt.alpha,
                max_edge=opt.max_edge,
                min_leg=opt.min_leg,
                edge_filter=edge_filter,
            ), n
        n = 1 if opt.planner == "single" else opt.waypoints
        return Planner(algo, candidates_from_maze(maze), n=n, alpha=opt.alpha, beam=opt.beam, min_leg=opt.min_leg), n
    if opt.planner == "graph":
        if opt.candidate_source == "synthetic":
            raise UserError("--planner graph plans over the dataset's achieved goals; it takes no --candidate-source synthetic")
        from aerohrl.planning.graph import GraphPlanner

        n = graph_waypoints(opt)
        cand = candidates_from_dataset(data, opt.candidates, seed=opt.seed)
        return GraphPlanner(algo, cand, n=n, alpha=opt.alpha, max_edge=opt.max_edge, min_leg=opt.min_leg), n
    if opt.candidate_source == "synthetic":  # C = --candidates offsets (0: 256) from the dataset spec's ranges
        from aerohrl.planning.planner import ChainPlanner, offsets_from_spec

        n = 1 if opt.planner == "single" else opt.waypoints
        off = offsets_from_spec(data.info.get("spec"), opt.candidates or 256, seed=opt.seed)
        return ChainPlanner(algo, off, n=n, alpha=opt.alpha, beam=opt.beam), n
    cand = candidates_from_dataset(data, opt.candidates, seed=opt.seed)
    n = 1 if opt.planner == "single" else opt.waypoints
    return Planner(algo, cand, n=n, alpha=opt.alpha, beam=opt.beam, min_leg=opt.min_leg), n


def check_options(opt: EvalOptions) -> None:
    """UserError (one line) for a setting out of its declared range or choices
    (:func:`aerohrl.config.validate`), or options that contradict each other."""
    validate(opt)
    if opt.planner != "none" and opt.task not in PLANNED_TASKS:
        raise UserError(f"--planner {opt.planner} applies to --task ood only (and to --task maze)")
    if opt.task == "maze" and opt.candidate_source != "dataset":
        raise UserError("--task maze plans over the maze's free cells; it takes no --candidate-source")
    if opt.legs != "any" and not (opt.task == "maze" and opt.planner == "graph"):
        raise UserError("--legs corridor applies to --task maze with --planner graph only")
    if opt.waypoints_from != "cells" and not (opt.task == "maze" and opt.planner == "graph"):
        raise UserError("--waypoints-from data applies to --task maze with --planner graph only")
    if opt.waypoints_from == "data" and opt.legs == "corridor":
        raise UserError("--waypoints-from data joins the waypoints by legs no wall crosses; it takes no --legs corridor")
    if opt.planner == "multi" and opt.waypoints < 2:
        raise UserError(f"--planner multi needs --waypoints >= 2, got {opt.waypoints}")
    if opt.floor != "none" and opt.planner != "none":
        raise UserError("--floor replaces the policy; it takes no --planner")
    if (opt.family is not None or opt.ring is not None) and opt.task != "ood":
        raise UserError("--family / --ring apply to --task ood only")
    if opt.ring is not None and opt.family is None:
        raise UserError("--ring needs --family (position | velocity | acceleration | combined)")
    opt.ring_def()  # one-line errors for unknown families and bad rings
    perturbation(opt.perturb)  # one-line errors for unknown axes and values out of range


def build_episodes(data: Dataset, opt: EvalOptions) -> EpisodeSet:
    """The episode set of ``opt.task`` (starts, goals, horizons) on ``data``'s goals."""
    from aerohrl.eval.tasks import check_fits, make_episodes

    check_fits(opt.task, data)  # maze tasks on maze datasets, free-space tasks on free-space ones
    goals = int(data.rest_start_episodes().numel())
    if opt.task == "reach-desired" and opt.episodes > goals:  # a repeated goal would be flown the same way again
        raise UserError(
            f"--episodes {opt.episodes} exceeds the {goals} desired goals of dataset {data.info.get('path')} "
            f"(reach-desired flies each goal once); pass --episodes {goals} or fewer"
        )

    kw = {}
    ring = opt.ring_def()
    if ring is not None:  # a family's ring: its own horizon (scaled to distance) unless --horizon is given
        from aerohrl.eval.tasks import ood_family

        return ood_family(data, opt.episodes, opt.seed, ring=ring, horizon=opt.horizon)
    if opt.task == "ood":
        # every OOD variant flies the same goals with the same total time
        kw = {"leg_horizon": opt.horizon or OOD_HORIZON, "legs": 1}
    return make_episodes(opt.task, data, opt.episodes, opt.seed, **kw)


def fly(
    algo: Algorithm,
    episodes: EpisodeSet,
    data: Dataset,
    opt: EvalOptions,
    *,
    record: bool = False,
    record_states: bool = False,
    desc: str = "rollout",
) -> dict:
    """One checkpoint's flight of ``episodes`` with the planner ``opt`` asks for (legs of
    ``opt.leg_horizon`` steps, else the horizon shared among the legs) on the dataset's
    vehicle: :func:`aerohrl.envs.rollout.rollout`'s per-episode results (``record_states``:
    with every state and action flown)."""
    from aerohrl.envs.rollout import rollout
    from aerohrl.eval.tasks import dataset_maze

    planner, nw = make_planner(algo, data, opt)
    # graph, subgoal: legs of their own budget (the plan's length varies), re-planning at each goal reached
    if opt.planner in ("graph", "subgoal"):
        leg_h = opt.leg_horizon or GRAPH_LEG_HORIZON
    else:
        leg_h = opt.leg_horizon or max(1, int(episodes.horizons.max()) // (nw + 1))
    return rollout(
        algo,
        episodes,
        planner=planner,
        n_waypoints=nw,
        leg_horizon=leg_h,
        replan=opt.replan,
        replan_every=opt.replan_every,
        waypoint_tol=opt.waypoint_tol,
        goal_tol=opt.goal_tol,
        decline_margin=opt.decline_margin,
        record=record,
        record_states=record_states,
        progress=opt.progress,
        desc=desc,
        maze=dataset_maze(data) if episodes.task == "maze" else None,
        perturbation=perturbation(opt.perturb),
        perturb_seed=opt.seed,
        **sim_kwargs(data),
    )


def write_flown_mcap(out_dir: str | Path, step: int, episode: int, r: dict, fps: int) -> Path:
    """Episode ``episode`` of a flight recorded with ``record_states`` (:func:`fly`) as
    ``OUT/flown-episode-N-step-S.mcap``: the vehicle's states, the goal the policy flew to,
    its actions and, per step, the task goal's test; returns the path."""
    from aerohrl.datagen.mcap_export import EPOCH_NS, write_flight_mcap

    n = int(r["steps"][episode])
    states = r["states"][episode, : n + 1]
    goals = r["policy_goals"][episode, : n + 1]
    reached = np.zeros(n, bool)
    if r["success"][episode]:
        reached[int(r["first_success_step"][episode]) - 1 :] = True
    path = Path(out_dir) / f"flown-episode-{episode}-step-{step:09d}.mcap"
    path.parent.mkdir(parents=True, exist_ok=True)
    write_flight_mcap(
        path,
        states,
        goals,
        r["actions"][episode, :n],
        np.arange(n + 1, dtype=np.int64) * round(1e9 / fps) + EPOCH_NS,
        episode_index=np.full(n, episode),
        frame_index=np.arange(n),
        reward=reached.astype(float),
        done=reached,
        success=reached,
    )
    return path


def evaluate_run(run_dir: str | Path, opt: EvalOptions, loaded: tuple[Dataset, dict] | None = None) -> dict:
    """Evaluate the last ``opt.checkpoints`` checkpoints of ``run_dir``; returns the summary.
    ``loaded``: ``(data, meta)`` of :func:`load_run_dataset` for this run, when a study
    evaluates one run many times (a large dataset is then loaded once)."""
    from tqdm import tqdm

    from aerohrl.algorithms.base import load_policy
    from aerohrl.algorithms.run import Run
    from aerohrl.algorithms.trainer import resolve_device
    from aerohrl.envs.rollout import rollout
    from aerohrl.eval import results
    from aerohrl.eval.floors import wrap as wrap_floor

    check_options(opt)
    run = Run.open(run_dir, kind="train")
    ckpts = run_checkpoints(run, opt.checkpoints)
    if opt.floor == "hover":  # the same constant command at every checkpoint: fly it once
        ckpts = ckpts[-1:]
    device = resolve_device(opt.device)
    data, meta = loaded if loaded is not None else load_run_dataset(run, opt.dataset)
    episodes = build_episodes(data, opt)
    if opt.mcap_episode is not None and opt.mcap_episode >= len(episodes):
        raise UserError(f"--mcap-episode {opt.mcap_episode}: the task has {len(episodes)} episodes (0..{len(episodes) - 1})")
    out_dir = Path(opt.out) if opt.out else run.path / "eval" / opt.name()
    atomic.remove_stale_temporaries(out_dir)  # left by an evaluation that was killed while writing
    per_ckpt = []
    hover_success = None  # Reach-Intermediate: the hover floor's outcomes on these episodes (kind_rates)
    t_start = time.perf_counter()
    bar = tqdm(
        ckpts, desc=f"eval {opt.name()}", unit="ckpt", disable=None if opt.progress else True, dynamic_ncols=True
    )  # None: only on a terminal
    for i, path in enumerate(bar):
        algo, ck = load_policy(path, device, run)
        check_checkpoint_dataset(ck, data, path)
        if hover_success is None and episodes.task == "reach-intermediate" and opt.floor != "hover":  # one flight, ~1 s
            hover_success = rollout(
                wrap_floor(algo, "hover"),
                episodes,
                goal_tol=opt.goal_tol,
                perturbation=perturbation(opt.perturb),
                perturb_seed=opt.seed,
                **sim_kwargs(data),
            )["success"]
        algo = wrap_floor(algo, opt.floor)
        record = opt.record and i == len(ckpts) - 1
        flown = opt.mcap_episode is not None and i == len(ckpts) - 1
        t0 = time.perf_counter()
        r = fly(algo, episodes, data, opt, record=record, record_states=flown, desc=f"step {ck['step']}")
        wall = time.perf_counter() - t0
        results.write_episodes(out_dir, int(ck["step"]), episodes, r)
        per_ckpt.append(
            {
                "checkpoint": path.name,
                "step": int(ck["step"]),
                "success": float(r["success"].mean()),
                "near_success": float(r["near_success"].mean()),
                **({"collision": float(r["collision"].mean())} if episodes.task == "maze" else {}),
                "seconds": wall,
                **({"declined": float(r["declined"].mean())} if "declined" in r else {}),
                **results.kind_rates(episodes, r, r["success"] if opt.floor == "hover" else hover_success),
            }
        )
        bar.set_postfix(success=f"{per_ckpt[-1]['success']:.3f}")
        if flown:
            assert opt.mcap_episode is not None
            write_flown_mcap(out_dir, int(ck["step"]), opt.mcap_episode, r, int(sim_kwargs(data)["fps"]))
        if record:
            results.write_trajectories(out_dir, int(ck["step"]), episodes, r)
            if episodes.task == "maze":  # the top-down maze with the flown paths
                from aerohrl.eval.plots import plot_maze

                plot_maze(episodes, r, out_dir / "maze.png", title=f"{opt.name()}, step {ck['step']}")
    summary = results.summarize(
        per_ckpt, run_dir=run.path, meta=meta, options=opt, episodes=episodes, seconds=time.perf_counter() - t_start
    )
    results.write_summary(out_dir, summary)
    if episodes.task == "maze":
        results.write_text(out_dir / "tasks.md", results.maze_table_markdown(summary))
    return summary


def make_reach_intermediate_evaluator(
    data: Dataset, cfg: TrainConfig, episodes: int | None = None
) -> Callable[[Algorithm, int], dict[str, float]]:
    """Reach-Intermediate (docs/spec.md; thesis Fig. 3.4: 75 episodes, a third to the desired
    goal with 500 steps, two thirds to an achieved goal <= 45 steps ahead with 100 steps)
    on a fixed, seeded episode set; default ``3 * cfg.eval_episodes`` episodes: a trainer
    evaluation hook (``Trainer(..., evaluators={"reach_intermediate": ...})``)."""
    from aerohrl.envs.rollout import rollout
    from aerohrl.eval.tasks import reach_intermediate

    eps = reach_intermediate(data, episodes or 3 * cfg.eval_episodes, seed=cfg.seed + 12345)
    spec = data.info.get("spec") or {}
    kw = {
        "vehicle": spec.get("vehicle", "hummingbird"),
        "fps": int(spec.get("fps", 100)),
        "substeps": int(spec.get("substeps", 5)),
    }

    def evaluate(algo, step):
        r = rollout(algo, eps, **kw)
        return {"success": float(r["success"].mean()), "near_success": float(r["near_success"].mean())}

    return evaluate


def critics_auc(run_dir: str | Path) -> float:
    """How well a run's critics know which goals its policy reaches: the ROC AUC of the
    ensemble's take-off value ``mean_j Q_j(s0, pi(s0, g), g)`` for success on the run's
    Reach-Novel evaluation (``RUN/eval/reach-novel/``, newest checkpoint; NaN when that
    checkpoint has not been evaluated there). UserError when the evaluated goals are not
    the task's (the dataset moved or changed)."""
    import csv
    from types import SimpleNamespace

    import torch

    from aerohrl import task
    from aerohrl.algorithms.base import load_policy
    from aerohrl.algorithms.run import read_json
    from aerohrl.datagen.dataset import open_dataset
    from aerohrl.planning.oracle import roc_auc
    from aerohrl.eval.tasks import reach_novel

    run_dir = Path(run_dir)
    ck = run_checkpoints(run_dir, 1)[-1]
    f = run_dir / "eval" / "reach-novel" / f"episodes-{ck.stem}.csv"
    if not f.exists():
        return float("nan")
    with open(f) as fh:
        rows = list(csv.DictReader(fh))
    success = np.array([int(r["success"]) for r in rows], bool)
    goals = np.array([[float(r[f"goal_{n}"]) for n in task.GOAL_NAMES] for r in rows])
    spec = open_dataset(read_json(run_dir / "config.json")["dataset"]["path"], verify=False).spec  # its ranges: the task's goals
    eps = reach_novel(SimpleNamespace(info={"spec": spec}), len(success), 0)
    if not np.allclose(eps.goals, goals):
        raise UserError(f"{f}: its Reach-Novel goals are not the task's (the dataset moved or changed?)")
    algo, _ = load_policy(ck)
    s = torch.as_tensor(eps.start_states, dtype=torch.float32)
    g = torch.as_tensor(eps.goals, dtype=torch.float32)
    v = algo.critics(s, g, algo.act(s, g)).mean(0).numpy()
    return roc_auc(v, success)


__all__ = [
    "EvalOptions",
    "evaluate_run",
    "fly",
    "run_checkpoints",
    "load_run_dataset",
    "critics_auc",
    "PLANNERS",
    "make_reach_intermediate_evaluator",
]
