"""Time to a working skill: wall clock and CPU time from the start of ``train`` to the first
checkpoint whose closed-loop evaluation reaches a target success, per seed.

    .venv/bin/python bench/bench_time_to_skill.py                       # Reach-Desired >= 90 % on the 250-goal dataset
    .venv/bin/python bench/bench_time_to_skill.py --task reach-novel --dataset datasets/quadrotor-reach/n25000-s0-81b96355
    .venv/bin/python bench/bench_time_to_skill.py --preset cpu --seeds 0 1 2 3 --threads 1

What is measured: the ``train`` command itself, one process per seed, run as a user runs
it (``train --preset P --dataset DS --seed S --threads T``) with the trainer's periodic
closed-loop evaluation (``--eval-task``, ``--eval-episodes`` goals, every ``--eval-every``
steps from ``--eval-start``, a checkpoint at each) and ``--stop-success TARGET``: the run ends with a checkpoint
at the first evaluation that reaches the target, so the process's wall clock is the time
to that checkpoint, start-up, dataset loading, normaliser fit and the evaluations
included. ``cpu s`` is the process's CPU time (user + system): on a machine other jobs
share, the time of one core that the run used. ``train s`` is the gradient steps alone
(from the run's metric lines), the rest being start-up and evaluation. A run that ends its
steps without reaching the target is reported with its best evaluation.

Without ``--dataset`` the task's dataset is built first in a temporary folder (not
timed): Reach-Desired the thesis's 250 goals (``datagen build --goals 250``), Reach-Novel
the recommended recipe (``datagen build --spec datasets/quadrotor-reach-dart.toml``,
``--goals`` to build a smaller one of the same recipe).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

TARGETS = {"reach-desired": 0.90, "reach-novel": 0.95}
DART_SPEC = Path(__file__).resolve().parent.parent / "datasets" / "quadrotor-reach-dart.toml"


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    """The bench's flags."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--task", default="reach-desired", choices=tuple(TARGETS), help="evaluation task [reach-desired]")
    ap.add_argument("--dataset", default=None, help="dataset folder [built for the task in a temporary folder]")
    ap.add_argument("--goals", type=int, default=None, help="without --dataset: goals of the built dataset [250 | the recipe's]")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2], help="training seeds [0 1 2]")
    ap.add_argument("--threads", type=int, default=1, help="torch threads of each run [1]")
    ap.add_argument("--preset", default="fast", help="training preset [fast]")
    ap.add_argument("--target", type=float, default=None, help="success to reach [reach-desired 0.9, reach-novel 0.95]")
    ap.add_argument("--episodes", type=int, default=250, help="episodes per evaluation [250]")
    ap.add_argument("--eval-every", type=int, default=None, help="evaluation (and checkpoint) every N steps [the preset's]")
    ap.add_argument("--eval-start", type=int, default=None, help="evaluations from this step on [the preset's]")
    ap.add_argument("--steps", type=int, default=None, help="at most this many steps [the preset's]")
    ap.add_argument("--keep", type=Path, default=None, help="keep the runs in this folder [a temporary folder, removed]")
    a = ap.parse_args(argv)
    if a.target is None:
        a.target = TARGETS[a.task]
    if not 0 < a.target <= 1:
        ap.error(f"--target must be in (0, 1], got {a.target}")
    return a


def build_dataset(a: argparse.Namespace, folder: Path) -> str:
    """The task's default dataset, built under ``folder``; its path."""
    cmd = [sys.executable, "-m", "aerohrl.datagen.cli", "build", "--out", str(folder), "--quiet"]
    if a.task == "reach-novel":
        cmd += ["--spec", str(DART_SPEC)] + (["--goals", str(a.goals)] if a.goals else [])
    else:
        cmd += ["--goals", str(a.goals or 250)]
    p = subprocess.run(cmd, capture_output=True, text=True)
    if p.returncode != 0:
        sys.exit(f"bench_time_to_skill: error: dataset build failed: {p.stderr.strip()}")
    return p.stdout.strip().splitlines()[-1]


