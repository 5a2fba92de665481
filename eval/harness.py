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
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Callable

import numpy as np

from aerohrl import atomic
from aerohrl.errors import UserError

if TYPE_CHECKING:
    from aerohrl.algorithms.base import Algorithm
    from aerohrl.algorithms.config import TrainConfig
    from aerohrl.algorithms.data import Dataset
    from aerohrl.algorithms.run import Run
    from aerohrl.eval.families import Ring
    from aerohrl.envs.episodes import EpisodeSet
    from aerohrl.planning.planner import ChainPlanner, Planner

PLANNERS = ("none", "single", "multi")
OOD_HORIZON = 1000  # the thesis's OOD flight: two legs of 500 steps, planned or not


@dataclass
class EvalOptions:
    task: str = "reach-desired"
    episodes: int = 250
    checkpoints: int = 10
    planner: str = "none"  # none | single (Eq. 3.7) | multi (Eq. 3.6, beam search)
    waypoints: int = 2  # multi: intermediate goals
    beam: int = 8
    alpha: float = 1.0
    candidates: int = 1024  # 0 = every achieved goal of the dataset
    replan: bool = True  # multi: re-plan the remaining goals at each reached intermediate goal
    replan_every: int = 0  # also re-plan every K steps during intermediate legs (0: never)
    horizon: int | None = None  # ood: total steps of every variant (none | single | multi); None: 1000 (2 legs of 500), a family ring's own
    family: str | None = None  # ood: a goal family of eval/families.py (None: the thesis's OOD set)
    ring: str | None = None  # ood --family: a 1-based step of the family, or LO:HI (eval/families.py)
    leg_horizon: int = 0  # ood: step budget of an intermediate leg (0: horizon // (intermediate goals + 1))
    waypoint_tol: float = 1.0  # an intermediate goal counts as reached with the tolerances x this
    floor: str = "none"  # none | hover | no-goal: a trivial floor instead of the learned policy (eval/floors.py)
    goal_tol: float = 1.0  # the task goal's tolerances x this (0.5: the precision variant; 1: the thesis's test)
    decline_margin: float | None = None  # planner: fly straight where plan score <= direct score + this (None: never)
    min_leg: float = 0.0  # planner: candidates closer than this (m) to the start are not chosen first (0: all)
    candidate_source: str = "dataset"  # planner: dataset (achieved goals) | synthetic (chains of offsets, ChainPlanner)
    seed: int = 0
    device: str = "cpu"
    record: bool = True  # keep trajectories of the newest checkpoint (for plots)
    progress: bool = True
    dataset: str | None = None
    out: str | None = None  # default RUN/eval/<name>
    extra: dict = field(default_factory=dict)

    def ring_def(self) -> Ring | None:
        """The :class:`~aerohrl.eval.families.Ring` of ``family``/``ring`` (None: the thesis's OOD set)."""
        if self.family is None:
            return None
        from aerohrl.eval.families import parse_ring

        return parse_ring(self.family, self.ring if self.ring is not None else "1")

    def name(self) -> str:
        """The evaluation's folder name under ``RUN/eval/``: task, planner and the options that
        differ from the defaults."""
        ring = self.ring_def()
        if ring is not None:  # ood-<family>-<ring>-<planner>...: a family's ring, planned or not
            return "ood-" + ring.slug + "-" + self._ood_name()[len("ood-"):]
        return self._ood_name()

    def _ood_name(self) -> str:
        tol = (f"-goaltol{self.goal_tol:g}" if self.goal_tol != 1.0 else "") + (f"-floor-{self.floor}" if self.floor != "none" else "")
        return self.task + tol if self.task != "ood" else f"ood-{self.planner}" + (f"{self.waypoints}" if self.planner == "multi" else "") \
            + (f"-replan{self.replan_every}" if self.replan_every and self.planner != "none" else "") \
            + (f"-tol{self.waypoint_tol:g}" if self.waypoint_tol != 1.0 and self.planner != "none" else "") \
            + (f"-a{self.alpha:g}" if self.alpha != 1.0 and self.planner != "none" else "") \
            + (f"-minleg{self.min_leg:g}" if self.min_leg > 0 and self.planner != "none" else "") \
            + (f"-decline{self.decline_margin:g}" if self.decline_margin is not None and self.planner != "none" else "") \
            + ("-synth" if self.candidate_source == "synthetic" and self.planner != "none" else "") + tol


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


