"""``make results``: the whole chapter-3 reproduction, data to tables.

    .venv/bin/python experiments/reproduce.py                       # the real thing (hours on 2 CPU cores)
    .venv/bin/python experiments/reproduce.py --steps 200 --episodes 20 --checkpoints 2 --runs /tmp/r --out /tmp/res \
        --results-dir /tmp/pages                                    # a smoke run of the same pipeline

1. ``datagen build --goals 250`` (seed 0; verified, not rebuilt, when it exists);
2. ``train --algo A --preset cpu --checkpoint-every STEPS/30 --seed S`` for GCSL, TD3-BC,
   TD3-AWBC and CQL and every seed of ``--seeds`` (0 1 2; seed 0's runs keep the names
   ``ALGO-cpu`` of the one-seed tables, the others are ``ALGO-cpu-sS``) through ``aerohrl sweep``'s
   training tasks (``aerohrl.sweep.train_runs``: Ray tasks of one CPU each on a local Ray of ``--jobs``
   (2) cores, or on the cluster at ``--address``), one thread each (an existing run is resumed, a finished one is left as it is; a task whose worker dies is
   retried and resumes its run); checkpoints every 1/30 of the run so that "the last 10 checkpoints"
   are the final third of training, as the thesis' last 10 epochs are its end;
3. ``aerohrl eval`` Reach-Desired, Reach-Intermediate and the Reach-Novel diagnostic for
   every run (last 10 checkpoints x 250 episodes), OOD without planner, with the
   single-goal planner (Eq. 3.7) and with 2 planned goals (Eq. 3.6, beam search,
   re-planning) for GCSL, and ``aerohrl eval oracle`` (what any single-goal planner could
   reach with that policy);
   An evaluation whose summary already covers the run's newest checkpoints with the
   same episodes is kept (``--reevaluate`` redoes them all);
4. the planner experiment (``--continuations N``, default 5000; 0 skips it): ``datagen
   build --goals N --continuations N`` (rest-start flights plus continuation episodes,
   datagen/README), GCSL with the cpu preset on it for ``--continuation-steps`` with
   ``--critic-random-goal-prob`` (run ``gcsl-cpu-cont``), trained beside the others and
   evaluated like GCSL (OOD with every planner, oracle);
5. ``aerohrl eval table`` -> ``OUT/tables.md`` + CSV, trajectory plots and learning
   curves under ``OUT/``, and the tables with the wall time of every stage written as the
   dated page ``RESULTS_DIR/YYYY-MM-DD-chapter3-tables.md`` (``--results-dir``, default
   docs/results; the command first) and as ``OUT/results.md``.

Every stage but training is the real command line run as a subprocess with ``OMP_NUM_THREADS=1``
(with ``--in-process``: the same command line called as its module's ``main(argv)`` in this
interpreter with one thread, its output captured alike: no new interpreter's start-up, imports
and torch, per command, which is most of what a smoke run's evaluations cost);
training goes through ``aerohrl sweep``'s Ray tasks (``aerohrl.sweep.train_runs``), one thread each.
"""

from __future__ import annotations

import shlex
import sys
import time
from datetime import datetime, timezone
from pathlib import Path

from aerohrl import cli_types as T
from aerohrl.errors import ArgumentParser, run_cli
from aerohrl.eval.results import evaluation_is_current, write_results_page
from study_tools import run_logged

PROG = "experiments/reproduce.py"
ALGOS = ("gcsl", "td3bc", "td3awbc", "cql")
STUDY = "chapter3-tables"  # the results page: RESULTS_DIR/YYYY-MM-DD-chapter3-tables.md
CONT_RANDOM_GOAL = 0.3  # the planner experiment's --critic-random-goal-prob (eval/README.md)


def _train_all(items: list[tuple[str, Path, dict]], log, jobs: int, address: str | None = None) -> dict[str, float]:
    """Train the runs ``(label, run folder, config)`` through ``aerohrl sweep``'s Ray tasks
    (aerohrl/sweep.py: one CPU each on a local Ray of ``jobs`` cores, or on the cluster at
    ``address``; a run is started, resumed or left finished; a task whose worker dies is
    retried and resumes its run); the seconds each took here."""
    from aerohrl.algorithms.config import to_dict
    from aerohrl.sweep import train_runs

    def note(line: str) -> None:
        print(line, flush=True)
        log.write(line + "\n")
        log.flush()

    # the longest (CQL, the continuation runs: listed last) first, so that 2 cores end together
    done = train_runs(
        [(label, str(rd.resolve()), to_dict(cfg)) for label, rd, cfg in reversed(items)],
        address=address,
        num_cpus=None if address else jobs,
        log=note,
    )
    return {label: done[label]["seconds"] for label, *_ in items}


