"""``aerohrl bench suite``: the benchmark's leaderboard, agents x datasets x tasks over seeds.

    aerohrl bench suite --agents gcsl td3bc gcsl+planner --datasets maze-large-stitch maze-large-navigate \\
        --seeds 0 1 2 3 --out bench-out/suite
    aerohrl bench suite --size ci --out bench-out/suite-ci       # the CI-sized variant (minutes on 2 cores)
    aerohrl bench list                                           # datasets, tasks and agents of the suite

A dataset is named by its spec file, ``datasets/<name>.toml`` (``maze-large-stitch`` and
``quadrotor-maze-large-stitch-v0`` both name ``datasets/quadrotor-maze-large-stitch.toml``);
it is built when missing (``datagen build``, versioned and verified as always). Its tasks
follow its world: a maze dataset is evaluated on the maze's five frozen tasks (``maze``),
a free-space dataset on ``reach-novel`` and ``fast``.

An agent is an algorithm (``train --algo``), or ``ALGO+planner``: the thesis's planner over
that algorithm's skills and critics (Eq. 3.6 solved by shortest paths over the
candidates, ``aerohrl eval --planner graph``), or ``hiql+subgoals``: HIQL's high level as the
candidate source (its subgoals snapped to the nearest candidate, ``aerohrl eval --planner
subgoal``); both fly the same trained runs. Training and evaluation go through the sweep's Ray tasks
(aerohrl/sweep.py): every run resumable, a rerun does only what is missing.

The leaderboard is the success rate at each run's final checkpoint, per agent x dataset x
task, as mean ± std over seeds with the 95 % bootstrap interval of the mean and every
seed's value: ``OUT/leaderboard.md``, ``OUT/leaderboard.csv`` and ``OUT/leaderboard.png``.
"""

from __future__ import annotations

import dataclasses
import re
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from aerohrl import atomic
from aerohrl import cli_types as T
from aerohrl import config as K
from aerohrl.cli_common import add_common
from aerohrl.errors import ArgumentParser, UserError, run_cli

PROG = "aerohrl bench"
PLANNER_SUFFIX = "+planner"
SUBGOALS_SUFFIX = "+subgoals"  # a hierarchical agent's high level as the candidate source (planning/subgoals.py)
HIERARCHICAL = ("hiql",)  # the algorithms with a high level an ALGO+subgoals agent reads
# The planner an ALGO+planner agent evaluates with. In a maze: Eq. 3.6 solved exactly over
# the free cells' centres (planning/graph.py), legs only along straight free corridors
# (Maze.in_corridor: no leg crosses a wall) of at most 4 cells (8 m, the longest hop of the
# stitch data, plus a quarter cell), never to the cell the vehicle sits in (half a cell),
# re-planned at every intermediate goal reached. Corridor legs rather than legs between
# adjacent cells: a hover at every cell makes the giant maze's paths outlast the horizon. In
# free space: the thesis's multi-waypoint plan (Eq. 3.6) with the declining chain.
MAZE_PLANNER_ARGS = ("--planner", "graph", "--legs", "corridor", "--max-edge", "8.5", "--min-leg", "1")
FREE_PLANNER_ARGS = ("--planner", "multi", "--decline-margin", "0")
# Train settings of every run on a maze's data, under the suite's --set: Fourier features of
# the position (networks.position_features). The corridor to take is a function of the
# position with jumps at the walls, which the raw coordinates fit slowly; with the features
# the skills learn the turns in the suite's budget, and the corridor legs above need them.
MAZE_TRAIN_SETTINGS = {"pos_octaves": 5}
# Train settings of every run on an explore dataset, under the suite's --set: its desired
# goals are the flights' last states (mostly a collision), never a goal to learn to reach,
# so every goal is a later state of the flight (GCSL and the thesis's agents: relabelling
# probability 1, uniform over the rest of the flight, as OGBench's GCBC) and the reference
# agents' actors take trajectory goals (OGBench's own setting, which the presets change
# for expert data).
EXPLORE_TRAIN_SETTINGS = {
    "relabel_prob": 1.0,
    "relabel_offset": "uniform",
    "gciql_actor_p_trajgoal": 1.0,
    "crl_actor_p_trajgoal": 1.0,
    "qrl_actor_p_trajgoal": 1.0,
    "hiql_actor_p_trajgoal": 1.0,
}
# ALGO+subgoals: the high level's subgoal snapped to the nearest candidate (a maze's free cells,
# never the cell the vehicle sits in; in free space the dataset's achieved goals), asked again
# from the flown state every second
MAZE_SUBGOALS_ARGS = ("--planner", "subgoal", "--min-leg", "1", "--replan-every", "100")
FREE_SUBGOALS_ARGS = ("--planner", "subgoal", "--replan-every", "100")
FREE_TASKS = ("reach-novel", "fast")
MAZE_TASKS = ("maze",)
DEFAULT_DATASETS = ("maze-large-navigate", "maze-large-stitch", "maze-large-explore")
DEFAULT_AGENTS = ("gcsl", "gciql", "hiql", "gcsl+planner")


