"""``aerohrl sweep``: a grid of training runs as Ray tasks, evaluated and tabulated.

    aerohrl sweep --algos gcsl td3bc --seeds 0 1 2 --datasets datasets/quadrotor-reach/<version> --out sweeps/s1
    aerohrl sweep --config sweep.toml --out sweeps/s1              # the same grid from a file (or sweep.yaml)
    aerohrl sweep --config sweep.toml --out sweeps/s1 --address HEAD:6379   # on a Ray cluster

The grid is algorithms x seeds x datasets x the product of the ``[grid]`` overrides
(``--grid batch_size=256,512``), every run with the ``[set]`` overrides (``--set
steps=2000``) on top of ``--preset``. It is saved as ``OUT/sweep.toml``; the runs go
to ``OUT/runs/<algo>-<dataset version>-s<seed>[-<overrides>]``.

Each run is one Ray task declaring ``num_cpus`` (``--cpus-per-run``) and, with
``--device cuda``, ``num_gpus`` (``--gpus-per-run``). Without ``--address`` the command
starts a local Ray limited to ``--num-cpus`` cores (and stops it at the end); with it,
it joins that cluster. A task trains in-process in its Ray worker: a new run starts, an
unfinished one resumes from its newest checkpoint (``train --resume``), a finished one
is left alone. A worker that dies (killed, node lost) is retried by Ray
(``max_retries``) and resumes from the last checkpoint; because a resumed run ends
with the weights of an uninterrupted one (algorithms/trainer.py), the sweep's tables
equal an uninterrupted sweep's. Re-running the command does only what is missing.

Then every run is evaluated (``aerohrl eval --task T`` for each of ``--tasks``, one Ray
task per run; an evaluation already covering the run's newest checkpoints is kept) and
the runs that differ only in their seed are aggregated (eval/results.py: mean ± std,
95 % bootstrap interval, per-seed values) into ``OUT/tables.md`` and
``OUT/tables-t31.csv`` / ``-t32.csv``.
"""

from __future__ import annotations

import argparse
import contextlib
import itertools
import os
import re
import sys
import time
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable

from aerohrl import atomic
from aerohrl import cli_types as T
from aerohrl import config as K
from aerohrl.algorithms.config import ALGORITHMS, presets
from aerohrl.cli_common import add_common, toml_value
from aerohrl.cluster import ray_connect
from aerohrl.errors import ArgumentParser, UserError, run_cli

if TYPE_CHECKING:
    from aerohrl.algorithms.config import TrainConfig

PROG = "aerohrl sweep"
# what a run's identity is made of (top-level keys), never a [set]/[grid] override
IDENTITY = ("algo", "seed", "dataset", "preset")
EVAL_TASKS = ("reach-desired", "reach-intermediate")


# ----------------------------------------------------------------------------- the grid


@dataclass
class SweepSpec:
    """A sweep's grid, as its file (TOML or YAML, ``--config``) and its flags give it."""

    algos: tuple[str, ...] = K.param((), "algorithms", choices=ALGORITHMS)
    seeds: tuple[int, ...] = K.param((0,), "training seeds", ge=0)
    datasets: tuple[str, ...] = K.param((), "dataset folders (datasets/<name>/<version>)")
    preset: str = K.param("cpu", "train preset under every run", choices=presets())
    set: dict = K.param({}, "train settings of every run (setting -> value)")
    grid: dict = K.param({}, "train settings swept (setting -> list of values)")
    # the evaluation of every run (a file may hold these under [eval]); a task's name is
    # checked against aerohrl.eval.tasks in check_spec, which --help does not import
    tasks: tuple[str, ...] = K.param(EVAL_TASKS, "evaluation tasks")
    episodes: int = K.param(250, "evaluation episodes per run and task", ge=1)
    checkpoints: int = K.param(10, "newest checkpoints evaluated per run", ge=1)

    def to_toml(self) -> str:
        """The grid as TOML (what ``--config`` reads back), saved as ``OUT/sweep.toml``."""
        lines = ["# aerohrl sweep grid (written by `aerohrl sweep`; rerun with --config this file)"]
        for k in ("algos", "seeds", "datasets", "preset", "tasks", "episodes", "checkpoints"):
            lines.append(f"{k} = {_toml_value(getattr(self, k))}")
        for table in ("set", "grid"):
            lines.append(f"\n[{table}]")
            lines += [f"{k} = {_toml_value(v)}" for k, v in sorted(getattr(self, table).items())]
        return "\n".join(lines) + "\n"