def load_run_dataset(run_dir: str | Path | Run, override: str | Path | None = None) -> tuple[Dataset, dict]:
    """The run's dataset (``config.json``; found by version under ``datasets/`` when it
    moved), or ``override``; identity checked against the run. Returns (data, config.json)."""
    from aerohrl.algorithms.data import load_dataset
    from aerohrl.algorithms.run import Run, check_same_dataset

    run = Run.open(run_dir, kind="train")
    meta = run.meta
    path = run.locate_dataset(override)  # the recorded path, else found by version, else "pass --dataset"
    data = load_dataset(path)
    try:
        check_same_dataset(meta.get("dataset") or {}, data)
    except UserError as e:
        raise UserError(f"dataset {path} does not belong to run {run_dir}: {e}") from None
    return data, meta


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
    return {"vehicle": spec.get("vehicle", "hummingbird"), "fps": int(spec.get("fps", 100)), "substeps": int(spec.get("substeps", 5))}


def make_planner(algo: Algorithm, data: Dataset, opt: EvalOptions) -> tuple[Planner | ChainPlanner | None, int]:
    """The planner of ``opt.planner`` over ``data``'s achieved goals (or synthetic offsets)
    and its number of intermediate goals; ``(None, 0)`` without one."""
    from aerohrl.planning.planner import Planner, candidates_from_dataset

    if opt.planner == "none":
        return None, 0
    if opt.candidate_source == "synthetic":  # C = --candidates offsets (0: 256) from the dataset spec's ranges
        from aerohrl.planning.planner import ChainPlanner, offsets_from_spec

        n = 1 if opt.planner == "single" else opt.waypoints
        off = offsets_from_spec(data.info.get("spec"), opt.candidates or 256, seed=opt.seed)
        return ChainPlanner(algo, off, n=n, alpha=opt.alpha, beam=opt.beam), n
    cand = candidates_from_dataset(data, opt.candidates, seed=opt.seed)
    n = 1 if opt.planner == "single" else opt.waypoints
    return Planner(algo, cand, n=n, alpha=opt.alpha, beam=opt.beam, min_leg=opt.min_leg), n


def check_options(opt: EvalOptions) -> None:
    """UserError (one line) for an unknown task or planner, or options that contradict each other."""
    from aerohrl.eval.tasks import TASKS

    if opt.task not in TASKS:
        raise UserError(f"unknown task {opt.task!r} (choose from {', '.join(TASKS)})")
    if opt.planner not in PLANNERS:
        raise UserError(f"unknown planner {opt.planner!r} (choose from {', '.join(PLANNERS)})")
    if opt.candidate_source not in ("dataset", "synthetic"):
        raise UserError(f"unknown candidate source {opt.candidate_source!r} (choose from dataset, synthetic)")
    if opt.planner != "none" and opt.task != "ood":
        raise UserError(f"--planner {opt.planner} applies to --task ood only")
    if opt.episodes < 1:
        raise UserError(f"empty goal set: --episodes must be >= 1, got {opt.episodes}")
    if opt.planner == "multi" and opt.waypoints < 2:
        raise UserError(f"--planner multi needs --waypoints >= 2, got {opt.waypoints}")
    from aerohrl.eval.floors import FLOORS

    if opt.floor not in FLOORS:
        raise UserError(f"unknown floor {opt.floor!r} (choose from {', '.join(FLOORS)})")
    if opt.floor != "none" and opt.planner != "none":
        raise UserError("--floor replaces the policy; it takes no --planner")
    if not 0 < opt.goal_tol <= 10:
        raise UserError(f"--goal-tol must be in (0, 10] (a factor on the goal tolerances), got {opt.goal_tol}")
    if opt.decline_margin is not None and not np.isfinite(opt.decline_margin):
        raise UserError(f"--decline-margin must be a finite number, got {opt.decline_margin}")
    if not opt.min_leg >= 0:
        raise UserError(f"--min-leg must be >= 0 m, got {opt.min_leg}")
    if (opt.family is not None or opt.ring is not None) and opt.task != "ood":
        raise UserError("--family / --ring apply to --task ood only")
    if opt.ring is not None and opt.family is None:
        raise UserError("--ring needs --family (position | velocity | acceleration | combined)")
    opt.ring_def()  # one-line errors for unknown families and bad rings
    if (opt.horizon is not None and opt.horizon < 1) or opt.leg_horizon < 0 or opt.beam < 1 or opt.candidates < 0 or opt.replan_every < 0:
        raise UserError("--horizon and --beam must be >= 1, --leg-horizon, --candidates and --replan-every >= 0")


