"""A hierarchical agent's high level as the planner's candidate source (HIQL's subgoals
snapped to real states).

HIQL's high-level policy proposes, for a state ``s`` and a goal ``G``, the representation
``z = pi_h(s, G)`` of a state ``w`` to reach about ``hiql_subgoal_steps`` steps from now
(algorithms/hiql.py). A representation is no state to fly to, so this planner reads it
against a candidate set (a maze's free cells' hover states, or the dataset's achieved
goals, :class:`~aerohrl.planning.planner.Candidates`): the subgoal is the candidate whose
own representation seen from ``s`` is closest to the proposal,

    g_1 = argmin_c  ||phi(s, c) - z||^2,      z = pi_h(s, G);

with OGBench's length-normalised representations (both of norm ``sqrt(rep_dim)``) this
ranks as the dot product and the cosine, and with ``hiql_subgoal_space = "goal"`` (phi the
goal columns of the input) it is the nearest candidate to the proposed subgoal. A plan of
``n`` goals chains the choice from each chosen candidate's state:
``g_{k+1} = argmin_c ||phi(s_{g_k}, c) - pi_h(s_{g_k}, G)||^2``. The run's own
skill (``algo.act``) flies each leg; with ``--replan-every K`` the rollout asks again
from the flown state every K steps, which is HIQL's own execution with its subgoal
replaced by the nearest real state.

``score`` and ``direct_score`` are the product over the plan's legs (and the straight
leg) of the ensemble's mean leg values ``Q(s, pi(s, g), g)``, as the other planners
report them; they take no part in the choice, which is the high level's.
"""

from __future__ import annotations

import numpy as np
import torch

from aerohrl import task
from aerohrl.planning.planner import DEFAULT_CHUNK, Candidates, Plan, leg_values


class SubgoalPlanner:
    """Plans with a high-level policy's subgoals snapped to :class:`Candidates` (module
    docstring); the ``plan(s0, G, n)`` interface of :class:`~aerohrl.planning.planner.Planner`.
    ``algo`` must have ``subgoals(s, g)`` and ``goal_representation(s, g)`` (HIQL)."""

    def __init__(self, algo, candidates: Candidates, *, n: int = 1, min_leg: float = 0.0, chunk: int = DEFAULT_CHUNK):
        if not (hasattr(algo, "subgoals") and hasattr(algo, "goal_representation")):
            raise ValueError(f"the subgoal planner needs an agent with a high-level policy (hiql), not {type(algo).__name__}")
        if len(candidates) == 0:
            raise ValueError("the planner's candidate set is empty")
        if n < 1:
            raise ValueError(f"the number of intermediate goals must be >= 1, got {n}")
        if not min_leg >= 0:
            raise ValueError(f"the shortest first leg must be >= 0 m, got {min_leg}")
        self.algo, self.cand, self.n, self.min_leg, self.chunk = algo, candidates, int(n), float(min_leg), int(chunk)
        self.device = next(algo.parameters()).device
        self.cg = candidates.goals.to(self.device)
        self.cs = candidates.states.to(self.device)

    def _choose(self, s: torch.Tensor, G: torch.Tensor, first: bool) -> torch.Tensor:
        """(E,) the candidate closest to the high level's proposal from states ``s`` (E, 18)."""
        E, C = len(s), len(self.cg)
        z = self.algo.subgoals(s, G)  # (E, r)
        sim = torch.empty(E, C, device=self.device)
        rows = max(1, self.chunk // max(1, C))  # episodes per pass: rows x C representations
        for e0 in range(0, E, rows):
            se = s[e0 : e0 + rows]
            ie = torch.arange(len(se) * C, device=self.device) // C
            ic = torch.arange(len(se) * C, device=self.device) % C
            phi = self.algo.goal_representation(se[ie], self.cg[ic]).reshape(len(se), C, -1)
            sim[e0 : e0 + rows] = -(phi - z[e0 : e0 + rows, None]).pow(2).sum(-1)
        if first and self.min_leg > 0:
            near = torch.linalg.norm(self.cg[None, :, task.POS] - s[:, None, task.POS], dim=-1) < self.min_leg
            sim = sim.masked_fill(near & ~near.all(1, keepdim=True), -torch.inf)
        return sim.argmax(1)

    @torch.no_grad()
    def plan(self, s0: np.ndarray | torch.Tensor, G: np.ndarray | torch.Tensor, n: int | None = None) -> Plan:
        """``n`` (default ``self.n``) chained subgoals per episode from ``s0`` (E, 18) to ``G`` (E, 15)."""
        n = self.n if n is None else int(n)
        s = torch.as_tensor(np.asarray(s0), dtype=torch.float32, device=self.device)
        Gt = torch.as_tensor(np.asarray(G), dtype=torch.float32, device=self.device)
        start = s
        seq = torch.empty(len(s), n, dtype=torch.long, device=self.device)
        for k in range(n):
            seq[:, k] = self._choose(s, Gt, first=k == 0)
            s = self.cs[seq[:, k]]
        # the plan's legs s0 -> g_1 -> ... -> g_n -> G, valued by the critics (reported, not chosen on)
        froms = [start] + [self.cs[seq[:, k]] for k in range(n)]
        tos = [self.cg[seq[:, k]] for k in range(n)] + [Gt]
        score = torch.ones(len(start), device=self.device)
        for a, b in zip(froms, tos):
            score = score * leg_values(self.algo, a, b, self.chunk).mean(0).clamp(0, 1)
        direct = leg_values(self.algo, start, Gt, self.chunk).mean(0).clamp(0, 1)
        idx = seq.cpu().numpy()
        goals = self.cand.goals[torch.as_tensor(idx)].double().numpy()
        return Plan(goals, idx, self.cand.frame[idx], score.cpu().numpy(), direct.cpu().numpy())


__all__ = ["SubgoalPlanner"]
