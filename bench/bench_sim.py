"""Throughput of the batched simulator (docs/spec.md "Vehicle and simulator").

    .venv/bin/python bench/bench_sim.py [--batches 1 64 1024 4096 16384] [--seconds 1.0]

``--processes 2`` splits each batch between this process and a worker process (the
2-core figure); ``--threads 2`` splits it between threads (GIL-bound, slower at 4096).
Prints vehicle-steps per second (one step = one 100 Hz control step of CTBR input:
5 RK4 substeps at 500 Hz with the rate loop at each) for each batch size, the split
used and the machine's load average (the timings are the best of several
repeats, which filters out other processes' bursts but not a sustained load). Target:
>= 1,000,000 vehicle-steps/s at a batch of 4096 on 2 cores.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from aerohrl.sim import BatchedQuadrotor, get_preset


def bench(n: int, seconds: float, threads: int, processes: int, preset: str) -> tuple[float, float, str]:
    """Best time per control step (s) over repeats, median, and the sim's split."""
    p = get_preset(preset)
    sim = BatchedQuadrotor(p, n, threads=threads, processes=processes)
    rng = np.random.default_rng(0)
    a = np.column_stack([np.full(n, 9.81) + rng.uniform(-1, 1, n), rng.uniform(-0.5, 0.5, (n, 3))])
    sim.step(a)  # warm up
    per_rep = max(3, int(0.1 / max(1e-6, 1.5e-6 * n + 1e-3)))  # ~0.1 s per repeat
    times = []
    t_end = time.perf_counter() + seconds
    while time.perf_counter() < t_end or len(times) < 5:
        sim.reset()
        t0 = time.perf_counter()
        for _ in range(per_rep):
            sim.step(a)
        times.append((time.perf_counter() - t0) / per_rep)
    split = f"{sim.processes}p" if sim.processes > 1 else f"{sim.threads}t"
    sim.close()
    return min(times), float(np.median(times)), split


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--batches", type=int, nargs="+", default=[1, 64, 1024, 4096, 16384])
    ap.add_argument("--seconds", type=float, default=1.0, help="time budget per batch size")
    ap.add_argument("--threads", type=int, default=1, help="thread split of the batch (default 1)")
    ap.add_argument(
        "--processes", type=int, default=1, help="process split of the batch (this process + workers over shared memory)"
    )
    ap.add_argument("--preset", default="hummingbird")
    args = ap.parse_args()
    load = os.getloadavg()
    from aerohrl.hardware import describe_cpu

    print(f"# {describe_cpu()}, numpy {np.__version__}, load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}")
    print(f"# preset {args.preset}, dt 0.01 s, 5 RK4 substeps, CTBR rate loop at 500 Hz")
    print(f"{'batch':>7} {'split':>7} {'ms/step':>9} {'veh-steps/s (best)':>19} {'(median)':>12}")
    for n in args.batches:
        best, med, th = bench(n, args.seconds, args.threads, args.processes, args.preset)
        print(f"{n:>7} {th:>7} {best * 1e3:>9.3f} {n / best:>19,.0f} {n / med:>12,.0f}", flush=True)
    print(f"# load average after: {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