@dataclass
class Size:
    """What one size of the suite trains and evaluates with, and its grid when none is given."""

    episodes: int  # dataset episodes (the spec's goal count); 0 keeps the spec file's
    steps: int  # gradient steps per run
    eval_episodes: int  # evaluation episodes per task
    agents: tuple[str, ...]
    datasets: tuple[str, ...]
    seeds: tuple[int, ...]


SIZES = {
    # the spec files' own dataset sizes, the cpu preset's run length, four seeds
    "full": Size(0, 30_000, 250, DEFAULT_AGENTS, DEFAULT_DATASETS, (0, 1, 2, 3)),
    # a newcomer's first look in minutes: small data, short runs, two seeds; its numbers show
    # that the pipeline works end to end, not how the methods compare
    "ci": Size(40, 600, 25, ("gcsl", "gcsl+planner"), ("maze-medium-navigate", "maze-medium-stitch"), (0, 1)),
}


@dataclass
class SuiteSpec:
    """The suite's grid (flags or ``--config`` TOML)."""

    agents: tuple[str, ...] = K.param(
        (), "agents: an algorithm, ALGO+planner (the thesis planner over its skills) or hiql+subgoals; none: the size's"
    )
    datasets: tuple[str, ...] = K.param(
        (), "datasets by name (datasets/<name>.toml), NAME@EPISODES for another size of it; none: the size's"
    )
    seeds: tuple[int, ...] = K.param((), "training seeds; none: the size's", ge=0)
    size: str = K.param("full", "full | ci (small data, short runs)", choices=tuple(SIZES))
    preset: str = K.param("cpu", "train preset of every run")
    steps: int = K.param(0, "gradient steps per run (0: the size's)", ge=0)
    eval_episodes: int = K.param(0, "evaluation episodes per task (0: the size's)", ge=0)
    set: dict = K.param({}, "train settings of every run (setting -> value) over the preset and the size")


def with_size_defaults(sp: SuiteSpec) -> SuiteSpec:
    """``sp`` with its size's agents, datasets and seeds where it names none."""
    z = SIZES[sp.size]
    return dataclasses.replace(sp, agents=sp.agents or z.agents, datasets=sp.datasets or z.datasets, seeds=sp.seeds or z.seeds)


# ----------------------------------------------------------------------------- names


def spec_path(name: str, root: Path = Path("datasets")) -> Path:
    """The spec file of dataset ``name`` (``maze-large-stitch``, ``quadrotor-maze-large-stitch``
    or ``quadrotor-maze-large-stitch-v0``); UserError when there is none."""
    base = re.sub(r"-v\d+$", "", name)
    for cand in (base, f"quadrotor-{base}"):
        p = root / f"{cand}.toml"
        if p.is_file():
            return p
    known = sorted(p.stem for p in root.glob("quadrotor-*.toml"))
    raise UserError(f"unknown dataset {name!r} (no {root}/{base}.toml; the suite's datasets: {', '.join(known)})")


def split_dataset(name: str) -> tuple[str, int]:
    """(name, episodes) of ``NAME`` or ``NAME@EPISODES`` (a smaller or larger build of the same
    spec, for data-efficiency curves; 0: the spec's own); UserError on a bad count."""
    base, _, n = name.partition("@")
    if not n:
        return base, 0
    if not n.isdigit() or int(n) < 1:
        raise UserError(f"dataset {name!r}: the episode count after @ must be a positive integer")
    return base, int(n)


def dataset_world(spec: Any) -> str:
    """``free`` or ``maze-<name>``: the world a spec's data is flown in."""
    return str(getattr(spec, "world", "free"))


def tasks_for(world: str) -> tuple[str, ...]:
    """The evaluation tasks of a world's datasets."""
    return FREE_TASKS if world == "free" else MAZE_TASKS