def build_episodes(data: Dataset, opt: EvalOptions) -> EpisodeSet:
    """The episode set of ``opt.task`` (starts, goals, horizons) on ``data``'s goals."""
    from aerohrl.eval.tasks import make_episodes

    goals = int(data.rest_start_episodes().numel())
    if opt.task == "reach-desired" and opt.episodes > goals:  # a repeated goal would be flown the same way again
        raise UserError(f"--episodes {opt.episodes} exceeds the {goals} desired goals of dataset {data.info.get('path')} "
                        f"(reach-desired flies each goal once); pass --episodes {goals} or fewer")

    kw = {}
    ring = opt.ring_def()
    if ring is not None:  # a family's ring: its own horizon (scaled to distance) unless --horizon is given
        from aerohrl.eval.tasks import ood_family

        return ood_family(data, opt.episodes, opt.seed, ring=ring, horizon=opt.horizon)
    if opt.task == "ood":
        # every OOD variant flies the same goals with the same total time
        kw = {"leg_horizon": opt.horizon or OOD_HORIZON, "legs": 1}
    return make_episodes(opt.task, data, opt.episodes, opt.seed, **kw)


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
    out_dir = Path(opt.out) if opt.out else run.path / "eval" / opt.name()
    atomic.remove_stale_temporaries(out_dir)  # left by an evaluation that was killed while writing
    per_ckpt = []
    hover_success = None  # Reach-Intermediate: the hover floor's outcomes on these episodes (kind_rates)
    t_start = time.perf_counter()
    bar = tqdm(ckpts, desc=f"eval {opt.name()}", unit="ckpt", disable=None if opt.progress else True, dynamic_ncols=True)  # None: only on a terminal
    for i, path in enumerate(bar):
        algo, ck = load_policy(path, device, run)
        check_checkpoint_dataset(ck, data, path)
        if hover_success is None and episodes.task == "reach-intermediate" and opt.floor != "hover":  # one flight, ~1 s
            hover_success = rollout(wrap_floor(algo, "hover"), episodes, goal_tol=opt.goal_tol, **sim_kwargs(data))["success"]
        algo = wrap_floor(algo, opt.floor)
        planner, nw = make_planner(algo, data, opt)
        leg_h = opt.leg_horizon or max(1, int(episodes.horizons.max()) // (nw + 1))
        record = opt.record and i == len(ckpts) - 1
        t0 = time.perf_counter()
        r = rollout(algo, episodes, planner=planner, n_waypoints=nw, leg_horizon=leg_h, replan=opt.replan,
                    replan_every=opt.replan_every, waypoint_tol=opt.waypoint_tol, goal_tol=opt.goal_tol, decline_margin=opt.decline_margin, record=record, progress=opt.progress, desc=f"step {ck['step']}",
                    **sim_kwargs(data))
        wall = time.perf_counter() - t0
        results.write_episodes(out_dir, int(ck["step"]), episodes, r)
        per_ckpt.append({"checkpoint": path.name, "step": int(ck["step"]), "success": float(r["success"].mean()),
                         "near_success": float(r["near_success"].mean()), "seconds": wall,
                         **({"declined": float(r["declined"].mean())} if "declined" in r else {}),
                         **results.kind_rates(episodes, r, r["success"] if opt.floor == "hover" else hover_success)})
        bar.set_postfix(success=f"{per_ckpt[-1]['success']:.3f}")
        if record:
            results.write_trajectories(out_dir, int(ck["step"]), episodes, r)
    summary = results.summarize(per_ckpt, run_dir=run.path, meta=meta, options=opt, episodes=episodes,
                                seconds=time.perf_counter() - t_start)
    results.write_summary(out_dir, summary)
    return summary


def make_reach_intermediate_evaluator(data: Dataset, cfg: TrainConfig,
                                      episodes: int | None = None) -> Callable[[Algorithm, int], dict[str, float]]:
    """Reach-Intermediate (docs/spec.md; thesis Fig. 3.4: 75 episodes, a third to the desired
    goal with 500 steps, two thirds to an achieved goal <= 45 steps ahead with 100 steps)
    on a fixed, seeded episode set; default ``3 * cfg.eval_episodes`` episodes: a trainer
    evaluation hook (``Trainer(..., evaluators={"reach_intermediate": ...})``)."""
    from aerohrl.envs.rollout import rollout
    from aerohrl.eval.tasks import reach_intermediate

    eps = reach_intermediate(data, episodes or 3 * cfg.eval_episodes, seed=cfg.seed + 12345)
    spec = data.info.get("spec") or {}
    kw = {"vehicle": spec.get("vehicle", "hummingbird"), "fps": int(spec.get("fps", 100)), "substeps": int(spec.get("substeps", 5))}

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


__all__ = ["EvalOptions", "evaluate_run", "run_checkpoints", "load_run_dataset", "critics_auc", "PLANNERS",
           "make_reach_intermediate_evaluator"]
