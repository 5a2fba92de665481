"""``make results``: the whole chapter-3 reproduction, data to tables.

    .venv/bin/python -m aerohrl.eval.reproduce                      # the real thing (hours on 2 CPU cores)
    .venv/bin/python -m aerohrl.eval.reproduce --steps 200 --episodes 20 --checkpoints 2 --runs /tmp/r --out /tmp/res
                                                                    # a smoke run of the same pipeline

1. ``datagen build --goals 250`` (seed 0; verified, not rebuilt, when it exists);
2. ``train --algo A --preset cpu --checkpoint-every STEPS/30`` for GCSL, TD3-BC,
   TD3-AWBC and CQL, ``--jobs`` (2) at a time with one thread each (an existing run is
   resumed, a finished one is left as it is); checkpoints every 1/30 of the run so that "the last 10 checkpoints"
   are the final third of training, as the thesis' last 10 epochs are its end;
3. ``aerohrl eval`` Reach-Desired, Reach-Intermediate and the Reach-Novel diagnostic for
   every run (last 10 checkpoints x 250 episodes), OOD without planner, with the
   single-goal planner (Eq. 3.7) and with 2 planned goals (Eq. 3.6, beam search,
   re-planning) for GCSL, and ``aerohrl eval oracle`` (what any single-goal planner could
   reach with that policy);
4. ``aerohrl eval table`` -> ``OUT/tables.md`` + CSV, trajectory plots and learning
   curves under ``OUT/``, and the tables with the wall time of every stage written into
   ``README`` between the lines ``<!-- results:begin -->`` and ``<!-- results:end -->``
   (when those markers exist; ``OUT/results.md`` always).

Every stage is the real command line run as a subprocess with ``OMP_NUM_THREADS=1``.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from datetime import datetime, timezone
from pathlib import Path

from aerohrl.errors import UserError, run_cli

PROG = "aerohrl.eval.reproduce"
ALGOS = ("gcsl", "td3bc", "td3awbc", "cql")
BEGIN, END = "<!-- results:begin -->", "<!-- results:end -->"


def _run(cmd: list[str], log) -> str:
    env = {**os.environ, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    print("+ " + " ".join(cmd), flush=True)
    p = subprocess.run(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    log.write("+ " + " ".join(cmd) + "\n" + p.stdout + "\n")
    log.flush()
    if p.returncode != 0:
        tail = p.stdout.strip().splitlines()[-1:] or ["(no output)"]
        raise UserError(f"`{' '.join(cmd[:4])} ...` failed (exit {p.returncode}): {tail[0]}")
    return p.stdout


def _run_parallel(cmds: list[tuple[str, list[str]]], log, jobs: int) -> dict[str, float]:
    """Run the named commands, ``jobs`` at a time (each with one thread); wall time of each.
    The longest (CQL, listed last by default) is started first."""
    import concurrent.futures as cf
    import io

    def one(item):
        name, cmd = item
        buf = io.StringIO()
        t0 = time.perf_counter()
        _run(cmd, buf)
        return name, time.perf_counter() - t0, buf.getvalue()

    out = {}
    order = list(reversed(cmds)) if jobs > 1 else cmds
    with cf.ThreadPoolExecutor(max_workers=max(1, jobs)) as ex:
        for name, dt, text in ex.map(one, order):
            log.write(text)
            log.flush()
            out[name] = dt
    return {name: out[name] for name, _ in cmds}


def update_readme(readme: Path, block: str) -> bool:
    if not readme.exists():
        return False
    text = readme.read_text()
    if BEGIN not in text or END not in text:
        return False
    head, rest = text.split(BEGIN, 1)
    _, tail = rest.split(END, 1)
    tmp = readme.with_name(f".{readme.name}.tmp-{os.getpid()}")
    tmp.write_text(head + BEGIN + "\n" + block.rstrip() + "\n" + END + tail)
    tmp.replace(readme)
    return True


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog=PROG, description="Build data, train all four algorithms, evaluate, write the tables.")
    ap.add_argument("--datasets", default="datasets", help="dataset root [datasets]")
    ap.add_argument("--runs", default="runs", help="runs root [runs]")
    ap.add_argument("--out", default="results", help="tables and plots [results]")
    ap.add_argument("--readme", default="README.md", help="README to write the tables into (between the markers) [README.md]")
    ap.add_argument("--algos", nargs="+", default=list(ALGOS))
    ap.add_argument("--steps", type=int, default=None, help="override the cpu preset's training steps (smoke runs)")
    ap.add_argument("--episodes", type=int, default=250)
    ap.add_argument("--checkpoints", type=int, default=10)
    ap.add_argument("--oracle-goals", type=int, default=40, help="OOD goals of the planner oracle [40]")
    ap.add_argument("--oracle-candidates", type=int, default=150, help="candidates of the planner oracle [150]")
    ap.add_argument("--jobs", type=int, default=2, help="training runs at a time, one thread each [2 = the 2 cores]")
    ap.add_argument("--planner-algos", nargs="+", default=["gcsl"], help="runs evaluated on OOD with the planners [gcsl]")
    a = ap.parse_args(argv)

    def go() -> int:
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
            t0 = time.perf_counter()
            ds = _run([py, "-m", "aerohrl.datagen.cli", "build", "--goals", "250", "--seed", "0", "--out", a.datasets, "--quiet"],
                      log).strip().splitlines()[-1].strip()
            times["dataset"] = time.perf_counter() - t0
            runs, cmds = [], []
            for algo in a.algos:
                rd = Path(a.runs) / f"{algo}-cpu"
                if (rd / "config.json").exists():
                    cmd = [py, "-m", "aerohrl.algorithms.cli", "--resume", str(rd), "--no-progress"]
                    if a.steps:
                        cmd += ["--steps", str(a.steps)]
                else:
                    cmd = [py, "-m", "aerohrl.algorithms.cli", "--algo", algo, "--dataset", ds, "--preset", "cpu", "--out", a.runs,
                           "--name", rd.name, "--no-progress", "--checkpoint-every", str(ckpt_every)] \
                        + (["--steps", str(a.steps)] if a.steps else [])
                cmds.append((f"train {algo}", cmd))
                runs.append(rd)
            times.update(_run_parallel(cmds, log, a.jobs))
            ev = [py, "-m", "aerohrl.eval.cli"]
            oracles = []
            common = ["--episodes", str(a.episodes), "--checkpoints", str(a.checkpoints), "--no-progress"]
            for rd, algo in zip(runs, a.algos):
                t0 = time.perf_counter()
                for t in ("reach-desired", "reach-intermediate", "reach-novel"):
                    _run(ev + ["--task", t, "--run", str(rd)] + common, log)
                if algo in a.planner_algos:
                    for pl in (["none"], ["single"], ["multi", "--waypoints", "2"]):
                        _run(ev + ["--task", "ood", "--run", str(rd), "--planner"] + pl + common, log)
                    rep = _run(ev + ["oracle", "--run", str(rd), "--goals", str(a.oracle_goals), "--candidates",
                                     str(a.oracle_candidates), "--no-progress"], log)
                    oracles.append(f"Oracle of the single-goal planner for {algo} (`aerohrl eval oracle --run {rd} --goals "
                                   f"{a.oracle_goals} --candidates {a.oracle_candidates}`, eval/oracle.py):\n\n```\n"
                                   + "\n".join(line for line in rep.strip().splitlines() if not line.startswith("report:")) + "\n```\n")
                    _run(ev + ["plot", "--task", "ood", "--planner", "single", "--run", str(rd), "-o", str(out / f"ood-{algo}.png")], log)
                _run(ev + ["plot", "--task", "reach-desired", "--run", str(rd), "-o", str(out / f"reach-desired-{algo}.png")], log)
                times[f"eval {algo}"] = time.perf_counter() - t0
            _run(ev + ["plot", "--curves", *map(str, runs), "-o", str(out / "learning-curves.png")], log)
            tables = _run(ev + ["table", *map(str, runs), "-o", str(out / "tables")], log)
        total = time.perf_counter() - t_all
        stamp = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
        wall = ", ".join(f"{k} {v / 60:.1f} min" for k, v in times.items())
        # the runs' own step rates: true training times also when this invocation resumed runs
        from aerohrl.algorithms.runs import summary

        trained = ", ".join(f"{algo} {summary(rd)['training_s'] / 60:.1f} min" for rd, algo in zip(runs, a.algos))
        block = (f"Reproduced by `make results` on {stamp} (dataset `{ds}`, cpu preset"
                 + (f", {a.steps} training steps" if a.steps else "") + f", {a.episodes} episodes x last {a.checkpoints} checkpoints)"
                 f"; wall time {total / 60:.1f} min ({wall}); gradient steps of each run ({a.jobs} at a time, one thread "
                 f"each): {trained}.\n\n" + tables + "".join("\n" + o for o in oracles))
        (out / "results.md").write_text(block)
        where = a.readme if update_readme(Path(a.readme), block) else f"{out / 'results.md'} (no results markers in {a.readme})"
        print(f"tables written to {where}; total {total / 60:.1f} min")
        return 0

    return run_cli(PROG, go)


if __name__ == "__main__":
    sys.exit(main())