def split_agent(agent: str) -> tuple[str, str]:
    """(algorithm, kind) of an agent name, kind ``""`` (flat), ``"planner"`` (ALGO+planner) or
    ``"subgoals"`` (ALGO+subgoals); UserError for an unknown algorithm or a kind it cannot fly."""
    from aerohrl.algorithms.config import ALGORITHMS

    algo, kind = agent, ""
    for suffix in (PLANNER_SUFFIX, SUBGOALS_SUFFIX):
        if agent.endswith(suffix):
            algo, kind = agent[: -len(suffix)], suffix[1:]
    if algo not in ALGORITHMS:
        raise UserError(
            f"unknown agent {agent!r} (an algorithm: {', '.join(ALGORITHMS)}; or ALGO{PLANNER_SUFFIX}, "
            f"{'|'.join(HIERARCHICAL)}{SUBGOALS_SUFFIX})"
        )
    if kind == "subgoals" and algo not in HIERARCHICAL:
        raise UserError(f"agent {agent!r}: {SUBGOALS_SUFFIX} needs a hierarchical agent ({', '.join(HIERARCHICAL)})")
    return algo, kind


def eval_entries(world: str, kind: str) -> list[tuple[str, ...]]:
    """The ``aerohrl eval`` argument tuples of one agent kind (:func:`split_agent`) on a world's tasks."""
    free = world == "free"
    args = {
        "": (),
        "planner": FREE_PLANNER_ARGS if free else MAZE_PLANNER_ARGS,
        "subgoals": FREE_SUBGOALS_ARGS if free else MAZE_SUBGOALS_ARGS,
    }[kind]
    return [("--task", t, *args) for t in tasks_for(world)]


# ----------------------------------------------------------------------------- running


@dataclass(frozen=True)
class SuiteRun:
    algo: str
    dataset: str  # the suite's name of the dataset
    path: str  # the built dataset's folder
    world: str
    seed: int
    family: str = "navigate"  # the dataset's family (navigate | stitch | explore)

    def name(self) -> str:
        """The run folder's name: ``ALGO-DATASET-sSEED``."""
        return f"{self.algo}-{self.dataset.replace('@', '-n')}-s{self.seed}"


def build_datasets(
    sp: SuiteSpec, root: Path, log: Callable[[str], Any] = print, specs: Path = Path("datasets")
) -> dict[str, tuple[str, str, str]]:
    """Every dataset of the suite (spec files in ``specs``) built (or verified) under ``root``:
    name -> (folder, world, family)."""
    from aerohrl.datagen.build import build
    from aerohrl.datagen.spec import load_spec

    size = SIZES[sp.size]
    out = {}
    for name in sp.datasets:
        base, episodes = split_dataset(name)
        spec = load_spec(spec_path(base, specs))
        if episodes or size.episodes:
            spec = dataclasses.replace(spec, goals=episodes or min(spec.goals, size.episodes))
        res = build(spec, root, progress=False, log=log)
        log(f"suite: dataset {name}: {res.path} ({res.episodes} episodes, {res.frames:,} frames)")
        out[name] = (str(Path(res.path).resolve()), dataset_world(spec), spec.family)
    return out


def suite_runs(sp: SuiteSpec, datasets: dict[str, tuple[str, str, str]]) -> list[SuiteRun]:
    """The training runs: one per algorithm (an ALGO+planner agent shares ALGO's runs) x dataset x
    seed; ``datasets``: name -> (folder, world, family), as :func:`build_datasets` returns."""
    algos = list(dict.fromkeys(split_agent(a)[0] for a in sp.agents))
    return [
        SuiteRun(a, d, datasets[d][0], datasets[d][1], s, datasets[d][2]) for d in sp.datasets for a in algos for s in sp.seeds
    ]