def _toml_value(v) -> str:
    try:
        return toml_value(v)  # the writer of run.toml too (aerohrl.cli_common)
    except TypeError:
        raise UserError(f"cannot write {v!r} to a TOML grid") from None


def _parse_value(text: str):
    """``--set``/``--grid`` values: TOML syntax (512, 1e-3, true, "x", [256, 256]); a
    bare word is a string."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def key_values(items: list[str], flag: str, many: bool) -> dict:
    """``KEY=VALUE`` flags (``many``: ``KEY=V1,V2``) as a dict, keys with ``_`` for ``-``; UserError on a malformed item."""
    out = {}
    for it in items or []:
        key, eq, val = it.partition("=")
        if not eq or not key:
            raise UserError(f"{flag} {it!r}: expected KEY=VALUE" + ("[,VALUE...]" if many else ""))
        key = key.strip().replace("-", "_")
        if many:
            parts = re.split(r",(?![^\[]*\])", val)  # commas outside brackets
            out[key] = [_parse_value(p.strip()) for p in parts]
        else:
            out[key] = _parse_value(val.strip())
    return out


def check_spec(sp: SweepSpec) -> SweepSpec:
    """One-line errors for what cannot run (the per-key rules are SweepSpec's declarations,
    :func:`aerohrl.config.validate`): an unknown grid key, an identity key swept as an
    override, a missing dataset, an empty axis, an unknown task, a value the config refuses."""
    from aerohrl.algorithms import config as C
    from aerohrl.eval.tasks import TASKS

    K.validate(sp)
    names = set(C.to_dict(C.TrainConfig())) - set(C.INTERNAL)
    for table in ("set", "grid"):
        for k in getattr(sp, table):
            if k in IDENTITY:
                raise UserError(f"[{table}] {k}: the {k} is an axis of the sweep (use --{k}s / the top-level key)")
            if k not in names:
                raise UserError(f"unknown grid key {k!r} in [{table}] (a train flag: {', '.join(sorted(names))})")
    for k, v in sp.grid.items():
        if not isinstance(v, list) or not v:
            raise UserError(f"[grid] {k} needs a non-empty list of values")
    for axis in ("algos", "seeds", "datasets"):
        if not getattr(sp, axis):
            raise UserError(f"the sweep has no {axis} (--{axis})")
    for t in sp.tasks:
        if t not in TASKS or t == "ood":
            raise UserError(f"unknown evaluation task {t!r} (choose from {', '.join(x for x in TASKS if x != 'ood')})")
    from aerohrl.datagen.dataset import open_dataset

    for d in sp.datasets:
        open_dataset(d, verify=False)  # each run verifies its checksums when it loads it
    for p in points(sp):  # every config the grid makes is one `train` accepts
        _config(sp, p)
    return sp


def load_spec(path: Path | None, a: argparse.Namespace) -> SweepSpec:
    """The grid: ``--config`` TOML, with the flags given on top."""
    d: dict = {}
    where = "the sweep"
    if path is not None:
        where = str(path)
        try:
            text = Path(path).read_text()
            if Path(path).suffix in (".yaml", ".yml"):  # the same keys as YAML (pyyaml comes with lerobot)
                import yaml

                d = yaml.safe_load(text) or {}
                if not isinstance(d, dict):
                    raise UserError(f"{path} is not a mapping of sweep keys")
            else:
                d = tomllib.loads(text)
        except FileNotFoundError:
            raise UserError(f"no sweep file at {path}") from None
        except UserError:
            raise
        except Exception as e:  # a TOML/YAML syntax error, an unreadable file
            raise UserError(f"cannot read {path}: {str(e).splitlines()[0] if str(e) else type(e).__name__}") from None
        if isinstance(d.get("eval"), dict):
            d.update(d.pop("eval"))
    if a.algos:
        d["algos"] = a.algos
    if a.seeds:
        d["seeds"] = a.seeds
    if a.datasets:
        d["datasets"] = [str(x) for x in a.datasets]
    if a.preset:
        d["preset"] = a.preset
    if a.tasks:
        d["tasks"] = a.tasks
    if a.episodes:
        d["episodes"] = a.episodes
    if a.checkpoints:
        d["checkpoints"] = a.checkpoints
    d["set"] = {**d.get("set", {}), **key_values(a.set, "--set", False)}
    d["grid"] = {**d.get("grid", {}), **key_values(a.grid, "--grid", True)}
    if a.device:
        d["set"]["device"] = a.device
    sp = K.from_mapping(SweepSpec, d, where=where, check=False, hint="a run override goes under [set] or [grid]")
    sp.datasets = tuple(str(Path(x).resolve()) for x in sp.datasets)
    return check_spec(sp)


@dataclass(frozen=True)
class Point:
    algo: str
    seed: int
    dataset: str
    overrides: tuple  # ((key, value), ...) of the [grid]

    def name(self) -> str:
        """The run's folder name: ``ALGO-DATASET[-KEYVALUE...]-sSEED``."""
        ov = "".join(f"-{k}{_label(v)}" for k, v in self.overrides)
        return f"{self.algo}-{Path(self.dataset).name}{ov}-s{self.seed}"


