"""Eq. 3.6 solved exactly over any number of intermediate goals: shortest paths on the
candidates' graph, weighted by the critics (search on the replay buffer, Eysenbach et
al. 2019, with the thesis's leg values).

Eq. 3.6 scores a plan ``s0 -> g_1 -> ... -> g_k -> G`` by the product of its legs' values.
With each leg valued by the ensemble's penalised value (the variance penalty of Eq. 3.6
taken per leg, which makes the objective decompose over legs)::

    l(s -> g) = clip(mean_j Q_j(s, pi(s, g), g) - alpha var_j Q_j(s, pi(s, g), g), eps, 1)

the best plan maximises ``prod_legs l`` = minimises ``sum_legs -log l``: a shortest path
from ``s0`` to ``G`` through the candidates, with edge lengths ``-log l``. With critics
in [0, 1] that estimate ``gamma^steps``, ``-log l / -log gamma`` is the estimated number
of steps of a leg, so the plan is the quickest chain of legs the critics believe in.
``Planner``'s beam search approximates this for a fixed ``n``; here the number of legs
is free and the optimum exact over the candidate set:

* the candidate-to-candidate lengths ``D`` (C, C): every pair's leg once, then all-pairs
  shortest paths (scipy's ``csgraph.shortest_path``, Dijkstra), with predecessors;
* per episode, the first leg ``a[e, i] = -log l(s0_e -> c_i)`` and the last
  ``b[e, j] = -log l(s_{c_j} -> G_e)``; the best plan is ``min_{i, j} a[e, i] + D[i, j] +
  b[e, j]`` (a min-plus product, in episode blocks), compared with the straight leg
  ``-log l(s0 -> G)``.

Legs valued below ``min_leg_value`` are not edges (the critics' values of far pairs,
which the data never connects, are the least trustworthy), nor, with ``max_edge``, legs
longer than that many metres (a roadmap's connection radius). Learned values generalise
with the distance between the vehicle and its goal: a pair of states on the two sides of
a wall gets the value of an open leg of that length, and a plan through such a spurious
edge flies into the wall. Among waypoints at the free cells' centres of a grid maze, a
radius below the diagonal of a cell (``sqrt 2 cell``) leaves only legs between adjacent
free cells, which no wall separates: the planner then knows the map's free cells and
their neighbours, and learns only how long each leg takes. ``edge_filter`` gives the map
another way: legs along straight free corridors only (``Maze.in_corridor``), the legs a
maze expert flies between the corners of its path, of any length.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import torch

from aerohrl import task
from aerohrl.planning.planner import DEFAULT_ALPHA, DEFAULT_CHUNK, Candidates, Plan, leg_values

EPS = 1e-6  # leg values are clipped to [EPS, 1] before the log
EPISODE_BLOCK_FLOATS = 1 << 24  # the (E_block, C, C) min-plus product stays below this


def leg_lengths(values: torch.Tensor, alpha: float, min_leg_value: float = 0.0) -> torch.Tensor:
    """Edge lengths ``-log clip(mean - alpha var, EPS, 1)`` of leg values (m, ...) over the
    ensemble's first axis; ``inf`` where the penalised value is below ``min_leg_value``."""
    v = values.mean(0) - alpha * values.var(0, unbiased=False)
    length = -torch.log(v.clamp(EPS, 1.0))
    return length.masked_fill(v < min_leg_value, math.inf) if min_leg_value > 0 else length


