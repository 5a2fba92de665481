"""Timing of the minimum-time reference search (aerohrl.datagen.reference).

Prints microseconds per reference for
  * the batched closed-form bisection (degree 5), N = 250 and N = 10,000;
  * the OSQP path: Alg. 1 per reference (degree 5 and 7), and per single QP solve
    (one axis, one duration; counted inside the bisection and timed cold via
    ``min_jerk_qp``).
Goals come from rho_D (``sample_goals``, seed 0). Best of ``--repeat`` runs.

    .venv/bin/python bench/bench_reference.py [--qp-refs 50] [--repeat 3]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from aerohrl.datagen import reference as ref
from aerohrl.datagen.goals import sample_goals


def states(n: int, seed: int = 0):
    g = sample_goals(np.random.default_rng(seed), n)
    return np.zeros((n, 3, 3)), np.stack([g["pos"], g["vel"], g["acc"]], axis=-1)


def best_of(repeat: int, fn):
    out, best = None, float("inf")
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t)
    return best, out


class SolveCounter:
    """Counts (and times) the QP solves made inside min_time."""

    def __init__(self):
        self.n, self.seconds = 0, 0.0
        self._orig = ref._QPWorkspace.solve

    def __enter__(self):
        orig, me = self._orig, self

        def solve(ws, *a, **k):
            t = time.perf_counter()
            r = orig(ws, *a, **k)
            me.seconds += time.perf_counter() - t
            me.n += 1
            return r

        ref._QPWorkspace.solve = solve
        return self

    def __exit__(self, *exc):
        ref._QPWorkspace.solve = self._orig


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--qp-refs", type=int, default=50, help="references for the QP timings (default 50)")
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    from aerohrl.hardware import describe_cpu

    print(f"cpu: {describe_cpu()}")
    print(
        f"bisection: [{ref.T_LO}, {ref.T_HI}] s, tol {ref.TOL} s, a_max {ref.A_MAX} m/s^2, "
        f"n_samples {ref.N_SAMPLES}, OSQP eps {ref.OSQP_SETTINGS['eps_abs']}, max_iter {ref.OSQP_SETTINGS['max_iter']}"
    )
    for n in (250, 10_000):
        x0, xf = states(n)
        ref.min_time(x0[:8], xf[:8])  # warm-up
        dt, (T, _, f) = best_of(args.repeat, lambda: ref.min_time(x0, xf))
        print(
            f"closed-form min-time, batched N={n:>6}: {dt / n * 1e6:8.2f} us/reference "
            f"({dt * 1e3:.1f} ms total; feasible {f.mean():.3f}, mean T {T[f].mean():.3f} s)"
        )

    n = args.qp_refs
    x0, xf = states(n)
    for degree in (5, 7):
        ref.min_jerk_qp(x0[:1], xf[:1], 2.0, degree=degree)  # workspace set-up outside the timing
        with SolveCounter() as cnt:
            t = time.perf_counter()
            T, _, f = ref.min_time(x0, xf, solver="qp", degree=degree)
            dt = time.perf_counter() - t
        print(
            f"QP min-time, degree {degree}, N={n}: {dt / n * 1e6:9.1f} us/reference "
            f"({cnt.n / n:.1f} QP solves/reference, {cnt.seconds / cnt.n * 1e6:.1f} us/solve incl. infeasible ones)"
        )
        T_cf = ref.min_time(x0, xf)[0] if degree == 5 else None
        dt, (_, ok) = best_of(args.repeat, lambda: ref.min_jerk_qp(x0, xf, T, degree=degree))
        print(
            f"  single QP solve at the found T (cold start, solved): {dt / (3 * n) * 1e6:8.1f} us/solve "
            f"(feasible {ok.mean():.2f})"
        )
        if T_cf is not None:
            d = T_cf - T
            print(f"  degree-5 QP vs closed form: equal T for {np.mean(d == 0):.3f}, max |dT| {np.abs(d).max():.4f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