def _label(v) -> str:
    text = "x".join(map(str, v)) if isinstance(v, (list, tuple)) else str(v)
    return re.sub(r"[^A-Za-z0-9.+_]", "_", text)


def points(sp: SweepSpec) -> list[Point]:
    """Every grid point of ``sp``: datasets x grid combinations x algorithms x seeds."""
    keys = sorted(sp.grid)
    combos = list(itertools.product(*(sp.grid[k] for k in keys))) or [()]
    return [
        Point(a, s, d, tuple(zip(keys, (tuple(v) if isinstance(v, list) else v for v in combo))))
        for d in sp.datasets
        for combo in combos
        for a in sp.algos
        for s in sp.seeds
    ]


def _config(sp: SweepSpec, p: Point):
    from aerohrl.algorithms import config as C

    ov = {**sp.set, **dict(p.overrides), "algo": p.algo, "seed": p.seed, "dataset": p.dataset}
    ov = {k: tuple(v) if isinstance(v, list) else v for k, v in ov.items()}
    try:
        return C.make_config(sp.preset, **ov)
    except K.ConfigError as e:
        raise UserError(f"run {p.name()}: {e}") from None


# ----------------------------------------------------------------------------- tasks (run in Ray workers)


def config_differences(run_dir: str | Path, cfg: TrainConfig) -> str:
    """``""``, or ``" (kept its own config: FIELD RUN's -> asked, ...)"`` when the run at
    ``run_dir`` was started with another config than ``cfg`` (a run is reused or resumed
    with its own config: a preset changed since, or a flag, shows here instead of silently;
    the step count, checkpoint interval, device and dataset path are not compared)."""
    from aerohrl.algorithms import config as C
    from aerohrl.algorithms.run import Run

    try:
        old = C.to_dict(Run.open(run_dir, kind="train").config)
    except UserError:  # no run there, or a damaged one: resume_run says so
        return ""
    new = C.to_dict(cfg)
    # amp "auto" asked is met by whichever precision the run resolved it to
    keys = [
        k
        for k in new
        if k not in ("steps", "checkpoint_every", "device", "dataset")
        and old.get(k) != new[k]
        and not (k == "amp" and new[k] == "auto")
    ]
    return f" (kept its own config: {', '.join(f'{k} {old.get(k)} -> {new[k]}' for k in keys)})" if keys else ""


def train_task(run_dir: str, cfg_dict: dict, threads: int) -> dict:
    """Train one run to its end: start it, resume it, or leave it (finished). Runs in a
    Ray worker; a retry after the worker died resumes from the newest checkpoint."""
    import torch

    from aerohrl.algorithms import config as C
    from aerohrl.algorithms.run import Run
    from aerohrl.algorithms.trainer import resume_run, start_run

    torch.set_num_threads(max(1, int(threads)))
    rd = Path(run_dir)
    cfg = C.from_dict(cfg_dict)
    t0 = time.perf_counter()
    kw = {"progress": False, "progress_every_s": 60.0}
    if (rd / "config.json").exists():
        run = Run.open(rd, kind="train")
        differs = config_differences(rd, cfg)
        if run.checkpoints() and run.step >= cfg.steps:
            return {"run": run_dir, "step": run.step, "status": "finished before" + differs, "seconds": 0.0}
        tr = resume_run(rd, overrides={"steps": cfg.steps}, **kw)
        status = f"resumed at step {tr.step}" + differs
    else:
        if rd.is_dir() and not Run(rd).checkpoints():
            import shutil

            shutil.rmtree(rd, ignore_errors=True)  # claimed by a worker that died before config.json: ours to redo
        tr = start_run(cfg, rd, **kw)
        status = "trained"
    step = tr.train()
    return {"run": run_dir, "step": step, "status": status, "seconds": time.perf_counter() - t0}


