"""Batched closed-loop evaluation through the Gymnasium vector environment.

All episodes of a task fly together in one :class:`~aerohrl.envs.reach.QuadrotorReachVectorEnv`
(one batched simulator step and one policy call per control step; the Python loop is
over time only). The policy sees the environment's ``desired_goal``: the task goal, or
during a planned flight the current intermediate goal (the vehicle "flies to g, then
to G", docs/spec.md / thesis §3.5). A leg ends when the environment reports it terminated
(the intermediate goal is reached; ``waypoint_tol`` scales the tolerances of
that test, 1 = the goal-reached test) or truncated (its ``leg_horizon`` budget is used);
then the next goal is set with :meth:`set_desired_goals`, after re-planning the
remaining intermediate goals from the vehicle's actual state when ``replan`` is on.
``replan_every = K`` also re-plans every K steps during intermediate legs, with the
option of dropping the remaining intermediate goals when flying straight to G scores
higher (Eq. 3.6 with n = 0).

Outcomes are judged against the *task* goal G at every step of every leg (docs/spec.md:
success = the goal-reached test holds at any step within the horizon, and the episode
ends there; near success = the test with tolerances x 2.5 at any step).
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING

import numpy as np
import torch

from aerohrl import task
from aerohrl.envs.episodes import EpisodeSet, hover_states

if TYPE_CHECKING:
    from aerohrl.algorithms.base import Algorithm
    from aerohrl.planning.graph import GraphPlanner
    from aerohrl.planning.planner import ChainPlanner, Planner
    from aerohrl.sim.perturb import Perturbation
    from aerohrl.worlds.maze import Maze


class PolicyFn:
    """``algo.act`` on NumPy states/goals, clipped to the policy's action range (the
    data range widened by 10%, as the training normaliser maps it) and made finite."""

    def __init__(self, algo):
        self.algo = algo
        self.device = next(algo.parameters()).device
        n = algo.normalizer
        self.lo = (n.act_center - n.act_half).double().cpu().numpy()
        self.hi = (n.act_center + n.act_half).double().cpu().numpy()

    @torch.no_grad()
    def __call__(self, states: np.ndarray, goals: np.ndarray) -> np.ndarray:
        s = torch.as_tensor(states, dtype=torch.float32, device=self.device)
        g = torch.as_tensor(goals, dtype=torch.float32, device=self.device)
        a = self.algo.act(s, g).double().cpu().numpy()
        return np.clip(np.nan_to_num(a, nan=0.0), self.lo, self.hi)


def rollout(
    algo: Algorithm,
    episodes: EpisodeSet,
    *,
    planner: Planner | ChainPlanner | GraphPlanner | None = None,
    n_waypoints: int = 0,
    leg_horizon: int | None = None,
    replan: bool = True,
    replan_every: int = 0,
    waypoint_tol: float = 1.0,
    goal_tol: float = 1.0,
    decline_margin: float | None = None,
    record: bool = False,
    record_states: bool = False,
    vehicle: str = "hummingbird",
    fps: int = 100,
    substeps: int = 5,
    progress: bool = False,
    desc: str = "rollout",
    maze: Maze | None = None,
    perturbation: Perturbation | None = None,
    perturb_seed: int = 0,
) -> dict:
    """Fly every episode of ``episodes`` with the policy of ``algo``; per-episode results.

    ``planner`` (a :class:`~aerohrl.planning.planner.Planner` or ``ChainPlanner``; used only
    through ``planner.plan(states, goals, n=k)``, whose result has ``goals`` (E, k, 15),
    ``frame``, ``score`` and ``direct_score``) with ``n_waypoints >= 1``
    plans intermediate goals before take-off (thesis Eq. 3.7 / 3.6). ``goal_tol`` scales
    the tolerances of the task goal's test (success, and near success = x 2.5 of it;
    0.5 = the precision variant of eval/README.md). ``decline_margin = m`` lets the
    planner decline: an episode whose plan scores no more than flying straight plus ``m``
    (``plan_score <= direct_score + m``, the critics' composed value against V(s0, G))
    flies straight to G from take-off (``declined``); None never declines (the thesis).
    Returns a dict of
    (E,)-arrays (success, near_success, first_success_step, first_near_step, steps,
    final_pos_err / final_vel_err / final_rot_err at the episode's last step,
    min_pos_err) plus the plan (``waypoints`` (E, n, 15), ``waypoint_frame``,
    ``plan_score``, ``legs_reached``) and, with ``record``, ``positions`` (E, T+1, 3); with
    ``record_states``, the observed ``states`` (E, T+1, 18), the ``actions`` flown (E, T, 4)
    and the ``policy_goals`` the policy saw (E, T+1, 15), each episode's first
    ``steps + 1`` (actions: ``steps``) rows being its flight.
    In a ``maze`` (the episodes fly in :class:`~aerohrl.envs.maze.QuadrotorMazeVectorEnv`)
    a collision at any step ends the episode as a failure: ``collision`` (E,) and
    ``collision_step`` (E,; -1 for none) say which and when (every other array is
    returned too, free space's ``collision`` all False). ``perturbation`` flies the vehicles
    on a perturbed plant (:mod:`aerohrl.sim.perturb`, seeded by ``perturb_seed``): the policy
    and the planner see the observed state, the outcomes are judged on the true one.
    A policy that observes the disturbance estimate (``algo.normalizer.disturbance_tau`` > 0)
    flies with the expert's :class:`~aerohrl.datagen.expert.DisturbanceObserver` beside it,
    fed with the observed state and the collective flown, as the data's expert was.
    """
    from tqdm import tqdm

    from aerohrl.envs.reach import QuadrotorReachVectorEnv

    was_training = algo.training
    algo.eval()
    policy = PolicyFn(algo)
    E = len(episodes)
    tau = float(getattr(algo.normalizer, "disturbance_tau", 0.0))
    dob = None
    if tau > 0:
        from aerohrl.datagen.expert import DisturbanceObserver

        dob = DisturbanceObserver(E, tau, 1.0 / fps)
    G = episodes.goals.astype(np.float64)
    total = episodes.horizons.astype(np.int64)
    T = int(total.max())
    nw = int(n_waypoints) if planner is not None else 0
    leg_h = int(leg_horizon or episodes.meta.get("leg_horizon", T))
    sim = dict(
        vehicle=vehicle,
        fps=fps,
        substeps=substeps,
        autoreset=False,
        horizon=T,
        tolerance_scale=waypoint_tol,
        perturbation=perturbation,
        perturb_seed=perturb_seed,
    )
    if maze is not None:  # the same closed loop; the maze env's collisions end episodes
        from aerohrl.envs.maze import QuadrotorMazeVectorEnv

        env: QuadrotorReachVectorEnv = QuadrotorMazeVectorEnv(E, maze=maze, **sim)  # type: ignore[arg-type]
    else:
        env = QuadrotorReachVectorEnv(E, **sim)  # type: ignore[arg-type]
    out: dict = {}
    t_plan = 0.0
    if nw:
        assert planner is not None  # nw > 0 only with a planner
        t0 = time.perf_counter()
        plan = planner.plan(episodes.start_states, G, n=nw)
        t_plan += time.perf_counter() - t0
        wp = plan.goals.copy()  # (E, nw, 15), rewritten by re-planning
        out.update(
            plan_score=plan.score,
            direct_score=plan.direct_score,
            planned_frame=plan.frame.copy(),
            planned_waypoints=plan.goals.copy(),
        )
        wp_frame = plan.frame.copy()
    tol = task.TOLERANCE.scaled(float(goal_tol))
    leg = np.zeros(E, np.int64)  # index of the goal being flown to (nw = the task goal)
    legs_reached = np.zeros(E, np.int64)  # intermediate goals reached (env terminated, not truncated)
    first_goal = wp[:, 0] if nw else G
    first_budget = np.minimum(leg_h, total) if nw else total
    if nw and decline_margin is not None:  # flying straight stays a candidate
        declined = plan.score <= plan.direct_score + float(decline_margin)
        leg[declined] = nw
        first_goal = np.where(declined[:, None], G, first_goal)
        first_budget = np.where(declined, total, first_budget)
        out["declined"] = declined
    obs, _ = env.reset(options={"start_states": episodes.start_states, "goals": first_goal, "horizons": first_budget})
    success = np.zeros(E, bool)
    near = np.zeros(E, bool)
    first_success = np.full(E, -1, np.int64)
    first_near = np.full(E, -1, np.int64)
    collision_step = np.full(E, -1, np.int64)
    finished = np.zeros(E, bool)
    steps = total.copy()
    final = np.zeros((E, 3))
    min_pos: np.ndarray = np.full(E, np.inf)
    pos = np.zeros((E, T + 1, 3), np.float32) if record else None
    if record:
        assert pos is not None
        pos[:, 0] = obs["achieved_goal"][:, :3]
    if record_states:
        flown = {
            "states": np.zeros((E, T + 1, task.STATE_DIM)),
            "actions": np.zeros((E, T, task.ACTION_DIM)),
            "policy_goals": np.zeros((E, T + 1, task.GOAL_DIM)),
        }
        flown["states"][:, 0], flown["policy_goals"][:, 0] = obs["observation"][:, : task.STATE_DIM], obs["desired_goal"]
    bar = tqdm(total=T, desc=desc, unit="step", disable=None if progress else True, leave=False, dynamic_ncols=True)
    try:
        for t in range(T):
            active = ~finished
            a = np.zeros((E, 4))
            idx = np.flatnonzero(active)
            seen = obs["observation"][:, : task.STATE_DIM]
            x = seen if dob is None else np.concatenate([seen, dob.d_hat], 1)
            a[idx] = policy(x[idx], obs["desired_goal"][idx])
            a[~active] = [9.81, 0.0, 0.0, 0.0]  # finished vehicles hover (their results are fixed)
            if dob is not None:  # with the collective flown, for the next command
                dob.update(seen, a[:, 0])
            obs, _, term, trunc, info = env.step(a)
            if record_states:
                flown["actions"][:, t] = a
                flown["states"][:, t + 1], flown["policy_goals"][:, t + 1] = (
                    obs["observation"][:, : task.STATE_DIM],
                    obs["desired_goal"],
                )
            crash = info["collision"] & active
            ag = obs["achieved_goal"]
            if record:
                assert pos is not None
                pos[:, t + 1] = obs["achieved_goal"][:, :3]
            dp, dv, dr = task.goal_errors(ag, G)
            min_pos = np.where(active, np.minimum(min_pos, dp), min_pos)
            hit = task.goal_reached(ag, G, tol) & active & ~crash
            nr = task.near_success(ag, G, tol) & active & ~crash
            first_success[hit] = t + 1
            first_near[nr & ~near] = t + 1
            collision_step[crash] = t + 1
            success |= hit
            near |= nr
            ending = active & (hit | crash | (t + 1 >= total))
            final[ending] = np.stack([dp, dv, dr], 1)[ending]
            steps[ending] = t + 1
            finished |= ending
            if nw:  # leg bookkeeping
                switch = active & ~finished & (leg < nw) & (term | trunc)
                legs_reached += switch & term
                if replan_every and (t + 1) % replan_every == 0:
                    flying_wp = active & ~finished & ~switch & (leg < nw)
                    if flying_wp.any():
                        t0 = time.perf_counter()
                        wp, wp_frame, leg_to_direct = _replan(
                            planner, obs, G, wp, wp_frame, leg, flying_wp, nw, direct_option=True
                        )
                        t_plan += time.perf_counter() - t0
                        leg[leg_to_direct] = nw
                        env.set_desired_goals(
                            np.where((leg < nw)[:, None], wp[np.arange(E), np.minimum(leg, nw - 1)], G),
                            flying_wp,
                            horizons=np.where(leg < nw, leg_h, total - (t + 1)),
                        )
                if switch.any():
                    leg[switch] += 1
                    if replan and nw > 1:
                        more = switch & (leg < nw)
                        if more.any():
                            t0 = time.perf_counter()
                            wp, wp_frame, _ = _replan(planner, obs, G, wp, wp_frame, leg, more, nw, direct_option=False)
                            t_plan += time.perf_counter() - t0
                    goal = np.where((leg < nw)[:, None], wp[np.arange(E), np.minimum(leg, nw - 1)], G)
                    budget = np.where(leg < nw, np.minimum(leg_h, total - (t + 1)), total - (t + 1))
                    obs = env.set_desired_goals(goal, switch, horizons=budget)
            bar.update(1)
            if finished.all():
                break
    finally:
        bar.close()
        algo.train(was_training)
    out.update(
        success=success,
        near_success=(near | success) & (collision_step < 0),  # a crash after coming near is a failure
        first_success_step=first_success,
        first_near_step=first_near,
        steps=steps,
        final_pos_err=final[:, 0],
        final_vel_err=final[:, 1],
        final_rot_err=final[:, 2],
        min_pos_err=min_pos,
        collision=collision_step >= 0,
        collision_step=collision_step,
        plan_seconds=np.full(E, t_plan / max(E, 1)),
    )
    if nw:
        out.update(waypoints=wp, waypoint_frame=wp_frame, legs_reached=legs_reached, final_leg=leg)
    if record:
        out["positions"] = pos
    if record_states:
        out.update(flown)
    return out


def _replan(planner, obs, G, wp, wp_frame, leg, mask, nw, direct_option):
    """Re-plan the remaining ``nw - leg`` intermediate goals of the episodes in ``mask``
    from their current states. With ``direct_option``, episodes whose straight flight to
    G scores higher than their best plan go straight to G (returned mask)."""
    wp, wp_frame = wp.copy(), wp_frame.copy()
    to_direct = np.zeros(len(G), bool)
    for remaining in np.unique(nw - leg[mask]):  # at most nw groups, each planned in one batched pass
        sel = np.flatnonzero(mask & (nw - leg == remaining))
        p = planner.plan(obs["observation"][sel], G[sel], n=int(remaining))
        for r in range(int(remaining)):
            wp[sel, nw - remaining + r] = p.goals[:, r]
            wp_frame[sel, nw - remaining + r] = p.frame[:, r]
        if direct_option:
            to_direct[sel[p.direct_score > p.score]] = True
    return wp, wp_frame, to_direct


def rollout_reach(
    algo: Algorithm,
    goals: np.ndarray,
    *,
    horizon: int = 500,
    vehicle: str = "hummingbird",
    fps: int = 100,
    substeps: int = 5,
    start_states: np.ndarray | None = None,
) -> dict:
    """Reach-Desired style summary (success, near success, mean steps to success) for
    ``goals`` (N, 15) from hover at the origin or ``start_states``: the trainer's hook."""
    goals = np.asarray(goals, np.float64)
    n = len(goals)
    eps = EpisodeSet(
        "reach-desired",
        hover_states(n) if start_states is None else np.asarray(start_states, np.float64),
        goals,
        np.full(n, int(horizon), np.int64),
        np.full(n, -1, np.int64),
        np.zeros(n, np.int64),
        np.zeros(n, np.int64),
    )
    r = rollout(algo, eps, vehicle=vehicle, fps=fps, substeps=substeps)
    s = r["success"]
    return {
        "success": float(s.mean()),
        "near_success": float(r["near_success"].mean()),
        "mean_steps_to_success": float(r["first_success_step"][s].mean()) if s.any() else float("nan"),
    }


__all__ = ["rollout", "rollout_reach", "PolicyFn"]