class GraphPlanner:
    """Plans by shortest paths over :class:`Candidates` (module docstring); the
    ``plan(s0, G, n)`` interface of :class:`~aerohrl.planning.planner.Planner`."""

    def __init__(
        self,
        algo,
        candidates: Candidates,
        *,
        n: int = 1,
        alpha: float = DEFAULT_ALPHA,
        min_leg_value: float = 0.0,
        max_edge: float = 0.0,
        min_leg: float = 0.0,
        edge_filter: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None,
        chunk: int = DEFAULT_CHUNK,
    ):
        if len(candidates) == 0:
            raise ValueError("the planner's candidate set is empty")
        if n < 1:
            raise ValueError(f"the number of intermediate goals must be >= 1, got {n}")
        if not 0 <= min_leg_value < 1:
            raise ValueError(f"the smallest leg value of an edge must be in [0, 1), got {min_leg_value}")
        if not max_edge >= 0:
            raise ValueError(f"the longest edge must be >= 0 m (0: no limit), got {max_edge}")
        from scipy.sparse.csgraph import csgraph_from_dense, shortest_path

        self.algo, self.cand, self.n, self.alpha, self.min_leg_value, self.chunk = (
            algo,
            candidates,
            int(n),
            float(alpha),
            float(min_leg_value),
            int(chunk),
        )
        self.max_edge = float(max_edge)  # m; 0: no limit
        # legs from positions p to q (..., 3) that the map allows (e.g. Maze.in_corridor); None: all
        self.edge_filter = edge_filter
        # candidates closer than this to the vehicle are no first goal (Planner's min_leg): a
        # goal it already sits at is no leg, and the skills never learned to fly one
        if not min_leg >= 0:
            raise ValueError(f"the shortest first leg must be >= 0 m, got {min_leg}")
        self.min_leg = float(min_leg)
        self.device = next(algo.parameters()).device
        self.cg = candidates.goals.to(self.device)
        self.cs = candidates.states.to(self.device)
        C = len(candidates)
        s = self.cs[torch.arange(C * C, device=self.device) // C]
        g = self.cg[torch.arange(C * C, device=self.device) % C]
        lt = leg_lengths(leg_values(algo, s, g, self.chunk).reshape(-1, C, C), self.alpha, self.min_leg_value)
        L = self._prune(lt, self.cs[:, task.POS][:, None], self.cg[:, task.POS][None]).cpu().numpy()
        np.fill_diagonal(L, np.inf)  # no self-loops (a zero-length edge would read as "no edge" below)
        L = np.maximum(L, 1e-12)  # csgraph's dense input: 0 means no edge, so a free leg costs a hair
        graph = csgraph_from_dense(L, null_value=np.inf)
        self.dist, self.pred = shortest_path(graph, method="D", directed=True, return_predecessors=True)
        np.fill_diagonal(self.dist, 0.0)

    def _prune(self, lengths: torch.Tensor, p: torch.Tensor, q: torch.Tensor) -> torch.Tensor:
        """``lengths`` with legs from positions ``p`` to ``q`` (broadcast) longer than
        ``max_edge`` or refused by ``edge_filter`` removed."""
        if self.max_edge > 0:
            lengths = lengths.masked_fill(torch.linalg.norm(q - p, dim=-1) > self.max_edge, math.inf)
        if self.edge_filter is not None:  # asked only about the legs still in the graph
            live = torch.isfinite(lengths).cpu().numpy()
            shape = (*lengths.shape, p.shape[-1])
            P = np.broadcast_to(p.double().cpu().numpy(), shape)[live]
            Q = np.broadcast_to(q.double().cpu().numpy(), shape)[live]
            ok = np.ones(lengths.shape, bool)
            ok[live] = self.edge_filter(P, Q) if len(P) else True
            lengths = lengths.masked_fill(torch.as_tensor(~ok, device=lengths.device), math.inf)
        return lengths

    def _path(self, i: int, j: int) -> list[int]:
        """Candidate indices of the shortest path from ``i`` to ``j`` (both included)."""
        path = [j]
        while path[-1] != i:
            path.append(int(self.pred[i, path[-1]]))
        return path[::-1]

    @torch.no_grad()
    def plan(self, s0: np.ndarray | torch.Tensor, G: np.ndarray | torch.Tensor, n: int | None = None) -> Plan:
        """The first ``n`` (default ``self.n``) intermediate goals of each episode's best plan
        from ``s0`` (E, 18) to ``G`` (E, 15); a plan with fewer goals repeats its last one
        (reached at once). ``score``/``direct_score``: the plan's and the straight leg's
        products of penalised leg values."""
        n = self.n if n is None else int(n)
        s0 = torch.as_tensor(np.asarray(s0), dtype=torch.float32, device=self.device)
        Gt = torch.as_tensor(np.asarray(G), dtype=torch.float32, device=self.device)
        E, C = len(s0), len(self.cg)
        ie, ic = torch.arange(E * C, device=self.device) // C, torch.arange(E * C, device=self.device) % C
        la = leg_lengths(leg_values(self.algo, s0[ie], self.cg[ic], self.chunk), self.alpha, self.min_leg_value)
        lb = leg_lengths(leg_values(self.algo, self.cs[ic], Gt[ie], self.chunk), self.alpha, self.min_leg_value)
        la = self._prune(la.reshape(E, C), s0[:, None, task.POS], self.cg[None, :, task.POS])
        if self.min_leg > 0:
            near = torch.linalg.norm(self.cg[None, :, task.POS] - s0[:, None, task.POS], dim=-1) < self.min_leg
            la = la.masked_fill(near, math.inf)
        lb = self._prune(lb.reshape(E, C), self.cs[None, :, task.POS], Gt[:, None, task.POS])
        a, b = la.cpu().numpy(), lb.cpu().numpy()
        direct = leg_lengths(leg_values(self.algo, s0, Gt, self.chunk), self.alpha).cpu().numpy()
        best_i, best_j, best = np.zeros(E, np.int64), np.zeros(E, np.int64), np.full(E, np.inf)
        block = max(1, EPISODE_BLOCK_FLOATS // max(1, C * C))
        for e0 in range(0, E, block):  # min over (i, j) of a[e, i] + D[i, j] + b[e, j], in episode blocks
            sl = slice(e0, min(e0 + block, E))
            tot = a[sl, :, None] + self.dist[None] + b[sl, None, :]  # (e, C, C)
            flat = tot.reshape(tot.shape[0], -1).argmin(1)
            best_i[sl], best_j[sl] = flat // C, flat % C
            best[sl] = tot.reshape(tot.shape[0], -1)[np.arange(tot.shape[0]), flat]
        seq = np.zeros((E, n), np.int64)
        depth = np.zeros(E, np.int64)
        for e in range(E):  # path reconstruction: E short walks along the predecessor matrix
            path = self._path(int(best_i[e]), int(best_j[e])) if np.isfinite(best[e]) else [int(best_i[e])]
            depth[e] = len(path)
            path = (path + [path[-1]] * n)[:n]
            seq[e] = path
        goals = self.cand.goals[torch.as_tensor(seq)].double().numpy()
        frame = self.cand.frame[seq]
        # no chain of edges joins the vehicle to the goal (candidates that the edge rules leave
        # unconnected, e.g. dataset states no clear leg reaches): the only plan is the straight
        # leg, every intermediate goal is G itself (reached at once), frame -1
        none = ~np.isfinite(best)
        goals[none] = Gt[torch.as_tensor(none)].double().cpu().numpy()[:, None]
        frame[none], depth[none] = -1, 0
        return Plan(goals, seq, frame, np.exp(-best), np.exp(-direct), depth=np.minimum(depth, n))


__all__ = ["GraphPlanner", "leg_lengths"]
