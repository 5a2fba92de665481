"""IPP speed: batched environment steps/s and planning ms per decision per planner
(baselines and the learned policy with its per-primitive features, untrained weights:
the cost does not depend on them), target search and semantic detection.

    .venv/bin/python bench/bench_ipp.py [--quick] [--batch N] [--run RUN]
        [--sem-batch N] [--sem-decisions N] [--sem-run RUN] [--sem-only] [--planners a,b]

``--batch`` sets how many target-search environments are stepped together for the
planning table (``ipp bench`` batches 100); ``--run`` times a trained policy instead of
untrained weights of the default architecture. ``--sem-batch`` / ``--sem-decisions`` /
``--sem-run`` do the same for the semantic table (``ipp bench --world semantic`` runs
its 30 environments in one batch; the learned policy's cost per decision there is the
windowed fast path of ``features.semantic_fast`` + observation + network). ``detect`` is
the training-time teacher (not a thesis baseline); on semantic worlds it reads its
scores from the same fast path.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from aerohrl.ipp.baselines import PLANNERS, TEACHERS, PlannerConfig, make_planner
from aerohrl.ipp.env import EnvConfig, SearchEnv, semantic_config
from aerohrl.ipp.factory import create_env, sample_for
from aerohrl.ipp.lattice import default_lattice, semantic_lattice
from aerohrl.ipp.world import sample_worlds


def env_steps_per_s(lat, n: int, steps: int) -> tuple[float, float]:
    cfg = EnvConfig(budget=1e9)  # never runs out during the measurement
    env = SearchEnv(cfg, lat)
    env.reset(sample_worlds(cfg.world, 0, range(n)))
    rng = np.random.default_rng(0)
    t_obs = 0.0
    t0 = time.perf_counter()
    for _ in range(steps):
        m = env.valid_mask()
        a = np.argmax(rng.random(m.shape) * m, axis=1)  # a random valid action, vectorised
        env.step(a)  # includes building the observation
    dt = time.perf_counter() - t0
    t1 = time.perf_counter()
    for _ in range(steps):
        env.observe()
    t_obs = (time.perf_counter() - t1) / steps
    return n * steps / dt, 1000 * t_obs


def _rl_planner(env, run=None):
    import torch

    from aerohrl.ipp.features import N_FEAT
    from aerohrl.ipp.policy import ActorCritic, PolicyConfig, RLPlanner, load_policy

    torch.set_num_threads(1)
    obs = env.observe()
    if run is not None:
        model = load_policy(run)
        if getattr(model, "env_kind", "targets") != env.cfg.kind:
            raise SystemExit(f"{run}: policy trained on {model.env_kind} worlds, not {env.cfg.kind}")
        return RLPlanner(env, model)
    model = ActorCritic(
        obs["maps"].shape[1], obs["maps"].shape[2], obs["vec"].shape[1], env.lat.n_actions, PolicyConfig(), n_feat=N_FEAT
    ).eval()
    return RLPlanner(env, model)


def planning_ms(lat, name: str, n: int, decisions: int, cfg=None, run=None, warmup: int = 0) -> float:
    """ms per (environment, decision) over ``decisions`` batched decisions, after
    ``warmup`` untimed ones (one-time table builds, the start at hover)."""
    cfg = cfg or EnvConfig()
    env = create_env(cfg, lat)
    env.reset(sample_for(cfg, 0, range(n)))
    env.lazy_obs = True  # as ipp bench: planners read the maps, RLPlanner observes itself
    pl = _rl_planner(env, run) if name == "rl" else make_planner(name, env, PlannerConfig())
    for _ in range(warmup):
        env.step(pl.act())
    total, served = 0.0, 0
    for _ in range(decisions):
        live = int((~env.done).sum())
        if live == 0:
            break
        t = time.perf_counter()
        a = pl.act()
        total += time.perf_counter() - t
        served += live
        env.step(a)
    return 1000 * total / max(served, 1)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--batch", type=int, default=None, help="target-search planning batch")
    ap.add_argument("--run", help="trained policy (run directory or .pt) for the rl rows")
    ap.add_argument("--sem-batch", type=int, default=None, help="semantic planning batch")
    ap.add_argument("--sem-decisions", type=int, default=None, help="semantic: timed decisions (after 2 untimed ones)")
    ap.add_argument("--sem-run", help="trained semantic policy for the semantic rl row")
    ap.add_argument("--sem-only", action="store_true", help="only the semantic table")
    ap.add_argument("--planners", help="comma-separated subset of the planners to time")
    a = ap.parse_args()
    from aerohrl.hardware import describe_cpu

    print(f"cpu: {describe_cpu()}")
    names = PLANNERS + TEACHERS + ("rl",)
    if a.planners:
        names = tuple(x for x in a.planners.split(",") if x)
    if not a.sem_only:
        target_tables(a, names)
    slat, scfg = semantic_lattice(), semantic_config()
    n, dec = (2, 3) if a.quick else (4, 5)
    n, dec = a.sem_batch or n, a.sem_decisions or dec
    print(f"\nsemantic 256 x 256: planning ms per decision ({n} envs batched, {dec} decisions after 2 untimed)")
    print("| planner | ms/decision |\n|---|---|")
    for name in names:
        ms = planning_ms(slat, name, n, dec, scfg, run=a.sem_run, warmup=2)
        print(f"| {name} | {ms:.2f} |", flush=True)


def target_tables(a, names) -> None:
    lat = default_lattice()
    print(f"lattice: {lat.n_vertices} vertices, {lat.n_prims} primitives, {lat.n_actions} slots")
    print("\nenv steps/s (random valid primitives; step = sense + update + rewards + obs)")
    print("| batch | steps/s | obs ms/batch |\n|---|---|---|")
    for n in (1, 16, 64) if a.quick else (1, 16, 64, 256):
        sps, obs_ms = env_steps_per_s(lat, n, 20 if a.quick else 40)
        print(f"| {n} | {sps:,.0f} | {obs_ms:.2f} |")
    n, dec = (10, 5) if a.quick else (20, 10)
    n = a.batch or n
    print(f"\nplanning ms per decision ({n} envs batched, first {dec} decisions)")
    print("| planner | ms/decision |\n|---|---|")
    for name in names:
        print(f"| {name} | {planning_ms(lat, name, n, dec, run=a.run):.2f} |", flush=True)


if __name__ == "__main__":
    main()
