"""What any single-intermediate-goal planner could achieve: the *oracle* bound of Eq. 3.7.

The planner of thesis Eq. 3.7 picks one intermediate goal ``g`` from the dataset's
achieved goals and flies ``s0 -> g -> G``. Whether some candidate would have worked is a
question about the policy, not about the critics, and it can be answered by flying:

1. **first legs**: from the start (hover at the origin) to every candidate ``g``
   (``C`` flights, horizon ``leg_horizon``);
2. **second legs**: from every candidate's dataset state ``s_g`` to every task goal
   ``G`` (``E x C`` flights, all batched in chunks of ``chunk`` vehicles).

A candidate *works* for ``G`` when both legs succeed (the goal-reached test). The
composition is an approximation: a first leg that succeeds ends within the tolerances
of ``g``, not exactly at ``s_g``. Reported:

* ``oracle``: share of goals with at least one working candidate -- an estimate of the
  best success any planner over this candidate set can reach with this policy;
* ``planner``: share of goals whose Eq. 3.7 choice (the same critics, ``alpha``, over
  the same candidates) works -- what the planner would reach under the same composition;
* ``second_leg_success`` by distance ``|G - p_g|`` and the ROC AUC of the critics'
  second-leg value ``mean_j Q_j(s_g, pi(s_g, G), G)`` for second-leg success / near
  success, i.e. whether the critics rank candidates usefully at all.

``aerohrl eval oracle --run RUN`` (goals of the ``ood`` task by default; ``--task
reach-novel`` for fresh in-distribution goals). Cost: ``E x C`` flights of
``leg_horizon`` steps (40 goals x 150 candidates: about a minute on one core).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import torch

from aerohrl import task
from aerohrl.envs.episodes import EpisodeSet, hover_states

if TYPE_CHECKING:
    from aerohrl.algorithms.base import Algorithm
    from aerohrl.algorithms.data import Dataset
    from aerohrl.planning.planner import Candidates


def _flights(starts: np.ndarray, goals: np.ndarray, horizon: int) -> EpisodeSet:
    n = len(starts)
    none = np.full(n, -1, np.int64)
    return EpisodeSet("oracle", starts, goals, np.full(n, int(horizon), np.int64), none, none, np.zeros(n, np.int64))


def roc_auc(score: np.ndarray, label: np.ndarray) -> float:
    """Area under the ROC curve of ``score`` for the boolean ``label`` (nan when one class is empty).
    (Mann-Whitney U with average ranks for ties; scipy's rankdata.)"""
    from scipy.stats import rankdata

    s, y = np.ravel(score), np.ravel(label).astype(bool)
    n1, n0 = int(y.sum()), int((~y).sum())
    if n1 == 0 or n0 == 0:
        return float("nan")
    r = rankdata(s)
    return float((r[y].sum() - n1 * (n1 + 1) / 2) / (n1 * n0))


def oracle_single(
    algo: Algorithm,
    data: Dataset,
    goals: np.ndarray,
    *,
    candidates: int = 150,
    seed: int = 0,
    leg_horizon: int = 500,
    alpha: float = 1.0,
    chunk: int = 4096,
    sim: dict | None = None,
    progress: bool = False,
    cand: Candidates | None = None,
) -> dict:
    """Fly every first and second leg of the single-goal planner (see the module docstring).
    ``cand`` (:class:`~aerohrl.planning.planner.Candidates`) replaces the dataset's achieved
    goals, e.g. :func:`synthetic_candidates`."""
    from tqdm import tqdm

    from aerohrl.planning.planner import Planner, candidates_from_dataset, leg_values
    from aerohrl.envs.rollout import rollout

    sim = sim or {}
    G = np.asarray(goals, np.float64)
    if cand is None:
        cand = candidates_from_dataset(data, candidates, seed=seed)
    S = cand.states.double().cpu().numpy()
    E, C = len(G), len(cand)
    first = rollout(algo, _flights(hover_states(C), cand.goals.double().cpu().numpy(), leg_horizon), **sim)
    pairs_s = np.repeat(S[None], E, 0).reshape(E * C, -1)
    pairs_g = np.repeat(G[:, None], C, 1).reshape(E * C, -1)
    succ: np.ndarray = np.zeros(E * C, bool)
    near: np.ndarray = np.zeros(E * C, bool)
    for i in tqdm(range(0, E * C, chunk), desc="second legs", disable=None if progress else True, leave=False):
        r = rollout(algo, _flights(pairs_s[i : i + chunk], pairs_g[i : i + chunk], leg_horizon), **sim)
        succ[i : i + chunk], near[i : i + chunk] = r["success"], r["near_success"]
    succ, near = succ.reshape(E, C), near.reshape(E, C)
    dev = next(algo.parameters()).device
    f32 = dict(dtype=torch.float32, device=dev)
    B = leg_values(algo, torch.as_tensor(pairs_s, **f32), torch.as_tensor(pairs_g, **f32)).mean(0).cpu().numpy().reshape(E, C)
    works = succ & first["success"][None, :]
    works_near = near & first["near_success"][None, :]
    plan = Planner(algo, cand, n=1, alpha=alpha).plan(hover_states(E), G, n=1)
    pick = plan.index[:, 0]
    dist = np.linalg.norm(G[:, None, task.POS] - S[None, :, task.POS], axis=-1)
    by_dist = {}
    for lo in range(0, int(np.ceil(dist.max())) + 1):
        m = (dist >= lo) & (dist < lo + 1)
        if m.any():
            by_dist[f"{lo}-{lo + 1} m"] = {
                "pairs": int(m.sum()),
                "success": float(succ[m].mean()),
                "near_success": float(near[m].mean()),
            }
    return {
        "goals": E,
        "candidates": C,
        "leg_horizon": int(leg_horizon),
        "first_leg_success": float(first["success"].mean()),
        "first_leg_near_success": float(first["near_success"].mean()),
        "second_leg_success": float(succ.mean()),
        "second_leg_near_success": float(near.mean()),
        "goals_with_a_working_second_leg": float(succ.any(1).mean()),
        "oracle": float(works.any(1).mean()),
        "oracle_near": float(works_near.any(1).mean()),
        "planner": float(works[np.arange(E), pick].mean()),
        "planner_near": float(works_near[np.arange(E), pick].mean()),
        "auc_second_leg_value": roc_auc(B, succ),
        "auc_second_leg_value_near": roc_auc(B, near),
        "second_leg_by_distance": by_dist,
    }


def synthetic_candidates(spec: dict | None, n: int, seed: int = 0) -> Candidates:
    """``n`` synthetic waypoints relative to the start at the origin (planning/planner.py's
    offsets, none biased toward a goal): any state within rho_D of the start, as
    :class:`~aerohrl.planning.planner.Candidates` (state = the waypoint with zero body rates)."""
    from aerohrl.planning.planner import Candidates, offsets_from_spec

    off = offsets_from_spec(spec, n, seed, toward=0.0)
    goals = torch.cat([off.pos, off.vel, off.rot], dim=1).float()
    states = torch.cat([goals, torch.zeros(len(goals), 3)], dim=1)
    return Candidates(goals.clone(), states, np.full(len(goals), -1))


def format_report(r: dict) -> str:
    """The oracle's report (:func:`oracle_single`'s dict) as readable lines."""
    lines = [
        f"{r['goals']} goals x {r['candidates']} candidates, legs of {r['leg_horizon']} steps",
        f"first legs  (origin -> g):  success {100 * r['first_leg_success']:.1f} %, near {100 * r['first_leg_near_success']:.1f} %",
        f"second legs (s_g -> G):     success {100 * r['second_leg_success']:.2f} %, near {100 * r['second_leg_near_success']:.2f} %; "
        f"goals with any working second leg {100 * r['goals_with_a_working_second_leg']:.1f} %",
        f"oracle (best candidate, both legs): success {100 * r['oracle']:.1f} %, near {100 * r['oracle_near']:.1f} %",
        f"Eq. 3.7 choice, same composition:   success {100 * r['planner']:.1f} %, near {100 * r['planner_near']:.1f} %",
        f"critics' second-leg value, ROC AUC: success {r['auc_second_leg_value']:.3f}, near {r['auc_second_leg_value_near']:.3f}",
        "second legs by distance |G - p_g|: "
        + ", ".join(
            f"{k}: {100 * v['success']:.1f}/{100 * v['near_success']:.1f} % ({v['pairs']})"
            for k, v in r["second_leg_by_distance"].items()
        ),
    ]
    return "\n".join(lines)


__all__ = ["oracle_single", "format_report", "roc_auc", "synthetic_candidates"]
