"""Intermediate-goal planner over the dataset's achieved goals (thesis §3.4.3-3.4.4).

Every term of the planning objective is one *leg value*: the 5-critic ensemble at a
state and the policy's action for a goal, ``Q_j(s, pi(s, g), g)`` (:func:`leg_values`,
shape (m, M), evaluated in chunks of ``chunk`` rows in one batched pass).

* **Eq. 3.7** (single intermediate goal, the thesis' planner, :meth:`Planner.plan` with
  ``n = 1``): for each episode (start ``s0``, goal ``G``) and every candidate ``g`` with
  its dataset state ``s_g``::

      score(g) = mean_j(Q_j(s0, pi(s0,g), g) * Q_j(s_g, pi(s_g,G), G))
                 - alpha * (var_j Q_j(s0, pi(s0,g), g) + var_j Q_j(s_g, pi(s_g,G), G))

  ``A[e, c] = Q(s0_e -> c)`` is computed once per *distinct* start state (all OOD
  flights start at hover at the origin, so it is one row of C values), ``B[e, c] =
  Q(s_c -> G_e)`` for all E x C pairs; the arg-max is exact over the candidate set.
* **Eq. 3.6** (``n > 1`` intermediate goals, beyond the thesis): beam search. A partial
  plan ``s0 -> g_1 -> ... -> g_k`` keeps its per-critic product of leg values (m,) and
  its sum of leg variances; it is extended by every candidate ``g_{k+1}`` at once with
  the pair values ``P[g_k, c] = Q(s_{g_k} -> c)`` (computed for the beam's distinct
  ``g_k`` only) and ranked by its score *if completed now* (x ``B``, + var ``B``), i.e.
  by Eq. 3.6 with ``k`` goals; the ``beam`` best per episode survive. A plan may repeat
  a goal (then that leg costs nothing and is flown in one step), so "n goals" means
  "at most n distinct ones". ``beam >= C`` makes the search exhaustive.

``min_leg > 0`` drops the candidates within that distance of an episode's start from its
first choice: a goal the vehicle already sits at is no intermediate goal, yet Eq. 3.7
favours it whenever the critics value flying straight to G above any real detour
(``Q(s0 -> s0) ~ 1``, so such a plan scores as the straight flight).

The variance is the population variance over the ``m`` critics (``var_j``). Candidates:
the achieved goals of the dataset (``next_state[:, :15]``) with the state in which they
were achieved (``next_state``, 18) as ``s_g``; ``max_candidates`` draws a seeded subset
(the 52,530 achieved goals of the 250-goal dataset are 100 Hz samples of smooth
trajectories, so neighbours are near-duplicates; the cost is E x C network passes).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from aerohrl import task
from aerohrl.errors import UserError

DEFAULT_ALPHA = 1.0
DEFAULT_CHUNK = 32768
BEAM_FLOATS = 1 << 25  # episodes per beam-search block: m x E_block x beam x C floats stay below this


@dataclass
class Candidates:
    """Intermediate-goal candidates rho_{D,ag}: goals (C, 15), states s_g (C, 18), frame index (C,)."""

    goals: torch.Tensor
    states: torch.Tensor
    frame: np.ndarray

    def __len__(self) -> int:
        return len(self.goals)


def candidates_from_dataset(data, max_candidates: int = 0, seed: int = 0) -> Candidates:
    """The dataset's achieved goals (all, or a seeded subset of ``max_candidates``)."""
    F = len(data)
    if F == 0:
        raise UserError("the dataset holds no achieved goals to plan with")
    idx = np.arange(F)
    if 0 < max_candidates < F:
        idx = np.sort(np.random.default_rng([seed, 7]).choice(F, size=int(max_candidates), replace=False))
    ns = data.next_state[torch.as_tensor(idx)].float()
    return Candidates(task.achieved_goal(ns).clone(), ns.clone(), idx)


