"""Throughput of the batched simulator (docs/spec.md "Vehicle and simulator").

    .venv/bin/python bench/bench_sim.py [--batches 1 64 1024 4096 16384] [--seconds 1.0] [--dtype float32]

``--processes 2`` splits each batch between this process and a worker process (the
2-core figure); ``--threads 2`` splits it between threads (GIL-bound, slower at 4096);
``--dtype float32`` runs the simulator's explicit float32 mode (float64 is the default).
Prints vehicle-steps per second (one step = one 100 Hz control step of CTBR input:
5 RK4 substeps at 500 Hz with the rate loop at each) for each batch size, the split
used and the machine's load average: the best and the median over repeats of wall
time, and the median per CPU-second of this process (``--processes`` > 1 leaves the
workers' CPU out of it). The best filters out other processes' bursts but not a
sustained load; on a shared machine the CPU-time figure moves least with the load.
Target: >= 1,000,000 vehicle-steps/s at a batch of 4096 on 2 cores.

``--drift N`` measures instead what float32 costs in accuracy: the datagen expert flies N
references of the default dataset spec (seed 0) on a float64 and a float32 simulator,
each closing its own loop, and the float64 expert's actions are also replayed open loop
on float32; it prints the position and attitude gap to float64 over each episode.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from aerohrl.sim import BatchedQuadrotor, get_preset


def bench(
    n: int, seconds: float, threads: int, processes: int, preset: str, dtype: str = "float64"
) -> tuple[float, float, float, str]:
    """Best wall time per control step (s) over repeats, median, median CPU time of this
    process, and the sim's split."""
    p = get_preset(preset)
    sim = BatchedQuadrotor(p, n, threads=threads, processes=processes, dtype=np.dtype(dtype).type)
    rng = np.random.default_rng(0)
    a = np.column_stack([np.full(n, 9.81) + rng.uniform(-1, 1, n), rng.uniform(-0.5, 0.5, (n, 3))])
    sim.step(a)  # warm up
    per_rep = max(3, int(0.1 / max(1e-6, 1.5e-6 * n + 1e-3)))  # ~0.1 s per repeat
    times, cpu = [], []
    t_end = time.perf_counter() + seconds
    while time.perf_counter() < t_end or len(times) < 5:
        sim.reset()
        t0, c0 = time.perf_counter(), time.process_time()
        for _ in range(per_rep):
            sim.step(a)
        times.append((time.perf_counter() - t0) / per_rep)
        cpu.append((time.process_time() - c0) / per_rep)
    split = f"{sim.processes}p" if sim.processes > 1 else f"{sim.threads}t"
    sim.close()
    return min(times), float(np.median(times)), float(np.median(cpu)), split


