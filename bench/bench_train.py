"""Training speed: gradient steps per second per algorithm and the share of a step
spent outside the networks (sampling, relabelling, normalising, metric bookkeeping).

    .venv/bin/python bench/bench_train.py                       # cpu preset, synthetic data
    .venv/bin/python bench/bench_train.py --dataset datasets/quadrotor-reach/<version>
    .venv/bin/python bench/bench_train.py --algos gcsl --steps 300 --threads 2

For each algorithm, three timings over the same number of steps:
* ``loop``:     the trainer's own loop (``Trainer.train``: sample, relabel, update, NaN
  check, metric sums, logging; checkpoints and evaluations switched off);
* ``update``:   ``algo.update`` alone on batches sampled beforehand (forward, backward,
  optimiser and target updates: the networks' work);
* ``overhead``: the same trainer loop with ``algo.update`` replaced by a stub returning
  the metrics, i.e. everything but the networks (buffer draw, relabelling, rewards,
  normalisation, NaN check, metric sums, logging, progress).
non-network share = overhead / (overhead + update); measured this way it does not
depend on the two loops happening to run at equally loaded moments.

    .venv/bin/python bench/bench_train.py --device cuda --preset thesis   # on a GPU machine (one-line error without CUDA)
    .venv/bin/python bench/bench_train.py --compile --algos gcsl td3bc    # + torch.compile'd update
    .venv/bin/python bench/bench_train.py --flops --preset thesis --algos td3bc --steps 20

``--compile`` also times ``torch.compile(algo.update)`` on the same batches (``compiled
ms``; its compile time, spent in the 10 warm-up steps, is printed beside it).
``--flops`` counts the floating-point operations of one update (torch.profiler's
``with_flops``: matrix products, forward and backward) and the aten operators it runs
(each about one kernel launch on a GPU), the inputs of the README's GPU estimate.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import logging
import resource
import sys
import tempfile
import time
import warnings

import torch

warnings.filterwarnings("ignore")
logging.getLogger("torchrl").setLevel(logging.WARNING)


def main(argv=None) -> int:
    from aerohrl.algorithms.base import algorithm_class, build_algorithm
    from aerohrl.algorithms.config import ALGORITHMS, make_config
    from aerohrl.algorithms.data import GoalBatchSampler, fit_normalizer, load_dataset
    from aerohrl.algorithms.synthetic import straight_columns
    from aerohrl.algorithms.trainer import start_run

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dataset", default=None, help="dataset folder [synthetic: 250 episodes x 200 frames]")
    ap.add_argument("--algos", nargs="+", default=list(ALGORITHMS))
    ap.add_argument("--preset", default="cpu")
    ap.add_argument("--steps", type=int, default=300, help="timed steps per measurement")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--amp", default=None, help="override the preset's mixed precision (auto | none | bf16)")
    ap.add_argument("--device", default="cpu", help="cpu | cuda | cuda:N [cpu]")
    ap.add_argument("--compile", action="store_true", help="also time torch.compile(algo.update)")
    ap.add_argument("--flops", action="store_true", help="count FLOPs and operators of one update, then stop")
    a = ap.parse_args(argv)
    from aerohrl.algorithms.trainer import resolve_device
    from aerohrl.errors import UserError

    try:
        device = resolve_device(a.device)
    except UserError as e:
        print(f"bench_train: error: {e}", file=sys.stderr)
        return 2
    torch.set_num_threads(a.threads)
    if a.flops:
        return flops(a, device)
    data = load_dataset(a.dataset) if a.dataset else load_dataset(straight_columns(n_eps=250, length=200))
    gpu = f" ({torch.cuda.get_device_name(device)})" if device.type == "cuda" else ""
    from aerohrl.hardware import describe_cpu, resolve_amp

    print(f"cpu: {describe_cpu()}; torch capability {torch.backends.cpu.get_cpu_capability()}")
    print(
        f"torch {torch.__version__}, device {device}{gpu}, {a.threads} threads, amp {a.amp or 'preset'}, dataset "
        f"{data.info['version']} ({len(data)} frames), preset {a.preset}"
    )
    print(f"resident after loading the dataset: {_peak_gb():.2f} GB (peak so far)")
    print(
        f"{'algo':8s} {'steps/s':>8s} {'loop ms':>8s} {'update ms':>9s} {'overhd ms':>9s} {'sample ms':>9s} {'non-network':>11s}"
        + (f" {'compiled ms':>11s} {'compile s':>9s}" if a.compile else "")
    )
    sync = torch.cuda.synchronize if device.type == "cuda" else (lambda: None)
    for algo in a.algos:
        cfg = make_config(
            a.preset, algo=algo, steps=10**9, eval_every=0, log_every=200, checkpoint_every=10**9, amp=a.amp, device=str(device)
        )
        cfg = dataclasses.replace(cfg, amp=resolve_amp(cfg.amp, device)[0])
        amp = functools.partial(torch.autocast, device.type, dtype=torch.bfloat16, enabled=cfg.amp == "bf16")
        with tempfile.TemporaryDirectory() as tmp:
            tr = start_run(cfg, f"{tmp}/run", data=data, progress=False)
            tr.train(until=20)  # warm-up
            sync()
            t = time.perf_counter()
            tr.train(until=20 + a.steps)
            sync()
            loop = (time.perf_counter() - t) / a.steps
            m = tr.algo.update(tr.sampler.sample())
            tr.algo.update = lambda batch: m
            t = time.perf_counter()
            tr.train(until=20 + 2 * a.steps)
            overhead = (time.perf_counter() - t) / a.steps
        torch.manual_seed(0)
        norm = fit_normalizer(data, cfg.relabel_prob)
        alg = build_algorithm(cfg, norm).to(device)
        s = GoalBatchSampler(
            data,
            norm,
            cfg.batch_size,
            cfg.relabel_prob,
            torch.Generator().manual_seed(0),
            device=device,
            **algorithm_class(algo).sampler_options(cfg),
        )
        batches = [s.sample() for _ in range(a.steps)]
        t = time.perf_counter()
        for _ in range(a.steps):
            s.sample()
        sample = (time.perf_counter() - t) / a.steps
        update, _ = _time_updates(alg.update, batches, amp, sync)
        share = overhead / (overhead + update)
        extra = ""
        if a.compile:
            torch.manual_seed(0)
            alg2 = build_algorithm(cfg, norm).to(device)
            compiled, warm = _time_updates(torch.compile(alg2.update), batches, amp, sync)
            extra = f" {1e3 * compiled:11.2f} {warm:9.1f}"
        print(
            f"{algo:8s} {1 / loop:8.1f} {1e3 * loop:8.2f} {1e3 * update:9.2f} {1e3 * overhead:9.2f} {1e3 * sample:9.2f} "
            f"{100 * share:10.1f}%" + extra
        )
        sys.stdout.flush()
    print(
        f"peak resident memory of the whole bench: {_peak_gb():.2f} GB (dataset once, one run at a time, {a.steps} held batches)"
    )
    return 0


def _time_updates(update, batches, amp, sync) -> tuple[float, float]:
    """(s per update over ``batches``, s of the 10 warm-up updates before them). Each update
    in its own autocast context, as the trainer runs them: autocast caches the bf16 copies
    of the weights until its context exits, so one context around the loop would skip the
    casts a training step pays (and train on stale copies)."""
    t = time.perf_counter()
    for b in batches[:10]:
        with amp():
            update(b)
    sync()
    warm = time.perf_counter() - t
    t = time.perf_counter()
    for b in batches:
        with amp():
            update(b)
    sync()
    return (time.perf_counter() - t) / len(batches), warm


def flops(a, device) -> int:
    """FLOPs and aten operators of one update per algorithm (after 3 warm-up updates)."""
    from torch.profiler import ProfilerActivity, profile

    from aerohrl.algorithms.base import algorithm_class, build_algorithm
    from aerohrl.algorithms.config import make_config
    from aerohrl.algorithms.data import GoalBatchSampler, fit_normalizer, load_dataset
    from aerohrl.algorithms.synthetic import straight_columns

    data = load_dataset(straight_columns(n_eps=50, length=200))
    print(f"preset {a.preset}, amp {a.amp or 'preset'}; one update (forward + backward + optimiser) per algorithm")
    print(f"{'algo':8s} {'GFLOP/step':>10s} {'aten ops/step':>13s}")
    for algo in a.algos:
        cfg = make_config(a.preset, algo=algo, amp=a.amp)
        norm = fit_normalizer(data, cfg.relabel_prob)
        alg = build_algorithm(cfg, norm).to(device)
        s = GoalBatchSampler(
            data,
            norm,
            cfg.batch_size,
            cfg.relabel_prob,
            torch.Generator().manual_seed(0),
            device=device,
            **algorithm_class(algo).sampler_options(cfg),
        )
        from aerohrl.hardware import resolve_amp

        amp = torch.autocast(device.type, dtype=torch.bfloat16, enabled=resolve_amp(cfg.amp, device)[0] == "bf16")
        with amp:
            for _ in range(3):
                alg.update(s.sample())
            b = s.sample()
            with profile(activities=[ProfilerActivity.CPU], with_flops=True) as prof:
                alg.update(b)
        total = sum(
            e.flops or 0
            for e in prof.events()
            if e.name.startswith("aten::") and (e.cpu_parent is None or not e.cpu_parent.name.startswith("aten::"))
        )
        # top-level aten operators (not those called inside another): about one kernel launch each on a GPU
        ops = sum(
            1
            for e in prof.events()
            if e.name.startswith("aten::") and (e.cpu_parent is None or not e.cpu_parent.name.startswith("aten::"))
        )
        print(f"{algo:8s} {total / 1e9:10.2f} {ops:13d}")
    return 0


def _peak_gb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6  # KB on Linux


if __name__ == "__main__":
    sys.exit(main())
