"""Evaluation speed: seconds for 250 Reach-Desired episodes (500 steps each) of a
cpu-preset policy in the batched closed loop (target: <= 20 s on 2 cores).

    .venv/bin/python bench/bench_eval.py                         # random cpu-preset GCSL weights
    .venv/bin/python bench/bench_eval.py --checkpoint runs/<run>/checkpoints/step-N.pt --dataset <dataset>
    .venv/bin/python bench/bench_eval.py --planner                # + Eq. 3.7 planning for 250 OOD goals

What is measured: ``aerohrl.envs.rollout.rollout`` end to end (Gymnasium vector env,
one batched simulator step and one batched policy call per control step, outcome
bookkeeping), the network built exactly as the cpu preset builds it. With random
weights no episode succeeds, so all 250 x 500 steps are flown: the worst case (a
trained policy ends successful episodes early but the batch still steps until the
last one ends, so the time barely changes). Goals: the dataset's desired goals when
``--dataset`` is given, else 250 goals drawn from rho_D. ``--planner`` adds the time
to score ``--candidates`` achieved goals (dataset or synthetic) for 250 OOD goals.
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings

import numpy as np
import torch

warnings.filterwarnings("ignore")


def main(argv=None) -> int:
    from aerohrl.algorithms.base import build_algorithm, load_policy
    from aerohrl.algorithms.config import make_config
    from aerohrl.algorithms.data import fit_normalizer, load_dataset
    from aerohrl.algorithms.synthetic import straight_columns
    from aerohrl.datagen.goals import goal_vectors, sample_goals
    from aerohrl.envs.episodes import EpisodeSet, hover_states
    from aerohrl.envs.rollout import rollout
    from aerohrl.eval.tasks import ood_goals
    from aerohrl.planning.planner import Planner, candidates_from_dataset

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--episodes", type=int, default=250)
    ap.add_argument("--horizon", type=int, default=500)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--checkpoint", default=None)
    ap.add_argument("--dataset", default=None)
    ap.add_argument("--planner", action="store_true")
    ap.add_argument("--candidates", type=int, default=1024)
    a = ap.parse_args(argv)
    torch.set_num_threads(a.threads)
    torch.manual_seed(0)
    data = load_dataset(a.dataset) if a.dataset else load_dataset(straight_columns(n_eps=20, length=100))
    if a.checkpoint:
        algo, _ = load_policy(a.checkpoint)
        what = f"checkpoint {a.checkpoint}"
    else:
        cfg = make_config("cpu", algo="gcsl")
        algo = build_algorithm(cfg, fit_normalizer(data, cfg.relabel_prob)).eval()
        what = f"random cpu-preset GCSL weights (actor {cfg.hidden}, critics {cfg.num_critics} x {cfg.critic_hidden})"
    from aerohrl.hardware import describe_cpu

    print(f"cpu: {describe_cpu()}")
    n = a.episodes
    goals = (
        data.desired_goals().numpy().astype(np.float64)[:n]
        if a.dataset
        else goal_vectors(sample_goals(np.random.default_rng(0), n))
    )
    n = len(goals)
    eps = EpisodeSet(
        "reach-desired", hover_states(n), goals, np.full(n, a.horizon), -np.ones(n, int), np.zeros(n, int), np.zeros(n, int)
    )
    rollout(
        algo,
        EpisodeSet("reach-desired", hover_states(n), goals, np.full(n, 5), eps.source_episode, eps.start_frame, eps.steps_ahead),
    )  # warm-up
    t0 = time.perf_counter()
    r = rollout(algo, eps)
    dt = time.perf_counter() - t0
    flown = int(r["steps"].max())
    print(
        f"reach-desired: {n} episodes x {a.horizon} steps ({flown} flown, success {100 * r['success'].mean():.1f}%): "
        f"{dt:.2f} s  [{what}; {a.threads} torch thread(s)]"
    )
    if a.planner:
        cand = candidates_from_dataset(data, a.candidates)
        G = ood_goals(n, 0)
        pl = Planner(algo, cand, n=1)
        t0 = time.perf_counter()
        pl.plan(hover_states(n), G)
        dt = time.perf_counter() - t0
        print(f"planner Eq. 3.7: {n} OOD goals x {len(cand)} candidates: {dt:.2f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