def drift(n: int) -> None:
    """Print the float32 - float64 gap over ``n`` expert episodes (module doc), closed and open loop."""
    from aerohrl import task
    from aerohrl.datagen import goals as goals_mod
    from aerohrl.datagen import reference
    from aerohrl.datagen.build import plan_references
    from aerohrl.datagen.expert import GeometricController
    from aerohrl.datagen.spec import load_spec
    from aerohrl.sim import rotations as rot

    spec = load_spec()
    goals, T, coeffs, _, _ = plan_references(spec, np.random.default_rng(0), n)
    params = get_preset(spec.vehicle)
    ctrl = GeometricController(params)
    length = np.ceil(T * spec.fps - 1e-9).astype(np.int64)

    def sim(dtype):
        return BatchedQuadrotor(params, n, dt=spec.dt, substeps=spec.substeps, dtype=dtype)

    s64, s32, s32_open = sim(np.float64), sim(np.float32), sim(np.float32)
    x64, x32, xo = s64.state, s32.state, s32_open.state
    gap = {k: np.zeros(n) for k in ("closed pos", "closed att", "open pos", "open att")}
    goal = goals_mod.goal_vectors(goals)
    reached = {"float64": np.zeros(n, bool), "float32": np.zeros(n, bool)}

    def angle(Ra, Rb):
        # from the skew part of Ra^T Rb: arccos of the trace loses half the digits near 0
        M = np.swapaxes(Ra, 1, 2) @ Rb
        return np.arcsin(np.clip(np.linalg.norm(rot.vee(M), axis=1), 0.0, 1.0))

    for k in range(int(length.max())):
        t = np.minimum(k * spec.dt, T)
        ref = [reference.evaluate(coeffs, t, order=o) for o in range(4)]
        a64 = ctrl(x64, *ref, yaw=0.0)
        x64, x32, xo = s64.step(a64), s32.step(ctrl(x32, *ref, yaw=0.0)), s32_open.step(a64)
        live = k < length
        R64 = x64[:, 6:15].reshape(-1, 3, 3)
        for name, x in (("closed", x32), ("open", xo)):
            pos = np.linalg.norm(x[:, :3] - x64[:, :3], axis=1)
            att = angle(R64, x[:, 6:15].reshape(-1, 3, 3))
            np.maximum(gap[f"{name} pos"], np.where(live, pos, 0.0), out=gap[f"{name} pos"])
            np.maximum(gap[f"{name} att"], np.where(live, att, 0.0), out=gap[f"{name} att"])
        end = k == length - 1
        for nm, x in (("float64", x64), ("float32", x32)):
            reached[nm][end] = task.goal_reached(task.achieved_goal(x[end]), goal[end])
    print(f"# float32 vs float64: {n} expert episodes (default spec, seed 0), {length.mean() * spec.dt:.2f} s on average")
    print("# largest gap over each episode: median / 99th percentile / max over the episodes")
    for name, v in gap.items():
        unit = "um" if name.endswith("pos") else "urad"
        q = np.percentile(v, [50, 99, 100]) * 1e6
        print(f"{name:>11}: {q[0]:8.2f} {q[1]:8.2f} {q[2]:8.2f} {unit}")
    r64, r32 = reached["float64"], reached["float32"]
    print(
        f"# goal reached at the episode's end (closed loop): float64 {r64.mean():.1%}, float32 {r32.mean():.1%}, differing in {(r64 != r32).sum()}"
    )


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--batches", type=int, nargs="+", default=[1, 64, 1024, 4096, 16384])
    ap.add_argument("--seconds", type=float, default=1.0, help="time budget per batch size")
    ap.add_argument("--threads", type=int, default=1, help="thread split of the batch (default 1)")
    ap.add_argument(
        "--processes", type=int, default=1, help="process split of the batch (this process + workers over shared memory)"
    )
    ap.add_argument("--preset", default="hummingbird")
    ap.add_argument("--dtype", default="float64", choices=["float64", "float32"], help="the simulator's float type")
    ap.add_argument("--drift", type=int, metavar="N", help="measure float32's gap to float64 over N expert episodes instead")
    args = ap.parse_args()
    if args.drift:
        drift(args.drift)
        return 0
    load = os.getloadavg()
    from aerohrl.hardware import describe_cpu

    print(f"# {describe_cpu()}, numpy {np.__version__}, load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}")
    print(f"# preset {args.preset}, {args.dtype}, dt 0.01 s, 5 RK4 substeps, CTBR rate loop at 500 Hz")
    print(f"{'batch':>7} {'split':>7} {'ms/step':>9} {'veh-steps/s (best)':>19} {'(median)':>12} {'(per CPU-s)':>12}")
    for n in args.batches:
        best, med, cpu, th = bench(n, args.seconds, args.threads, args.processes, args.preset, args.dtype)
        print(f"{n:>7} {th:>7} {best * 1e3:>9.3f} {n / best:>19,.0f} {n / med:>12,.0f} {n / cpu:>12,.0f}", flush=True)
    print(f"# load average after: {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