def eval_task(run_dir: str, tasks: list[str], episodes: int, checkpoints: int, threads: int) -> dict:
    """``aerohrl eval --task T --run RUN`` for each task whose results do not already cover
    the run's newest checkpoints (same episodes)."""
    import io
    from contextlib import redirect_stderr, redirect_stdout

    from aerohrl.eval.cli import main as eval_main
    from aerohrl.eval.results import evaluation_is_current

    rd = Path(run_dir)
    done = []
    for t in tasks:
        if evaluation_is_current(rd, t, episodes, checkpoints):
            continue
        err = io.StringIO()
        with redirect_stdout(io.StringIO()), redirect_stderr(err):
            code = eval_main(
                [
                    "--task",
                    t,
                    "--run",
                    str(rd),
                    "--episodes",
                    str(episodes),
                    "--checkpoints",
                    str(checkpoints),
                    "--threads",
                    str(threads),
                    "--quiet",
                ]
            )
        if code != 0:
            raise RuntimeError(f"aerohrl eval --task {t} --run {rd} failed: {err.getvalue().strip().splitlines()[-1:]}")
        done.append(t)
    return {"run": run_dir, "evaluated": done}


# ----------------------------------------------------------------------------- driver


def _check_saved(out: Path, sp: SweepSpec, write: bool = True) -> None:
    """A sweep folder holds one grid: rerunning it resumes; another grid is refused.
    ``write``: save the grid as ``OUT/sweep.toml`` when it is new."""
    saved = out / "sweep.toml"
    if saved.exists():
        old = saved.read_text()
        if old != sp.to_toml():
            raise UserError(
                f"{out} holds another sweep (its grid is {saved}); rerun with --config {saved}, or choose another --out"
            )
    elif write:
        out.mkdir(parents=True, exist_ok=True)
        atomic.write_text(saved, sp.to_toml())


@contextlib.contextmanager
def _in_dir(path: Path):
    old = Path.cwd()
    os.chdir(path)
    try:
        yield
    finally:
        os.chdir(old)


def write_tables(out: Path, names: list[str]) -> str:
    """Seed-aggregated Table 3.1/3.2 analogues of the runs (paths relative to OUT, so that
    two sweeps of one grid write the same tables)."""
    from aerohrl.eval import results

    with _in_dir(out):
        t = results.tables([Path("runs") / n for n in names])
        md = results.tables_markdown(t)
        results.write_text(Path("tables.md"), md)
        results.write_text(Path("tables-t31.csv"), results.to_csv(*t["t31"]))
        results.write_text(Path("tables-t32.csv"), results.to_csv(*t["t32"]))
    return md


