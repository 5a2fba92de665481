"""End-to-end `datagen build` wall time, and how it scales with the number of goals.

    python bench/bench_datagen.py                 # 250, 1000, 2500, 10000 goals
    python bench/bench_datagen.py --goals 250 1000
    python bench/bench_datagen.py --goals 10000 100000 --recipe --action-noise 1 0.5   # a recipe at scale

Each size runs the real command (`python -m aerohrl.datagen.cli build`) in a fresh
output directory, so interpreter start-up, imports and writing are all counted; the
peak resident memory is the child's (``resource.getrusage(RUSAGE_CHILDREN)``, one
child at a time, so each row's maximum is its own: rows run smallest first).

Targets (issue 2): 250 goals <= 10 s; 10,000 goals <= 3 min, cost linear in goals.
"""

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--goals", type=int, nargs="+", default=[250, 1000, 2500, 10000])
    ap.add_argument("--recipe", nargs=argparse.REMAINDER, default=[], help="datagen build flags of a recipe (last)")
    a = ap.parse_args()
    print(f"cores: {os.cpu_count()}   python: {sys.version.split()[0]}   recipe: {' '.join(a.recipe) or 'default'}")
    print(f"{'goals':>7} {'wall s':>8} {'ms/goal':>8} {'peak RSS GB':>12}  frames")
    rows = []
    for n in sorted(a.goals):
        with tempfile.TemporaryDirectory(dir=os.environ.get("BENCH_TMP")) as d:
            t0 = time.perf_counter()
            p = subprocess.run([sys.executable, "-m", "aerohrl.datagen.cli", "build", "--goals", str(n), "--out", d, "--quiet",
                                *a.recipe], capture_output=True, text=True)
            wall = time.perf_counter() - t0
            if p.returncode != 0:
                sys.exit(f"build failed: {p.stderr.strip()}")
            frames = p.stdout.split(" frames")[0].rsplit(" ", 1)[-1]
        rss = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1e6  # KB -> GB, max over children so far
        rows.append((n, wall))
        print(f"{n:>7} {wall:>8.2f} {1000 * wall / n:>8.2f} {rss:>12.2f}  {frames}", flush=True)
    if len(rows) >= 2:
        (n0, w0), (n1, w1) = rows[0], rows[-1]
        print(f"marginal cost {1000 * (w1 - w0) / (n1 - n0):.2f} ms/goal between {n0} and {n1} goals")


if __name__ == "__main__":
    main()
