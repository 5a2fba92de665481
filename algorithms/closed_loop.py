"""A minimal closed-loop check in the simulator: the periodic evaluation hook of the
trainer until the evaluation harness (``aerohrl eval``) exists.

Reach-Desired (SPEC.md "Evaluation tasks"): every vehicle starts at hover at the
origin, gets one of the dataset's desired goals and flies the policy for ``horizon``
steps; success = the goal-reached test holds at some step (the episode ends there),
near success = the same with every tolerance x 2.5.
"""

from __future__ import annotations

import numpy as np
import torch

from aerohrl import task


def rollout_reach(algo, goals: np.ndarray, *, horizon: int = 500, vehicle: str = "hummingbird", fps: int = 100,
                  substeps: int = 5, start_states: np.ndarray | None = None) -> dict:
    """Batched closed loop from hover at the origin (or ``start_states``) to ``goals`` (N, 15)."""
    from aerohrl.sim import BatchedQuadrotor, get_preset

    goals = np.asarray(goals, dtype=np.float64)
    n = len(goals)
    sim = BatchedQuadrotor(get_preset(vehicle), n, dt=1.0 / fps, substeps=substeps)
    state = sim.reset(start_states)
    device = next(algo.parameters()).device
    g_t = torch.as_tensor(goals, dtype=torch.float32, device=device)
    lo = (algo.normalizer.act_center - algo.normalizer.act_half).cpu().numpy()
    hi = (algo.normalizer.act_center + algo.normalizer.act_half).cpu().numpy()
    success = np.zeros(n, bool)
    near = np.zeros(n, bool)
    steps = np.full(n, horizon)
    was_eval = algo.training
    algo.eval()
    try:
        for t in range(horizon):
            s_t = torch.as_tensor(state, dtype=torch.float32, device=device)
            a = algo.act(s_t, g_t).cpu().numpy().astype(np.float64)
            a = np.clip(np.nan_to_num(a, nan=0.0), lo, hi)
            state = sim.step(a)
            ok = np.isfinite(state).all(1)
            ag = task.achieved_goal(np.where(ok[:, None], state, 1e6))
            hit = task.goal_reached(ag, goals) & ~success
            steps[hit] = t + 1
            success |= hit
            near |= task.near_success(ag, goals)
            if success.all():
                break
    finally:
        algo.train(was_eval)
    return {"success": float(success.mean()), "near_success": float((near | success).mean()),
            "mean_steps_to_success": float(steps[success].mean()) if success.any() else float("nan")}


def make_reach_desired_evaluator(data, cfg):
    """Reach-Desired on ``cfg.eval_episodes`` of the dataset's desired goals (a fixed,
    seeded subset), with the dataset's vehicle and rates."""
    goals = data.desired_goals().cpu().numpy()
    rng = np.random.default_rng(cfg.seed + 12345)
    pick = rng.choice(len(goals), size=min(cfg.eval_episodes, len(goals)), replace=False)
    goals = goals[np.sort(pick)]
    spec = data.info.get("spec") or {}
    kw = {"vehicle": spec.get("vehicle", "hummingbird"), "fps": int(spec.get("fps", 100)), "substeps": int(spec.get("substeps", 5))}

    def evaluate(algo, step):
        r = rollout_reach(algo, goals, horizon=cfg.eval_horizon, **kw)
        return {k: v for k, v in r.items() if np.isfinite(v)}

    return evaluate


__all__ = ["rollout_reach", "make_reach_desired_evaluator"]