def run_sweep(
    sp: SweepSpec,
    out: Path,
    *,
    address: str | None = None,
    num_cpus: int | None = None,
    cpus_per_run: int = 1,
    gpus_per_run: float | None = None,
    max_retries: int = 3,
    evaluate: bool = True,
    log: Callable[[str], Any] = print,
) -> dict:
    """Train every grid point of ``sp`` on Ray into ``out/runs``, evaluate each as soon as it
    is trained (unless ``evaluate=False``) and write ``sweep-report.json`` and the tables;
    returns the report (``{"runs": ..., "errors": ...}``, as ``train_on_ray``)."""
    out = Path(out)
    _check_saved(out, sp, write=False)  # before Ray starts; nothing is written until it runs
    pts = points(sp)
    cuda = str(sp.set.get("device", "cpu")).startswith("cuda")
    gpus = (1 if gpus_per_run is None else gpus_per_run) if cuda else 0
    if not cuda and gpus_per_run:
        raise UserError("--gpus-per-run needs --device cuda")
    if not address and gpus:  # a local Ray has this machine's GPUs: say so before starting it
        import torch

        have = torch.cuda.device_count() if torch.cuda.is_available() else 0
        if gpus > have:
            raise UserError(f"each run asks for {gpus:g} GPU(s) (--device cuda), this machine has {have}")
    ray = ray_connect(address, num_cpus=num_cpus)
    try:
        have = ray.cluster_resources()
        if gpus > have.get("GPU", 0):
            raise UserError(f"each run asks for {gpus:g} GPU(s), the Ray cluster has {have.get('GPU', 0):g}")
        if cpus_per_run > have.get("CPU", 0):
            raise UserError(f"each run asks for {cpus_per_run} CPUs (--cpus-per-run), the Ray cluster has {have.get('CPU', 0):g}")
        _check_saved(out, sp)
        (out / "runs").mkdir(exist_ok=True)
        log(
            f"sweep: {len(pts)} runs on Ray ({have.get('CPU', 0):g} CPUs, {have.get('GPU', 0):g} GPUs; {cpus_per_run} CPU"
            + (f" + {gpus:g} GPU" if gpus else "")
            + " per run) -> "
            + str(out)
        )
        evaluate_r = ray.remote(num_cpus=cpus_per_run, num_gpus=gpus, max_retries=max_retries)(eval_task)
        evals = {}

        def then_evaluate(name: str, r: dict) -> None:  # as soon as a run is trained, beside the others
            if evaluate:
                evals[evaluate_r.remote(r["run"], sp.tasks, sp.episodes, sp.checkpoints, cpus_per_run)] = name

        report = train_on_ray(
            ray,
            [(p.name(), str((out / "runs" / p.name()).resolve()), _cfg_dict(sp, p)) for p in pts],
            cpus_per_run=cpus_per_run,
            gpus=gpus,
            max_retries=max_retries,
            log=log,
            on_trained=then_evaluate,
        )
        for ref, name in evals.items():
            try:
                ray.get(ref)
            except Exception as e:
                report["errors"][name] = _one_line(e)
                log(f"sweep: evaluating {name} FAILED: {_one_line(e)}")
    finally:
        if not address:
            ray.shutdown()
    atomic.write_json(out / "sweep-report.json", report)
    if report["errors"]:
        raise UserError(
            f"{len(report['errors'])} of {len(pts)} runs failed ({out / 'sweep-report.json'}); rerun the same "
            "command to retry them"
        )
    if evaluate:
        report["tables"] = write_tables(out, [p.name() for p in pts])
    return report


def train_on_ray(
    ray: Any,
    items: list[tuple[str, str, dict]],
    *,
    cpus_per_run: int = 1,
    gpus: float = 0,
    max_retries: int = 3,
    log: Callable[[str], Any] = print,
    on_trained: Callable[[str, dict], Any] | None = None,
) -> dict:
    """Train every ``(label, run folder, config dict)`` as one Ray task (``train_task``)
    declaring ``cpus_per_run`` CPUs and ``gpus`` GPUs, retried ``max_retries`` times when
    its worker dies; ``on_trained(label, result)`` as each one ends. The longest-first
    order is the caller's. ``{"runs": {label: result}, "errors": {label: one line}}``: a
    run that fails for good (bad data, divergence) does not stop the others."""
    train = ray.remote(num_cpus=cpus_per_run, num_gpus=gpus, max_retries=max_retries)(train_task)
    refs = {train.remote(rd, cfg, cpus_per_run): label for label, rd, cfg in items}
    report: dict[str, dict[str, Any]] = {"runs": {}, "errors": {}}
    pending = list(refs)
    while pending:
        ready, pending = ray.wait(pending, num_returns=1)
        label = refs[ready[0]]
        try:
            r = ray.get(ready[0])
        except Exception as e:
            report["errors"][label] = _one_line(e)
            log(f"sweep: {label} FAILED: {_one_line(e)}")
            continue
        report["runs"][label] = r
        log(f"sweep: {label} {r['status']}, step {r['step']} ({r['seconds']:.0f} s)")
        if on_trained:
            on_trained(label, r)
    return report


def train_runs(
    items: list[tuple[str, str, dict]],
    *,
    address: str | None = None,
    num_cpus: int | None = None,
    log: Callable[[str], Any] = print,
) -> dict[str, dict]:
    """``train_on_ray`` on a local Ray of ``num_cpus`` cores (started and stopped here) or
    the cluster at ``address``, one CPU per run: what ``make results`` trains through
    (experiments/reproduce.py). The result of each run by label; UserError when any failed."""
    ray = ray_connect(address, num_cpus=num_cpus)
    try:
        report = train_on_ray(ray, items, log=log)
    finally:
        if not address:
            ray.shutdown()
    if report["errors"]:
        label, msg = next(iter(report["errors"].items()))
        raise UserError(
            f"{len(report['errors'])} of {len(items)} training runs failed (first: {label}: {msg}); rerun the "
            "same command to resume them"
        )
    return report["runs"]