def train_seed(a: argparse.Namespace, dataset: str, seed: int, out: Path) -> dict:
    """One ``train`` process to the target (or its last step); its times and evaluations."""
    name = f"{a.preset}-{a.task}-s{seed}"
    cmd = [
        sys.executable,
        "-m",
        "aerohrl.algorithms.cli",
        "--algo",
        "gcsl",
        "--preset",
        a.preset,
        "--dataset",
        dataset,
        "--seed",
        str(seed),
        "--threads",
        str(a.threads),
        "--eval-task",
        a.task,
        "--eval-episodes",
        str(a.episodes),
        "--stop-success",
        str(a.target),
        "--out",
        str(out),
        "--name",
        name,
        "--quiet",
        "--logger",
        "none",
        "--progress-every",
        "0",
    ]
    if a.eval_every:
        cmd += ["--eval-every", str(a.eval_every), "--checkpoint-every", str(a.eval_every)]
    if a.eval_start is not None:
        cmd += ["--eval-start", str(a.eval_start)]
    if a.steps:
        cmd += ["--steps", str(a.steps)]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    p = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.perf_counter() - t
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if p.returncode != 0:
        sys.exit(f"bench_time_to_skill: error: train (seed {seed}) failed: {p.stderr.strip().splitlines()[-1:]}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    evals, train_s, last = [], 0.0, 0
    for line in (out / name / "metrics.jsonl").read_text().splitlines():
        rec = json.loads(line)
        key = next((k for k in rec if k.endswith("/success")), None)
        if key is not None:
            evals.append((rec["step"], rec[key]))
        elif "steps_per_s" in rec:
            train_s += (rec["step"] - last) / rec["steps_per_s"]
            last = rec["step"]
    hit = next(((s, v) for s, v in evals if v >= a.target), None)
    step, success = hit if hit else max(evals, key=lambda e: e[1], default=(last, float("nan")))
    return {
        "seed": seed,
        "reached": hit is not None,
        "wall": wall,
        "cpu": cpu,
        "train": train_s,
        "step": step,
        "success": success,
    }


def _mean_std(xs: list[float]) -> str:
    if not xs:
        return "-"
    return f"{statistics.mean(xs):.1f} ± {statistics.stdev(xs):.1f}" if len(xs) > 1 else f"{xs[0]:.1f}"


def main(argv: list[str] | None = None) -> int:
    """Run the bench; exit code."""
    import torch

    from aerohrl.hardware import describe_cpu

    a = parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        dataset = a.dataset or build_dataset(a, Path(tmp) / "datasets")
        if not Path(dataset).is_dir():
            print(f"bench_time_to_skill: error: no dataset at {dataset}", file=sys.stderr)
            return 2
        out = a.keep or Path(tmp) / "runs"
        print(f"cpu: {describe_cpu()}; torch capability {torch.backends.cpu.get_cpu_capability()}")
        load = " ".join(f"{x:.2f}" for x in os.getloadavg())
        print(
            f"torch {torch.__version__}, {a.threads} thread(s), preset {a.preset}, task {a.task}, target {100 * a.target:.0f} % "
            f"on {a.episodes} episodes, dataset {dataset}; load average at start {load}"
        )
        print(f"{'seed':>4s} {'reached':>7s} {'wall s':>7s} {'cpu s':>7s} {'train s':>7s} {'steps':>6s} {'success %':>9s}")
        rows = []
        for seed in a.seeds:
            r = train_seed(a, dataset, seed, out)
            rows.append(r)
            print(
                f"{seed:4d} {'yes' if r['reached'] else 'no':>7s} {r['wall']:7.1f} {r['cpu']:7.1f} {r['train']:7.1f} "
                f"{r['step']:6d} {100 * r['success']:9.1f}",
                flush=True,
            )
        ok = [r for r in rows if r["reached"]]
        print(
            f"reached by {len(ok)} of {len(rows)} seeds; over those, mean ± std: wall {_mean_std([r['wall'] for r in ok])} s, "
            f"cpu {_mean_std([r['cpu'] for r in ok])} s, train {_mean_std([r['train'] for r in ok])} s, "
            f"steps {_mean_std([float(r['step']) for r in ok])}, success {_mean_std([100 * r['success'] for r in ok])} %"
        )
        print(f"load average at the end {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