def main(argv: list[str] | None = None) -> int:
    """``make results``: build the data, train all four algorithms, evaluate them and write the
    tables and plots; exit code."""
    ap = ArgumentParser(prog=PROG, description="Build data, train all four algorithms, evaluate, write the tables.")
    ap.add_argument("--datasets", default="datasets", help="dataset root [datasets]")
    ap.add_argument("--runs", default="runs", help="runs root [runs]")
    ap.add_argument("--out", default="results", help="tables and plots [results]")
    ap.add_argument(
        "--results-dir",
        default="docs/results",
        help="folder of the dated results page YYYY-MM-DD-chapter3-tables.md [docs/results]",
    )
    ap.add_argument("--algos", nargs="+", default=list(ALGOS))
    ap.add_argument(
        "--seeds",
        nargs="+",
        type=T.nonneg_int,
        default=[0, 1, 2],
        help="training seeds of every run; seed 0 keeps the names ALGO-cpu, others ALGO-cpu-sN [0 1 2]",
    )
    ap.add_argument("--steps", type=T.positive_int, default=None, help="override the cpu preset's training steps (smoke runs)")
    ap.add_argument("--episodes", type=T.positive_int, default=250)
    ap.add_argument("--checkpoints", type=T.positive_int, default=10)
    ap.add_argument("--oracle-goals", type=T.positive_int, default=40, help="OOD goals of the planner oracle [40]")
    ap.add_argument("--oracle-candidates", type=T.positive_int, default=150, help="candidates of the planner oracle [150]")
    ap.add_argument(
        "--jobs",
        type=T.positive_int,
        default=2,
        help="local Ray's core budget: training runs at a time, one thread each [2 = the 2 cores]",
    )
    ap.add_argument("--address", default=None, help="run the training stage on the Ray cluster at HOST:PORT (aerohrl sweep's)")
    ap.add_argument("--planner-algos", nargs="+", default=["gcsl"], help="runs evaluated on OOD with the planners [gcsl]")
    ap.add_argument(
        "--continuations",
        type=T.nonneg_int,
        default=5000,
        help="planner experiment: goals and continuation episodes of its dataset (0: skip it) [5000]",
    )
    ap.add_argument("--continuation-steps", type=T.positive_int, default=60000, help="planner experiment: GCSL steps [60000]")
    ap.add_argument(
        "--critic-random-goal-prob",
        type=T.nonneg_float,
        default=CONT_RANDOM_GOAL,
        help=f"planner experiment: the critics' random-goal probability [{CONT_RANDOM_GOAL}]",
    )
    ap.add_argument("--reevaluate", action="store_true", help="redo evaluations whose results are up to date")
    ap.add_argument(
        "--in-process",
        action="store_true",
        help="run the stages other than training (dataset builds, evaluations, oracle, plots, tables) in this "
        "interpreter, the same command lines called as their main(): no interpreter start-up per command (smoke runs)",
    )
    a = ap.parse_args(argv)
    command = " ".join(["python", PROG, *map(shlex.quote, sys.argv[1:] if argv is None else argv)])

    def go() -> int:
        a.seeds = list(dict.fromkeys(a.seeds))
        py = sys.executable
        out = Path(a.out)
        out.mkdir(parents=True, exist_ok=True)
        times = {}
        # the last 10 checkpoints should be the end of training (thesis: "the last 10 epochs"), not
        # the whole run (the cpu preset checkpoints every 2,500 of 15,000 steps), so take one every
        # 1/30 of the run (the last 10 then cover its final third, where the cosine rate is low)
        from aerohrl.algorithms.config import make_config

        steps = a.steps or make_config("cpu").steps
        ckpt_every = max(1, steps // 30)
        t_all = time.perf_counter()
        with open(out / "reproduce.log", "a") as log:
            log.write(f"=== {datetime.now(timezone.utc).isoformat(timespec='seconds')} {' '.join(sys.argv)}\n")

            def run(cmd: list[str]) -> str:  # a stage's command line, logged; its output
                return run_logged(cmd, log, in_process=a.in_process)

            t0 = time.perf_counter()
            build = [py, "-m", "aerohrl.datagen.cli", "build", "--seed", "0", "--out", a.datasets, "--quiet"]
            ds = run(build + ["--goals", "250"]).strip().splitlines()[-1].strip()
            if a.continuations:
                n = str(a.continuations)
                ds_cont = run(build + ["--goals", n, "--continuations", n]).strip().splitlines()[-1].strip()
            times["datasets"] = time.perf_counter() - t0

            def config(**kw):  # the cpu preset, as `train --preset cpu --FLAG ...` would make it
                return make_config("cpu", **kw)

            runs, items = [], []  # (run dir, algorithm, label, seed); seed 0 keeps the one-seed names (runs reused)
            for seed in a.seeds:
                sfx = f"-s{seed}" if seed else ""
                for algo in a.algos:
                    rd = Path(a.runs) / f"{algo}-cpu{sfx}"
                    items.append(
                        (
                            f"train {algo}{sfx}",
                            rd,
                            config(
                                algo=algo, dataset=str(Path(ds).resolve()), seed=seed, steps=a.steps, checkpoint_every=ckpt_every
                            ),
                        )
                    )
                    runs.append((rd, algo, f"{algo}{sfx}", seed))
                if a.continuations:
                    rd = Path(a.runs) / f"gcsl-cpu-cont{sfx}"
                    c_steps = a.steps or a.continuation_steps
                    items.append(
                        (
                            f"train gcsl-cont{sfx}",
                            rd,
                            config(
                                algo="gcsl",
                                dataset=str(Path(ds_cont).resolve()),
                                seed=seed,
                                steps=c_steps,
                                checkpoint_every=max(1, c_steps // 30),
                                critic_random_goal_prob=a.critic_random_goal_prob,
                            ),
                        )
                    )
                    runs.append((rd, "gcsl", f"gcsl-cont{sfx}", seed))
            times.update(_train_all(items, log, a.jobs, a.address))
            ev = [py, "-m", "aerohrl.eval.cli"]
            oracles = []

            def evaluate(rd: Path, name: str, flags: list[str], checkpoints: int | None = None) -> None:
                k = checkpoints or a.checkpoints
                if a.reevaluate or not evaluation_is_current(rd, name, a.episodes, k):
                    run(ev + flags + ["--run", str(rd), "--episodes", str(a.episodes), "--checkpoints", str(k), "--quiet"])

            for rd, algo, label, seed in runs:
                t0 = time.perf_counter()
                for t in ("reach-desired", "reach-intermediate", "reach-novel"):
                    evaluate(rd, t, ["--task", t])
                    if algo in a.planner_algos and seed == a.seeds[0]:  # the floors beside it: hover, its policy without goal
                        for f in ("hover", "no-goal"):
                            evaluate(rd, f"{t}-floor-{f}", ["--task", t, "--floor", f], checkpoints=1)
                if algo in a.planner_algos:
                    for name, pl in (("none", ["none"]), ("single", ["single"]), ("multi2", ["multi", "--waypoints", "2"])):
                        evaluate(rd, f"ood-{name}", ["--task", "ood", "--planner"] + pl)
                if algo in a.planner_algos and seed == a.seeds[0]:  # the oracle and the figures: the first seed's run
                    rep = run(
                        ev
                        + [
                            "oracle",
                            "--run",
                            str(rd),
                            "--goals",
                            str(a.oracle_goals),
                            "--candidates",
                            str(a.oracle_candidates),
                            "--quiet",
                        ]
                    )
                    oracles.append(
                        f"Oracle of the single-goal planner for {label} (`aerohrl eval oracle --run {rd} --goals "
                        f"{a.oracle_goals} --candidates {a.oracle_candidates}`, planning/oracle.py):\n\n```\n"
                        + "\n".join(line for line in rep.strip().splitlines() if not line.startswith("report:"))
                        + "\n```\n"
                    )
                    run(
                        ev
                        + ["plot", "--task", "ood", "--planner", "single", "--run", str(rd), "-o", str(out / f"ood-{label}.png")]
                    )
                run(ev + ["plot", "--task", "reach-desired", "--run", str(rd), "-o", str(out / f"reach-desired-{label}.png")])
                times[f"eval {label}"] = time.perf_counter() - t0
            dirs = [str(rd) for rd, *_ in runs]
            run(ev + ["plot", "--curves", *dirs, "-o", str(out / "learning-curves.png")])
            tables = run(ev + ["table", *dirs, "-o", str(out / "tables")])
        total = time.perf_counter() - t_all
        stamp = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
        wall = ", ".join(f"{k} {v / 60:.1f} min" for k, v in times.items())
        # the runs' own step rates: true training times also when this invocation resumed runs
        from aerohrl.algorithms.runs import summary

        trained = ", ".join(f"{label} {summary(rd)['training_s'] / 60:.1f} min" for rd, _, label, _ in runs)
        block = (
            f"Reproduced by `make results` on {stamp} (dataset `{ds}`"
            + (
                f"; planner experiment `gcsl-cpu-cont` on `{ds_cont}`, {a.steps or a.continuation_steps} steps, "
                f"critic random-goal probability {a.critic_random_goal_prob}"
                if a.continuations
                else ""
            )
            + "; cpu preset"
            + (f", {a.steps} training steps" if a.steps else "")
            + f", {a.episodes} episodes x last {a.checkpoints} checkpoints)"
            f"; wall time {total / 60:.1f} min ({wall}); gradient steps of each run ({a.jobs} at a time, one thread "
            f"each): {trained}.\n\n" + tables + "".join("\n" + o for o in oracles)
        )
        (out / "results.md").write_text(block)
        page = write_results_page(a.results_dir, STUDY, command, block, title="Chapter 3 tables (make results)")
        print(f"tables written to {page} and {out / 'results.md'}; total {total / 60:.1f} min")
        return 0

    return run_cli(PROG, go)


if __name__ == "__main__":
    sys.exit(main())