def _cfg_dict(sp: SweepSpec, p: Point) -> dict:
    from aerohrl.algorithms import config as C

    return C.to_dict(_config(sp, p))


def _one_line(e: BaseException) -> str:
    cause = getattr(e, "cause", None) or e  # Ray wraps the task's exception
    text = str(cause).strip().splitlines()
    return text[-1] if text else type(cause).__name__


# ----------------------------------------------------------------------------- CLI


def parser() -> ArgumentParser:
    """The ``aerohrl sweep`` argument parser."""
    ap = ArgumentParser(
        prog=PROG,
        description="Train a grid of runs (algorithms x seeds x datasets x overrides) as Ray tasks, "
        "evaluate them and write seed-aggregated tables.",
    )
    ap.add_argument(
        "--config",
        type=Path,
        default=None,
        help="sweep grid, TOML or .yaml (keys: algos, seeds, datasets, "
        "preset, [set], [grid], [eval] tasks/episodes/checkpoints); flags add to it; saved as OUT/sweep.toml",
    )
    add_common(
        ap,
        out={"required": True, "help": "sweep folder: sweep.toml, runs/, tables.md"},
        device={"default": None, "help": "torch device of each run: cpu | cuda (asks Ray for GPUs) [cpu]"},
    )
    ap.add_argument(
        "--algos",
        nargs="+",
        default=None,
        metavar="ALGO",
        help="train algorithms: gcsl td3bc td3awbc cql (required here or in --config)",
    )
    ap.add_argument("--seeds", nargs="+", type=T.nonneg_int, default=None, metavar="SEED", help="[0]")
    ap.add_argument(
        "--datasets",
        nargs="+",
        type=Path,
        default=None,
        metavar="DATASET",
        help="dataset folders (datasets/<name>/<version>; required here or in --config)",
    )
    ap.add_argument("--preset", default=None, help="train preset of every run [cpu]")
    ap.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="a train flag for every run (--set steps=2000 --set hidden=[256,256]); repeatable",
    )
    ap.add_argument(
        "--grid",
        action="append",
        default=[],
        metavar="KEY=V1,V2",
        help="a train flag swept over values (--grid batch_size=256,512); repeatable: the product",
    )
    ap.add_argument("--address", default=None, help="join the Ray cluster at HOST:PORT (or auto) instead of a local one")
    ap.add_argument(
        "--num-cpus", type=T.positive_int, default=None, help="local Ray: the core budget [all cores, os.cpu_count()]"
    )
    ap.add_argument("--cpus-per-run", type=T.positive_int, default=1, help="Ray num_cpus (and torch threads) of a run [1]")
    ap.add_argument("--gpus-per-run", type=T.positive_float, default=None, help="Ray num_gpus of a run with --device cuda [1]")
    ap.add_argument("--max-retries", type=T.nonneg_int, default=3, help="retries of a run whose worker died [3]")
    ap.add_argument("--tasks", nargs="+", default=None, help=f"evaluation tasks [{' '.join(EVAL_TASKS)}]")
    ap.add_argument("--episodes", type=T.positive_int, default=None, help="evaluation episodes per checkpoint [250]")
    ap.add_argument("--checkpoints", type=T.positive_int, default=None, help="newest checkpoints evaluated [10]")
    ap.add_argument("--no-eval", action="store_true", help="train only")
    return ap


def main(argv: list[str] | None = None) -> int:
    """``aerohrl sweep``: train, evaluate and tabulate a grid; returns the exit code."""
    a = parser().parse_args(argv)

    def go() -> int:
        sp = load_spec(a.config, a)
        if not a.address and a.num_cpus is None:
            a.num_cpus = os.cpu_count() or 1
        rep = run_sweep(
            sp,
            a.out,
            address=a.address,
            num_cpus=a.num_cpus,
            cpus_per_run=a.cpus_per_run,
            gpus_per_run=a.gpus_per_run,
            max_retries=a.max_retries,
            evaluate=not a.no_eval,
            log=lambda m: print(m, file=sys.stderr, flush=True),
        )
        if "tables" in rep:
            print(rep["tables"], end="")
            print(f"tables: {a.out / 'tables.md'}", file=sys.stderr)
        return 0

    return run_cli(PROG, go)


if __name__ == "__main__":
    sys.exit(main())
