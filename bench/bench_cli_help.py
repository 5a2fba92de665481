"""How long `--help` takes for every command (target: under 1 s each).

    python bench/bench_cli_help.py              # best of 3 runs per command
    python bench/bench_cli_help.py --repeat 5

Each command runs as the user runs it, in a fresh interpreter (`python -m <entry>
... --help`), so interpreter start-up and every import are counted. The figure is the
best of ``--repeat`` runs (the least disturbed by other load); the interpreter alone
(`python -c pass`) is printed first for scale. The last column lists the heavy modules
(torch, lerobot, torchrl, scipy.ndimage) the help imported: it should be empty. No
assertion: the numbers depend on the machine and its load.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time

# (what the user types, the module run with -m, its arguments)
COMMANDS = [
    ("aerohrl", "aerohrl.cli", []),
    ("datagen", "aerohrl.datagen.cli", []),
    ("datagen build", "aerohrl.datagen.cli", ["build"]),
    ("datagen export", "aerohrl.datagen.cli", ["export"]),
    ("datagen push", "aerohrl.datagen.cli", ["push"]),
    ("train", "aerohrl.algorithms.cli", []),
    ("aerohrl eval", "aerohrl.cli", ["eval"]),
    ("aerohrl eval table", "aerohrl.cli", ["eval", "table"]),
    ("aerohrl eval plot", "aerohrl.cli", ["eval", "plot"]),
    ("aerohrl eval oracle", "aerohrl.cli", ["eval", "oracle"]),
    ("aerohrl runs show", "aerohrl.cli", ["runs", "show"]),
    ("aerohrl ipp", "aerohrl.cli", ["ipp"]),
    ("aerohrl ipp lattice build", "aerohrl.cli", ["ipp", "lattice", "build"]),
    ("aerohrl ipp train", "aerohrl.cli", ["ipp", "train"]),
    ("aerohrl ipp bench", "aerohrl.cli", ["ipp", "bench"]),
    ("aerohrl ipp show", "aerohrl.cli", ["ipp", "show"]),
    ("aerohrl ipp curve", "aerohrl.cli", ["ipp", "curve"]),
    ("aerohrl sweep", "aerohrl.cli", ["sweep"]),
]
HEAVY = ("torch", "lerobot", "torchrl", "scipy.ndimage")
PROBE = """import runpy, sys
sys.argv = [{prog!r}] + {args!r}
try:
    runpy.run_module({module!r}, run_name="__main__")
except SystemExit:
    pass
sys.stdout.flush()
print("\\nHEAVY=" + ",".join(m for m in {heavy!r} if m in sys.modules), file=sys.stderr)
"""


def time_once(argv: list[str]) -> float:
    t = time.perf_counter()
    subprocess.run(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=False)
    return time.perf_counter() - t


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3, help="runs per command; the best is shown [3]")
    a = ap.parse_args()
    base = min(time_once([sys.executable, "-c", "pass"]) for _ in range(a.repeat))
    print(f"{'command':<28} {'--help (s)':>10}  heavy imports")
    print(f"{'(python -c pass)':<28} {base:>10.3f}")
    worst = 0.0
    for name, module, args in COMMANDS:
        argv = [sys.executable, "-m", module, *args, "--help"]
        best = min(time_once(argv) for _ in range(a.repeat))
        probe = subprocess.run(
            [sys.executable, "-c", PROBE.format(prog=name, args=[*args, "--help"], module=module, heavy=HEAVY)],
            capture_output=True,
            text=True,
            check=False,
        )
        heavy = next((ln[len("HEAVY=") :] for ln in probe.stderr.splitlines() if ln.startswith("HEAVY=")), "?")
        worst = max(worst, best)
        print(f"{name:<28} {best:>10.3f}  {heavy or '-'}")
    print(f"slowest: {worst:.3f} s (target < 1 s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
