"""The IPP learned targets over three seeds (ipp/README.md "The learned targets over three seeds").

    python experiments/ipp_learned_targets.py                       # train what is missing, bench, write the page
    python experiments/ipp_learned_targets.py --bench-only          # bench the runs that are there
    python experiments/ipp_learned_targets.py --extra-run runs/ipp-thesis-b9250-x2   # one more row in the bench

1. ``aerohrl ipp train --preset P --seed S --name NAME`` for the presets ``--presets``
   (cpu: imitation of the detect planner, DAgger; thesis: map-only actor-critic, PPO) and
   the seeds ``--seeds`` (7 8 9). Seed 7 keeps the one-seed names ``ipp-P-b9250``, the
   others are ``ipp-P-b9250-sS`` (b9250: the default budget). A finished run is left as
   it is, an unfinished one resumed (``ipp train --resume``: the same weights as an
   uninterrupted run), a missing one started.
2. ``aerohrl ipp bench --all --envs 100 --threads 1 -o OUT --run ...`` with every run's
   ``model.pt``, and for the cpu preset also its ``best.pt`` (the best of its validations),
   plus ``--extra-run`` rows: the Table 2.1 analogue with every baseline, and each recipe
   given with several seeds as a claim over seeds (per-seed means, mean ± std, the
   seed-averaged policy paired with every baseline).
3. The bench's Markdown goes to the dated page ``RESULTS_DIR/YYYY-MM-DD-ipp-learned-targets.md``
   (``--results-dir``, default docs/results), the command first.

Cost on 2 cores, one thread each: cpu preset 15-27 min per seed (1.4 GB), thesis preset
11 min per seed (1.1 GB), the bench about 2 min. Interrupt it at will and run it again.
"""

from __future__ import annotations

import shlex
import sys
from pathlib import Path

from aerohrl import cli_types as T
from aerohrl.errors import ArgumentParser, UserError, run_cli

PROG = "experiments/ipp_learned_targets.py"
STUDY = "ipp-learned-targets"  # the results page: RESULTS_DIR/YYYY-MM-DD-ipp-learned-targets.md
PRESETS = ("cpu", "thesis")
SEEDS = (7, 8, 9)
FIRST_SEED = 7  # the presets' own seed: its run keeps the one-seed name


def run_name(preset: str, seed: int) -> str:
    """The run of a preset and seed: ``ipp-PRESET-b9250`` (seed 7) or ``ipp-PRESET-b9250-sSEED``."""
    return f"ipp-{preset}-b9250" + ("" if seed == FIRST_SEED else f"-s{seed}")


def finished(run: Path) -> bool:
    """Has the run logged its last iteration and saved the checkpoint after it?"""
    from aerohrl.ipp.curve import read_metrics
    from aerohrl.ipp.train import load_run_config

    ck, log = run / "checkpoint.pt", run / "metrics.jsonl"
    if not (ck.exists() and log.exists()):
        return False
    try:
        last = read_metrics(run)[-1]["iteration"]
    except UserError:
        return False
    return last >= load_run_config(run).total_iterations and ck.stat().st_mtime >= log.stat().st_mtime


def ipp(argv: list[str]) -> None:
    """``aerohrl ipp ARGV`` in this process; UserError when it fails (its one-line error printed)."""
    from aerohrl.ipp.cli import main

    print("+ aerohrl ipp " + " ".join(argv), flush=True)
    code = main(argv)
    if code != 0:
        raise UserError(f"`aerohrl ipp {' '.join(argv[:3])} ...` failed (exit {code})")


