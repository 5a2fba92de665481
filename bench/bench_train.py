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
"""

from __future__ import annotations

import argparse
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
    from aerohrl.algorithms.base import build_algorithm
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
    ap.add_argument("--amp", default=None, help="override the preset's mixed precision (none | bf16)")
    a = ap.parse_args(argv)
    torch.set_num_threads(a.threads)
    data = load_dataset(a.dataset) if a.dataset else load_dataset(straight_columns(n_eps=250, length=200))
    print(f"torch {torch.__version__}, {a.threads} threads, amp {a.amp or 'preset'}, dataset {data.info['version']} ({len(data)} frames), preset {a.preset}")
    print(f"resident after loading the dataset: {_peak_gb():.2f} GB (peak so far)")
    print(f"{'algo':8s} {'steps/s':>8s} {'loop ms':>8s} {'update ms':>9s} {'overhd ms':>9s} {'sample ms':>9s} {'non-network':>11s}")
    for algo in a.algos:
        cfg = make_config(a.preset, algo=algo, steps=10**9, eval_every=0, log_every=200, checkpoint_every=10**9, amp=a.amp)
        amp = torch.autocast("cpu", dtype=torch.bfloat16, enabled=cfg.amp == "bf16")
        with tempfile.TemporaryDirectory() as tmp:
            tr = start_run(cfg, f"{tmp}/run", data=data, progress=False)
            tr.train(until=20)  # warm-up
            t = time.perf_counter()
            tr.train(until=20 + a.steps)
            loop = (time.perf_counter() - t) / a.steps
            m = tr.algo.update(tr.sampler.sample())
            tr.algo.update = lambda batch: m
            t = time.perf_counter()
            tr.train(until=20 + 2 * a.steps)
            overhead = (time.perf_counter() - t) / a.steps
        torch.manual_seed(0)
        norm = fit_normalizer(data, cfg.relabel_prob)
        alg = build_algorithm(cfg, norm)
        s = GoalBatchSampler(data, norm, cfg.batch_size, cfg.relabel_prob, torch.Generator().manual_seed(0))
        batches = [s.sample() for _ in range(a.steps)]
        t = time.perf_counter()
        for _ in range(a.steps):
            s.sample()
        sample = (time.perf_counter() - t) / a.steps
        with amp:
            for b in batches[:10]:
                alg.update(b)
            t = time.perf_counter()
            for b in batches:
                alg.update(b)
        update = (time.perf_counter() - t) / a.steps
        share = overhead / (overhead + update)
        print(f"{algo:8s} {1 / loop:8.1f} {1e3 * loop:8.2f} {1e3 * update:9.2f} {1e3 * overhead:9.2f} {1e3 * sample:9.2f} {100 * share:10.1f}%")
        sys.stdout.flush()
    print(f"peak resident memory of the whole bench: {_peak_gb():.2f} GB (dataset once, one run at a time, {a.steps} held batches)")
    return 0


def _peak_gb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6  # KB on Linux


if __name__ == "__main__":
    sys.exit(main())