def run_config(sp: SuiteSpec, r: SuiteRun) -> dict:
    """The train config (flat dict) of one run: the preset, the size's steps, no in-training
    evaluation, a maze's settings (``MAZE_TRAIN_SETTINGS``), an explore dataset's
    (``EXPLORE_TRAIN_SETTINGS``), then ``--set``."""
    from aerohrl.algorithms import config as C

    steps = sp.steps or SIZES[sp.size].steps
    for k in sp.set:
        if k in ("algo", "dataset", "seed", "preset"):
            raise UserError(f"--set {k}: the {k} is an axis of the suite")
    cfg = C.make_config(
        sp.preset,
        **{
            "eval_every": 0,
            "steps": steps,
            "checkpoint_every": max(1, steps // 10),
            "keep_checkpoints": 2,
            **(MAZE_TRAIN_SETTINGS if r.world != "free" else {}),
            **(EXPLORE_TRAIN_SETTINGS if r.family == "explore" else {}),
            **sp.set,
            "algo": r.algo,
            "dataset": r.path,
            "seed": r.seed,
        },
    )
    return C.to_dict(cfg)


def eval_run(run_dir: str, entries: list[list[str]], episodes: int, threads: int) -> dict:
    """``aerohrl eval ARGS --run RUN`` at the final checkpoint for each entry not already done."""
    import io
    from contextlib import redirect_stderr, redirect_stdout

    from aerohrl.eval.cli import main as eval_main

    done = []
    for args in entries:
        if _evaluated(Path(run_dir), args, episodes):
            continue
        err = io.StringIO()
        argv = [*args, "--run", run_dir, "--episodes", str(episodes), "--checkpoints", "1", "--threads", str(threads), "--quiet"]
        with redirect_stdout(io.StringIO()), redirect_stderr(err):
            code = eval_main(argv)
        if code != 0:
            raise RuntimeError(f"aerohrl eval {' '.join(argv)} failed: {err.getvalue().strip().splitlines()[-1:]}")
        done.append(args)
    return {"run": run_dir, "evaluated": done}


def run_suite(
    sp: SuiteSpec,
    out: Path,
    *,
    num_cpus: int | None = None,
    address: str | None = None,
    log: Callable[[str], Any] = print,
    specs: Path = Path("datasets"),
    data: Path = Path("datasets"),
) -> list[dict]:
    """Build (spec files in ``specs``, data under ``data``), train and evaluate the suite into
    ``out``; write the leaderboard; returns it."""
    from aerohrl.cluster import ray_connect
    from aerohrl.sweep import train_on_ray

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    datasets = build_datasets(sp, data, log=log, specs=specs)
    runs = suite_runs(sp, datasets)
    episodes = sp.eval_episodes or SIZES[sp.size].eval_episodes
    entries: dict[str, list[list[str]]] = {}
    for r in runs:
        entries[r.name()] = [
            list(e)
            for agent in sp.agents
            if split_agent(agent)[0] == r.algo
            for e in eval_entries(r.world, split_agent(agent)[1])
        ]
    (out / "runs").mkdir(exist_ok=True)
    atomic.write_json(out / "suite.json", dataclasses.asdict(sp))  # the grid this folder holds
    ray = ray_connect(address, num_cpus=num_cpus)
    try:
        evaluate = ray.remote(num_cpus=1, max_retries=2)(eval_run)
        pending: dict[Any, str] = {}

        def then_evaluate(label: str, res: dict) -> None:
            pending[evaluate.remote(res["run"], entries[label], episodes, 1)] = label

        report = train_on_ray(
            ray,
            [(r.name(), str((out / "runs" / r.name()).resolve()), run_config(sp, r)) for r in runs],
            log=lambda m: log(m.replace("sweep:", "suite:")),
            on_trained=then_evaluate,
        )
        for ref, label in pending.items():
            try:
                ray.get(ref)
            except Exception as e:  # Ray wraps the task's error: keep its last line
                report["errors"][label] = str(e).strip().splitlines()[-1]
    finally:
        if not address:
            ray.shutdown()
    atomic.write_json(out / "suite-report.json", report)
    board = leaderboard(out, sp, runs)
    write_leaderboard(out, board)
    if report["errors"]:
        raise UserError(
            f"{len(report['errors'])} runs failed ({out / 'suite-report.json'}); rerun the same command to retry them"
        )
    return board


# ----------------------------------------------------------------------------- the leaderboard


def _summaries(run_dir: Path, args: list[str] | tuple[str, ...]):
    """The evaluation summaries of a run (sorted by folder) made by ``aerohrl eval ARGS``: the
    same task and planner, and every option ARGS gives at the value it gives."""
    import json

    task = args[args.index("--task") + 1]
    planner = args[args.index("--planner") + 1] if "--planner" in args else "none"
    for f in sorted((run_dir / "eval").glob("*/summary.json")):
        try:
            s = json.loads(f.read_text())
        except (OSError, ValueError):
            continue
        opts = s.get("options") or {}
        same = all(
            str(opts.get(k.lstrip("-").replace("-", "_"))) in (v, str(float(v)) if v.replace(".", "").isdigit() else v)
            for k, v in zip(args[::2], args[1::2])
            if k not in ("--task", "--planner")
        )
        if s.get("task") == task and s.get("planner", "none") == planner and same:
            yield s


def _evaluated(run_dir: Path, args: list[str], episodes: int) -> bool:
    """Does the run hold an evaluation of ``aerohrl eval ARGS`` with ``episodes`` episodes at its newest checkpoint?"""
    from aerohrl.algorithms.run import Run

    ckpts = Run(run_dir).checkpoints()
    return any(
        s.get("episodes") == episodes
        and ckpts
        and [c.get("checkpoint") for c in s.get("checkpoints", [])][-1:] == [ckpts[-1].name]
        for s in _summaries(run_dir, args)
    )


def _final_success(run_dir: Path, args: tuple[str, ...]) -> float | None:
    """Success rate at the final checkpoint of the run's evaluation by ``aerohrl eval ARGS``, or None when not evaluated."""
    for s in _summaries(run_dir, args):
        return float(s["checkpoints"][-1]["success"])
    return None


def leaderboard(out: Path, sp: SuiteSpec, runs: list[SuiteRun]) -> list[dict]:
    """One row per agent x dataset x task: the seeds' final-checkpoint success (%) and its statistics."""
    from aerohrl.eval.results import seed_stats

    rows = []
    worlds = {r.dataset: r.world for r in runs}
    for d in sp.datasets:
        for task in tasks_for(worlds[d]):
            for agent in sp.agents:
                algo, kind = split_agent(agent)
                args = next(e for e in eval_entries(worlds[d], kind) if e[1] == task)
                vals, seeds = [], []
                for r in runs:
                    if r.algo == algo and r.dataset == d:
                        v = _final_success(out / "runs" / r.name(), args)
                        if v is not None:
                            vals.append(100 * v)
                            seeds.append(r.seed)
                st = seed_stats(vals) if vals else None
                rows.append({"agent": agent, "dataset": d, "task": task, "seeds": seeds, "stats": st})
    return rows


def write_leaderboard(out: Path, rows: list[dict]) -> None:
    """``leaderboard.md``, ``leaderboard.csv`` and ``leaderboard.png`` under ``out``."""
    from aerohrl.eval.results import markdown, seed_cell, to_csv

    head = ["dataset", "task", "agent", "success % (mean ± std [95 % CI] (per seed))", "seeds"]
    md_rows = [[r["dataset"], r["task"], r["agent"], seed_cell(r["stats"]), len(r["seeds"])] for r in rows]
    atomic.write_text(out / "leaderboard.md", "# Leaderboard\n\n" + markdown(head, md_rows) + "\n")
    csv_head = ["dataset", "task", "agent", "mean", "std", "ci_lo", "ci_hi", "seeds", "values"]
    csv_rows = []
    for r in rows:
        st = r["stats"] or {"mean": float("nan"), "std": float("nan"), "ci95": (float("nan"),) * 2, "values": []}
        vals = " ".join(f"{v:.2f}" for v in st["values"])
        csv_rows.append([r["dataset"], r["task"], r["agent"], st["mean"], st["std"], *st["ci95"], len(r["seeds"]), vals])
    atomic.write_text(out / "leaderboard.csv", to_csv(csv_head, csv_rows))
    plot_leaderboard(out / "leaderboard.png", rows)


def plot_leaderboard(path: Path, rows: list[dict]) -> None:
    """Grouped bars: success per dataset x task (groups) and agent (bars), with each seed as a dot."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    cells = list(dict.fromkeys((r["dataset"], r["task"]) for r in rows))
    agents = list(dict.fromkeys(r["agent"] for r in rows))
    w = 0.8 / max(len(agents), 1)
    fig, ax = plt.subplots(figsize=(max(6, 1.6 * len(cells) * max(1, len(agents)) / 3), 4))
    for j, agent in enumerate(agents):
        for i, cell in enumerate(cells):
            r = next((x for x in rows if (x["dataset"], x["task"]) == cell and x["agent"] == agent), None)
            if r is None or r["stats"] is None:
                continue
            x = i + (j - (len(agents) - 1) / 2) * w
            st = r["stats"]
            lo, hi = st["ci95"]
            err = None if np.isnan(lo) else [[st["mean"] - lo], [hi - st["mean"]]]
            ax.bar(x, st["mean"], w, color=f"C{j}", yerr=err, capsize=2, label=agent if i == 0 else None)
            ax.plot([x] * len(st["values"]), st["values"], "k.", ms=3)
    ax.set_xticks(range(len(cells)), [f"{d}\n{t}" for d, t in cells], fontsize=7)
    ax.set_ylabel("success at the final checkpoint (%)")
    ax.set_ylim(0, 100)
    ax.legend(fontsize=7, ncol=min(4, len(agents)))
    fig.tight_layout()
    tmp = atomic.temp_path(path)
    fig.savefig(tmp, format="png", dpi=120)
    plt.close(fig)
    tmp.replace(path)


# ----------------------------------------------------------------------------- command line


def parser() -> ArgumentParser:
    """``aerohrl bench`` with its subcommands ``suite`` and ``list``."""
    ap = ArgumentParser(prog=PROG, description="The benchmark: mazes and free space, dataset families, frozen tasks.")
    sub = ap.add_subparsers(dest="cmd", required=True, metavar="COMMAND")
    s = sub.add_parser("suite", help="train and evaluate agents x datasets x seeds; write the leaderboard")
    s.add_argument("--config", type=Path, default=None, help="a suite TOML (its keys are these flags); flags override it")
    K.add_flags(s, SuiteSpec, skip=("set",))
    s.add_argument(
        "--set", nargs="+", default=[], metavar="KEY=VALUE", help="a train setting of every run (train's flags with _)"
    )
    s.add_argument("--specs", type=Path, default=Path("datasets"), help="folder of the dataset spec files [datasets]")
    s.add_argument("--data", type=Path, default=Path("datasets"), help="folder the datasets are built in [datasets]")
    s.add_argument("--num-cpus", type=T.positive_int, default=None, help="cores of the local Ray [all]")
    s.add_argument("--address", default=None, help="join the Ray cluster at HOST:PORT instead of a local one")
    add_common(s, out={"required": True, "help": "suite folder (runs, leaderboard)"})
    ls = sub.add_parser("list", help="the suite's datasets (spec files), their tasks, and the agents")
    ls.add_argument("--specs", type=Path, default=Path("datasets"), help="folder of the dataset spec files [datasets]")
    return ap


def cmd_list(specs: Path = Path("datasets")) -> int:
    """``aerohrl bench list``: what the suite can run."""
    from aerohrl.algorithms.config import ALGORITHMS
    from aerohrl.datagen.spec import load_spec

    print(f"datasets ({specs}/<name>.toml) and their tasks:")
    for p in sorted(specs.glob("quadrotor-*.toml")):
        world = dataset_world(load_spec(p))
        print(f"  {p.stem:36s} {world:12s} {' '.join(tasks_for(world))}")
    print(
        "agents: "
        + " ".join([*ALGORITHMS, *(a + PLANNER_SUFFIX for a in ALGORITHMS), *(a + SUBGOALS_SUFFIX for a in HIERARCHICAL)])
    )
    return 0


def main(argv: list[str] | None = None) -> int:
    """The ``aerohrl bench`` command; exit code."""
    a = parser().parse_args(argv)

    def go() -> int:
        if a.cmd == "list":
            return cmd_list(a.specs)
        d: dict = K.load_toml(a.config) if a.config else {}
        d.update(K.given_flags(a, SuiteSpec, skip=("set",)))
        if a.set:
            from aerohrl.sweep import key_values

            d["set"] = {**d.get("set", {}), **key_values(a.set, "--set", False)}
        sp = with_size_defaults(K.from_mapping(SuiteSpec, d, where=str(a.config or "the suite")))
        for agent in sp.agents:
            split_agent(agent)
        for name in sp.datasets:
            spec_path(split_dataset(name)[0], a.specs)
        board = run_suite(
            sp,
            a.out,
            num_cpus=a.num_cpus,
            address=a.address,
            log=lambda m: print(m, file=sys.stderr, flush=True),
            specs=a.specs,
            data=a.data,
        )
        print((Path(a.out) / "leaderboard.md").read_text(), end="")
        print(f"leaderboard: {a.out}/leaderboard.md, .csv, .png ({len(board)} rows)", file=sys.stderr)
        return 0

    return run_cli(PROG, go)


if __name__ == "__main__":
    sys.exit(main())
