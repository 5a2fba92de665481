"""End-to-end `datagen build` wall time, and how it scales with the number of goals.

    python bench/bench_datagen.py                 # 250, 1000, 2500, 10000 goals
    python bench/bench_datagen.py --goals 250 1000

Each size runs the real command (`python -m aerohrl.datagen.cli build`) in a fresh
output directory, so interpreter start-up, imports and writing are all counted.
Targets (issue 2): 250 goals <= 10 s; 10,000 goals <= 3 min, cost linear in goals.
"""

import argparse
import os
import subprocess
import sys
import tempfile
import time


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--goals", type=int, nargs="+", default=[250, 1000, 2500, 10000])
    a = ap.parse_args()
    print(f"cores: {os.cpu_count()}   python: {sys.version.split()[0]}")
    print(f"{'goals':>7} {'wall s':>8} {'ms/goal':>8}  frames")
    rows = []
    for n in a.goals:
        with tempfile.TemporaryDirectory() as d:
            t0 = time.perf_counter()
            p = subprocess.run([sys.executable, "-m", "aerohrl.datagen.cli", "build", "--goals", str(n), "--out", d, "--quiet"],
                               capture_output=True, text=True)
            wall = time.perf_counter() - t0
            if p.returncode != 0:
                sys.exit(f"build failed: {p.stderr.strip()}")
            frames = p.stdout.split(" frames")[0].rsplit(" ", 1)[-1]
        rows.append((n, wall))
        print(f"{n:>7} {wall:>8.2f} {1000 * wall / n:>8.2f}  {frames}")
    if len(rows) >= 2:
        (n0, w0), (n1, w1) = rows[0], rows[-1]
        print(f"marginal cost {1000 * (w1 - w0) / (n1 - n0):.2f} ms/goal between {n0} and {n1} goals")


if __name__ == "__main__":
    main()