def train(preset: str, seed: int, runs: Path, threads: int) -> Path:
    """Start, resume or keep the run of ``preset`` and ``seed``; its folder."""
    run = runs / run_name(preset, seed)
    if finished(run):
        print(f"{run}: finished before", flush=True)
    elif (run / "checkpoint.pt").exists():
        ipp(["train", "--resume", str(run), "--quiet"])
    elif run.exists():
        raise UserError(f"{run} holds no checkpoint (stopped in its first iteration?): remove it and run this again")
    else:
        ipp(
            [
                "train",
                "--preset",
                preset,
                "--seed",
                str(seed),
                "--threads",
                str(threads),
                "--out",
                str(runs),
                "--name",
                run.name,
                "--quiet",
            ]
        )
    return run


def main(argv: list[str] | None = None) -> int:
    """Train the learned IPP policies over seeds and bench them with every baseline; exit code."""
    ap = ArgumentParser(
        prog=PROG,
        description="Train the IPP learned policies (cpu and thesis presets) over seeds, bench "
        "them with every baseline on the test worlds, write the results page.",
    )
    ap.add_argument("--runs", type=Path, default=Path("runs"), help="folder of the training runs [runs]")
    ap.add_argument("--out", type=Path, default=Path("runs/ipp-bench-seeds"), help="the bench's files [runs/ipp-bench-seeds]")
    ap.add_argument("--presets", nargs="+", default=list(PRESETS), choices=PRESETS, help="[cpu thesis]")
    ap.add_argument("--seeds", nargs="+", type=T.nonneg_int, default=list(SEEDS), help="[7 8 9]")
    ap.add_argument("--envs", type=T.positive_int, default=100, help="test worlds of the bench [100]")
    ap.add_argument("--threads", type=T.positive_int, default=1, help="torch threads of training and bench [1]")
    ap.add_argument(
        "--extra-run",
        action="append",
        default=[],
        metavar="RUN",
        help="another run (or policy file) benched beside them; repeatable",
    )
    ap.add_argument("--bench-only", action="store_true", help="train nothing; bench the runs that are there")
    ap.add_argument(
        "--results-dir",
        type=Path,
        default=Path("docs/results"),
        help="folder of the dated results page YYYY-MM-DD-ipp-learned-targets.md [docs/results]",
    )
    a = ap.parse_args(argv)
    command = " ".join(["python", PROG, *map(shlex.quote, sys.argv[1:] if argv is None else argv)])

    def go() -> int:
        from aerohrl.eval.results import write_results_page

        seeds = list(dict.fromkeys(a.seeds))
        runs = []
        for preset in a.presets:
            for seed in seeds:
                run = a.runs / run_name(preset, seed)
                if not a.bench_only:
                    train(preset, seed, a.runs, a.threads)
                elif not finished(run):
                    raise UserError(f"{run} is not a finished run (drop --bench-only to train it)")
                runs.append((preset, run))
        # per preset its runs' final policies, then (cpu) their best validations: the README's row order
        bench_runs = []
        for preset in a.presets:
            mine = [r for p, r in runs if p == preset]
            bench_runs += [str(r) for r in mine] + ([str(r / "best.pt") for r in mine] if preset == "cpu" else [])
        bench_runs += a.extra_run
        ipp(
            [
                "bench",
                "--all",
                "--envs",
                str(a.envs),
                "--threads",
                str(a.threads),
                "-o",
                str(a.out),
                *[x for r in bench_runs for x in ("--run", r)],
                "--quiet",
            ]
        )
        md = (a.out / "ipp_bench.md").read_text()
        body = (
            f"`aerohrl ipp bench --all --envs {a.envs}` on the seeded test worlds (seed 1000, centre start) with the "
            f"runs {', '.join(f'`{r}`' for r in bench_runs)}.\n\n" + md
        )
        page = write_results_page(
            a.results_dir,
            STUDY,
            command,
            body,
            title="IPP learned targets over seeds",
            figures=[a.out / "ipp_kl.png"] if (a.out / "ipp_kl.png").exists() else [],
        )
        print(f"bench written to {a.out} and {page}", flush=True)
        return 0

    return run_cli(PROG, go)


if __name__ == "__main__":
    sys.exit(main())