@torch.no_grad()
def leg_values(algo, states: torch.Tensor, goals: torch.Tensor, chunk: int = DEFAULT_CHUNK) -> torch.Tensor:
    """``Q_j(s, pi(s, g), g)`` for every critic j: (m, M) from states (M, 18), goals (M, 15)."""
    out = []
    for i in range(0, len(states), chunk):
        s, g = states[i:i + chunk], goals[i:i + chunk]
        out.append(algo.critics(s, g, algo.act(s, g)))
    if not out:
        return torch.zeros(getattr(algo.cfg, "num_critics", 5), 0)
    return torch.cat(out, dim=1)


def _pairs(algo, states: torch.Tensor, goals: torch.Tensor, chunk: int) -> torch.Tensor:
    """(m, S, G) leg values of every (state, goal) pair, built chunk by chunk (never the
    full (S*G, 18) input)."""
    S, G = len(states), len(goals)
    out = []
    for i in range(0, S * G, chunk):
        idx = torch.arange(i, min(i + chunk, S * G), device=states.device)
        s, g = states[idx // G], goals[idx % G]
        out.append(algo.critics(s, g, algo.act(s, g)))
    if not out:
        return torch.zeros(getattr(algo.cfg, "num_critics", 5), S, G)
    return torch.cat(out, dim=1).reshape(-1, S, G)


@dataclass
class Plan:
    """Planned intermediate goals per episode."""

    goals: np.ndarray  # (E, n, 15) float64
    index: np.ndarray  # (E, n) candidate index
    frame: np.ndarray  # (E, n) dataset frame of each goal
    score: np.ndarray  # (E,) objective value of the chosen plan
    direct_score: np.ndarray  # (E,) the same objective with no intermediate goal (Q(s0 -> G) - alpha var)


class Planner:
    """Eq. 3.7 (``n = 1``) / Eq. 3.6 by beam search (``n > 1``) over :class:`Candidates`."""

    def __init__(self, algo, candidates: Candidates, *, n: int = 1, alpha: float = DEFAULT_ALPHA, beam: int = 8,
                 chunk: int = DEFAULT_CHUNK, min_leg: float = 0.0):
        if len(candidates) == 0:
            raise UserError("the planner's candidate set is empty")
        if n < 1:
            raise UserError(f"the number of intermediate goals must be >= 1, got {n}")
        if beam < 1:
            raise UserError(f"beam width must be >= 1, got {beam}")
        if not min_leg >= 0:
            raise UserError(f"the shortest first leg must be >= 0 m, got {min_leg}")
        self.algo, self.cand, self.n, self.alpha, self.beam, self.chunk = algo, candidates, int(n), float(alpha), int(beam), int(chunk)
        # candidates closer than this to the start are no intermediate goals (0: every candidate)
        self.min_leg = float(min_leg)
        dev = next(algo.parameters()).device
        self.device = dev
        self.cg = candidates.goals.to(dev)
        self.cs = candidates.states.to(dev)

    def _start_values(self, s0: torch.Tensor) -> torch.Tensor:
        """A (m, E, C): Q(s0_e -> c), computed once per distinct start state."""
        uniq, inv = torch.unique(s0, dim=0, return_inverse=True)
        return _pairs(self.algo, uniq, self.cg, self.chunk)[:, inv]

    def _goal_values(self, G: torch.Tensor) -> torch.Tensor:
        """B (m, E, C): Q(s_c -> G_e)."""
        return _pairs(self.algo, self.cs, G, self.chunk).transpose(1, 2)

    @torch.no_grad()
    def plan(self, s0, G, n: int | None = None) -> Plan:
        """Plan ``n`` (default ``self.n``) intermediate goals from states ``s0`` (E, 18) to goals ``G`` (E, 15)."""
        n = self.n if n is None else int(n)
        s0 = torch.as_tensor(np.asarray(s0), dtype=torch.float32, device=self.device)
        G = torch.as_tensor(np.asarray(G), dtype=torch.float32, device=self.device)
        E, C, a = len(s0), len(self.cg), self.alpha
        A = self._start_values(s0)  # (m, E, C)
        B = self._goal_values(G)  # (m, E, C)
        varB = B.var(0, unbiased=False)
        direct = leg_values(self.algo, s0, G, self.chunk)
        direct_score = direct.mean(0) - a * direct.var(0, unbiased=False)
        # depth 1 (Eq. 3.7 when n = 1): prod (m, E, C), var sum (E, C)
        prod, vsum = A, A.var(0, unbiased=False)
        score = (prod * B).mean(0) - a * (vsum + varB)
        if self.min_leg > 0:
            near = torch.cdist(s0[:, task.POS], self.cg[:, task.POS]) < self.min_leg  # (E, C)
            score = score.masked_fill(near, -torch.inf)
        if n == 1:
            best = score.argmax(1)
            ar = torch.arange(E, device=self.device)
            return self._result(best[:, None], score[ar, best], direct_score)
        k = min(self.beam, C)
        m = A.shape[0]
        block = max(1, BEAM_FLOATS // max(1, m * k * C))
        seqs, scores = [], []
        for e0 in range(0, E, block):  # episodes in blocks: the (m, E, k, C) extension stays bounded
            sl = slice(e0, min(e0 + block, E))
            sq, sc = self._beam(prod[:, sl], vsum[sl], score[sl], B[:, sl], varB[sl], n, k)
            seqs.append(sq)
            scores.append(sc)
        return self._result(torch.cat(seqs), torch.cat(scores), direct_score)

    def _beam(self, prod, vsum, score, B, varB, n: int, k: int):
        """Beam search of Eq. 3.6 for a block of episodes (see the module docstring)."""
        E, C, a = score.shape[0], score.shape[1], self.alpha
        top = score.topk(k, dim=1)  # beams (E, k)
        seq = top.indices[:, :, None]  # (E, k, depth)
        ar = torch.arange(E, device=self.device)[:, None]
        prod = prod[:, ar, top.indices]  # (m, E, k)
        vsum = vsum[ar, top.indices]  # (E, k)
        best_score, best_seq = top.values[:, 0], seq[:, 0, :]
        for _depth in range(1, n):
            last = seq[:, :, -1]  # (E, k)
            uniq, inv = torch.unique(last.reshape(-1), return_inverse=True)
            P = _pairs(self.algo, self.cs[uniq], self.cg, self.chunk)  # (m, U, C)
            Pk = P[:, inv.reshape(E, k)]  # (m, E, k, C)
            new_prod = prod[..., None] * Pk  # (m, E, k, C)
            new_vsum = vsum[..., None] + Pk.var(0, unbiased=False)  # (E, k, C)
            new_score = (new_prod * B[:, :, None, :]).mean(0) - a * (new_vsum + varB[:, None, :])  # (E, k, C)
            flat = new_score.reshape(E, -1)
            t = flat.topk(min(k, flat.shape[1]), dim=1)
            b_idx, c_idx = t.indices // C, t.indices % C
            seq = torch.cat([seq[ar, b_idx], c_idx[..., None]], dim=2)
            prod = new_prod.reshape(new_prod.shape[0], E, -1)[:, ar, t.indices]
            vsum = new_vsum.reshape(E, -1)[ar, t.indices]
            best_score, best_seq = t.values[:, 0], seq[:, 0, :]
        return best_seq, best_score

    def _result(self, seq: torch.Tensor, score: torch.Tensor, direct_score: torch.Tensor) -> Plan:
        seq = seq.cpu()
        goals = self.cand.goals[seq].double().numpy()
        return Plan(goals, seq.numpy(), self.cand.frame[seq.numpy()], score.double().cpu().numpy(),
                    direct_score.double().cpu().numpy())


__all__ = ["Candidates", "candidates_from_dataset", "leg_values", "Planner", "Plan", "DEFAULT_ALPHA"]
