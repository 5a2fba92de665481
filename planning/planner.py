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
were achieved (``next_state``, 18) as ``s_g``, or in a maze the hover states at the free
cells' centres (:func:`candidates_from_maze`); ``max_candidates`` draws a seeded subset
(the 52,530 achieved goals of the 250-goal dataset are 100 Hz samples of smooth
trajectories, so neighbours are near-duplicates; the cost is E x C network passes).

**Synthetic candidates for chains** (:class:`ChainPlanner`). The achieved goals all lie
within ~2 m of the origin (every expert flight starts there), so no chain to a goal
10-20 m away can be built from them. A synthetic candidate is any state within rho_D
*relative to the current one*, in distribution by construction (the networks are
translation invariant, aerohrl/task.py): a fixed, seeded offset set Delta
(:func:`synthetic_offsets`) of C offsets, position ``dp ~ U(-hi, hi)`` per axis (``hi`` =
the dataset spec's ``pos_range`` upper bound: what its flights cover from their start),
velocity ``v ~ U(vel_range)``, acceleration ``~ U(acc_range)`` -> ``R`` by flatness, body
rates 0. A chain ``s0 -> g_1 -> ... -> g_k -> G`` has ``g_{j+1} = g_j (+) Delta_c``:
position added to the previous waypoint's position (``g_0`` = the start), velocity and
attitude the offset's own. A fraction ``toward`` of the offsets is biased toward G: their
position step is ``sign(d_i) * min(u_i, |d_i|)`` per axis, ``d = p_G - p`` from the
waypoint being extended, ``u_i ~ U(toward_range)`` drawn once (never past G on an axis).
Leg values are computed plainly with the real states (a waypoint as a state: its p, v,
R and w = 0). Objective: Eq. 3.6 as above (product of the legs' values including the
final leg to G, mean over critics, minus alpha x the sum of the legs' variances). Beam
search over depths 1..n: at each depth every beam (E x k) is extended by the C offsets
from its last waypoint (E x k x C leg values, plus E x k x C final legs to G), ranked by
its score if completed now; the best *completed* plan over all depths is returned (a
chain may stop early), padded to n goals by repeating its last waypoint (a repeated goal
is reached at once and, with re-planning, triggers a new plan from the flown state).
:func:`chain_length` picks n from the distance to fly.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import torch

from aerohrl import task

if TYPE_CHECKING:
    from aerohrl.algorithms.base import Algorithm
    from aerohrl.algorithms.data import Dataset
    from aerohrl.worlds.maze import Maze

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


def candidates_from_dataset(data: Dataset, max_candidates: int = 0, seed: int = 0) -> Candidates:
    """The dataset's achieved goals (all, or a seeded subset of ``max_candidates``)."""
    F = len(data)
    if F == 0:
        raise ValueError("the dataset holds no achieved goals to plan with")
    idx: np.ndarray = np.arange(F)
    if 0 < max_candidates < F:
        idx = np.sort(np.random.default_rng([seed, 7]).choice(F, size=int(max_candidates), replace=False))
    ns = data.next_state[torch.as_tensor(idx)].float()
    return Candidates(task.achieved_goal(ns).clone(), ns.clone(), idx)


def candidates_from_maze(maze: Maze) -> Candidates:
    """Hover states at the centres of every free cell of ``maze`` (flight altitude, ``v = 0``,
    ``R = I``, ``w = 0``), in :attr:`~aerohrl.worlds.maze.Maze.free_cells` order (``frame`` =
    that index). In a maze the critics see the absolute position, so these waypoints carry
    the value of being at each maze position; the planner scores them as any candidates."""
    free = maze.free_cells
    states = np.zeros((len(free), task.STATE_DIM))
    states[:, task.POS] = maze.cell_center(free)
    states[:, task.ROT] = np.eye(3).ravel()
    t = torch.as_tensor(states, dtype=torch.float32)
    return Candidates(task.achieved_goal(t).clone(), t, np.arange(len(free)))


@torch.no_grad()
def leg_values(algo: Algorithm, states: torch.Tensor, goals: torch.Tensor, chunk: int = DEFAULT_CHUNK) -> torch.Tensor:
    """``Q_j(s, pi(s, g), g)`` for every critic j: (m, M) from states (M, 18), goals (M, 15)."""
    out = []
    for i in range(0, len(states), chunk):
        s, g = states[i : i + chunk], goals[i : i + chunk]
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
    depth: np.ndarray | None = None  # (E,) distinct goals of the plan (ChainPlanner: <= n; the rest repeat the last)


class Planner:
    """Eq. 3.7 (``n = 1``) / Eq. 3.6 by beam search (``n > 1``) over :class:`Candidates`."""

    def __init__(
        self,
        algo,
        candidates: Candidates,
        *,
        n: int = 1,
        alpha: float = DEFAULT_ALPHA,
        beam: int = 8,
        chunk: int = DEFAULT_CHUNK,
        min_leg: float = 0.0,
    ):
        if len(candidates) == 0:
            raise ValueError("the planner's candidate set is empty")
        if n < 1:
            raise ValueError(f"the number of intermediate goals must be >= 1, got {n}")
        if beam < 1:
            raise ValueError(f"beam width must be >= 1, got {beam}")
        if not min_leg >= 0:
            raise ValueError(f"the shortest first leg must be >= 0 m, got {min_leg}")
        self.algo, self.cand, self.n, self.alpha, self.beam, self.chunk = (
            algo,
            candidates,
            int(n),
            float(alpha),
            int(beam),
            int(chunk),
        )
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
    def plan(self, s0: np.ndarray | torch.Tensor, G: np.ndarray | torch.Tensor, n: int | None = None) -> Plan:
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
        return Plan(
            goals, seq.numpy(), self.cand.frame[seq.numpy()], score.double().cpu().numpy(), direct_score.double().cpu().numpy()
        )


MAX_CHAIN = 12  # chain_length's bound on the number of intermediate goals


@dataclass
class Offsets:
    """Synthetic offsets Delta (module docstring): position step (C, 3), velocity (C, 3),
    attitude (C, 9, row-major), ``toward`` (C,) bool: biased toward G, whose position
    step is ``sign(d) * min(mag, |d|)`` per axis with ``mag`` (C, 3) (unused otherwise)."""

    pos: torch.Tensor
    vel: torch.Tensor
    rot: torch.Tensor
    toward: torch.Tensor
    mag: torch.Tensor

    def __len__(self) -> int:
        return len(self.pos)

    def to(self, device: str | torch.device) -> "Offsets":
        """The offsets on ``device``."""
        return Offsets(*(t.to(device) for t in (self.pos, self.vel, self.rot, self.toward, self.mag)))

    def steps(self, d: torch.Tensor) -> torch.Tensor:
        """Position steps (..., C, 3) from waypoints whose remaining displacement to G is d (..., 3)."""
        d = d[..., None, :]
        biased = torch.sign(d) * torch.minimum(self.mag, d.abs())
        return torch.where(self.toward[:, None], biased, self.pos.expand(biased.shape))


def synthetic_offsets(
    C: int = 256,
    seed: int = 0,
    *,
    pos_hi: float = 2.0,
    vel_range: tuple[float, float] = (-2.5, 2.5),
    acc_range: tuple[float, float] = (-5.0, 5.0),
    toward: float = 0.5,
    toward_range: tuple[float, float] = (1.0, 2.0),
) -> Offsets:
    """C seeded offsets (module docstring): the first ``round(toward * C)`` biased toward G
    (position magnitude ``U(toward_range)`` per axis, signed at planning time), the rest
    ``dp ~ U(-pos_hi, pos_hi)``; all with ``v ~ U(vel_range)``, ``R = flat_attitude(a ~ U(acc_range))``."""
    from aerohrl.datagen.goals import check_range, flat_attitude

    if isinstance(C, bool) or int(C) != C or C < 1:
        raise ValueError(f"the number of synthetic offsets must be a positive integer, got {C!r}")
    if not (np.isfinite(pos_hi) and pos_hi > 0):
        raise ValueError(f"the offsets' position range must be > 0 m, got {pos_hi}")
    if not 0 <= toward <= 1:
        raise ValueError(f"the fraction of offsets toward the goal must be in [0, 1], got {toward}")
    v_lo, v_hi = check_range("vel_range", vel_range)
    a_lo, a_hi = check_range("acc_range", acc_range)
    t_lo, t_hi = check_range("toward_range", toward_range, non_negative=True)
    C = int(C)
    rng = np.random.default_rng([int(seed), 17])
    pos = rng.uniform(-pos_hi, pos_hi, (C, 3))
    vel = rng.uniform(v_lo, v_hi, (C, 3))
    acc = rng.uniform(a_lo, a_hi, (C, 3))
    mag = rng.uniform(t_lo, t_hi, (C, 3))
    tw = np.arange(C) < int(round(toward * C))
    R = flat_attitude(acc).reshape(C, 9)
    f = lambda x: torch.as_tensor(x, dtype=torch.float32)  # noqa: E731
    return Offsets(f(pos), f(vel), f(R), torch.as_tensor(tw), f(mag))


def offsets_from_spec(spec: dict | None, C: int = 256, seed: int = 0, **kw: Any) -> Offsets:
    """:func:`synthetic_offsets` with the ranges of a dataset spec (``pos_range`` hi, ``vel_range``, ``acc_range``)."""
    spec = spec or {}
    return synthetic_offsets(
        C,
        seed,
        pos_hi=float((spec.get("pos_range") or (1.0, 2.0))[1]),
        vel_range=tuple(spec.get("vel_range") or (-2.5, 2.5)),
        acc_range=tuple(spec.get("acc_range") or (-5.0, 5.0)),
        **kw,
    )


def chain_length(s0: np.ndarray, G: np.ndarray, step: float = 2.0, max_n: int = MAX_CHAIN) -> np.ndarray:
    """Intermediate goals to reach G (E, 15) from s0 (E, 18) in legs of at most ``step`` m
    per axis: ``ceil(max_i |G_i - p0_i| / step) - 1``, within [1, max_n]; (E,) int."""
    d = np.abs(np.asarray(G, np.float64)[..., :3] - np.asarray(s0, np.float64)[..., :3]).max(-1)
    return np.clip(np.ceil(d / float(step) - 1e-9).astype(np.int64) - 1, 1, int(max_n))


def _as_state(goals: torch.Tensor) -> torch.Tensor:
    """A goal (..., 15) as the state in which it holds: body rates 0 (..., 18)."""
    return torch.cat([goals, goals.new_zeros(*goals.shape[:-1], 3)], -1)


class ChainPlanner:
    """Eq. 3.6 over chains of synthetic candidates (module docstring); the interface of
    :class:`Planner`: ``plan(s0 (E, 18), G (E, 15), n=None) -> Plan`` with ``n`` goals per
    episode (the best chain of 1..n distinct ones, padded by repeating its last goal).
    ``Plan.index`` holds the offset index of each goal (-1 for a repeat), ``Plan.frame``
    -1 (no dataset frame), ``Plan.depth`` the number of distinct goals."""

    def __init__(
        self, algo, offsets: Offsets, *, n: int = 1, alpha: float = DEFAULT_ALPHA, beam: int = 8, chunk: int = DEFAULT_CHUNK
    ):
        if len(offsets) == 0:
            raise ValueError("the chain planner's offset set is empty")
        if n < 1:
            raise ValueError(f"the number of intermediate goals must be >= 1, got {n}")
        if beam < 1:
            raise ValueError(f"beam width must be >= 1, got {beam}")
        self.algo, self.n, self.alpha, self.beam, self.chunk = algo, int(n), float(alpha), int(beam), int(chunk)
        self.device = next(algo.parameters()).device
        self.off = offsets.to(self.device)

    def _legs(self, states: torch.Tensor, goals: torch.Tensor) -> torch.Tensor:
        """(m, *batch) leg values of states (*batch, 18) -> goals (*batch, 15)."""
        shape = goals.shape[:-1]
        v = leg_values(self.algo, states.reshape(-1, states.shape[-1]), goals.reshape(-1, goals.shape[-1]), self.chunk)
        return v.reshape(v.shape[0], *shape)

    @torch.no_grad()
    def plan(self, s0: np.ndarray | torch.Tensor, G: np.ndarray | torch.Tensor, n: int | None = None) -> Plan:
        """Plan ``n`` (default ``self.n``) intermediate goals from ``s0`` (E, 18) to ``G`` (E, 15)."""
        n = self.n if n is None else int(n)
        if n < 1:
            raise ValueError(f"the number of intermediate goals must be >= 1, got {n}")
        s0 = torch.as_tensor(np.asarray(s0), dtype=torch.float32, device=self.device)
        G = torch.as_tensor(np.asarray(G), dtype=torch.float32, device=self.device)
        E, C = len(s0), len(self.off)
        direct = leg_values(self.algo, s0, G, self.chunk)
        direct_score = direct.mean(0) - self.alpha * direct.var(0, unbiased=False)
        m = direct.shape[0]
        k = self.beam
        per_episode = k * C * (4 * m + 2 * task.STATE_DIM + 2 * task.GOAL_DIM)  # floats of one episode's depth step
        block = max(1, BEAM_FLOATS // per_episode)
        parts = [self._search(s0[i : i + block], G[i : i + block], n) for i in range(0, E, block)]
        goals, index, score, depth = (torch.cat(x) for x in zip(*parts))
        return Plan(
            goals.double().cpu().numpy(),
            index.cpu().numpy(),
            np.full((E, n), -1, np.int64),
            score.double().cpu().numpy(),
            direct_score.double().cpu().numpy(),
            depth.cpu().numpy(),
        )

    def _search(self, s0: torch.Tensor, G: torch.Tensor, n: int):
        """Beam search of Eq. 3.6 over chains for a block of episodes; the best completed chain of depth 1..n."""
        E, C, a, dev = len(s0), len(self.off), self.alpha, self.device
        ar = torch.arange(E, device=dev)[:, None]
        last = s0[:, None, :]  # (E, K, 18): the beams' last states (K = 1: the start)
        prod = torch.ones(1, E, 1, device=dev)  # (m, E, K) per-critic product of the legs so far
        vsum = torch.zeros(E, 1, device=dev)  # (E, K) sum of the legs' variances
        wps = s0.new_zeros(E, 1, 0, task.GOAL_DIM)  # (E, K, depth, 15)
        seq = torch.zeros(E, 1, 0, dtype=torch.long, device=dev)  # (E, K, depth) offset indices
        best_score = torch.full((E,), -torch.inf, device=dev)
        best_goals = s0.new_zeros(E, n, task.GOAL_DIM)
        best_index = torch.full((E, n), -1, dtype=torch.long, device=dev)
        best_depth = torch.zeros(E, dtype=torch.long, device=dev)
        for d in range(1, n + 1):
            K = last.shape[1]
            p = last[..., task.POS]  # (E, K, 3)
            new_p = p[:, :, None, :] + self.off.steps(G[:, None, task.POS] - p)  # (E, K, C, 3)
            W = torch.cat([new_p, self.off.vel.expand(E, K, C, 3), self.off.rot.expand(E, K, C, 9)], -1)  # (E, K, C, 15)
            Ws = _as_state(W)
            P = self._legs(last[:, :, None, :].expand(E, K, C, task.STATE_DIM), W)  # (m, E, K, C)
            F = self._legs(Ws, G[:, None, None, :].expand(E, K, C, task.GOAL_DIM))  # (m, E, K, C): final leg to G
            new_prod = prod[..., None] * P
            new_vsum = vsum[..., None] + P.var(0, unbiased=False)
            score = ((new_prod * F).mean(0) - a * (new_vsum + F.var(0, unbiased=False))).reshape(E, K * C)
            t = score.topk(min(self.beam, K * C), dim=1)  # (E, k'), best first
            b_idx, c_idx = t.indices // C, t.indices % C
            wps = torch.cat([wps[ar, b_idx], W[ar, b_idx, c_idx][:, :, None]], 2)  # (E, k', d, 15)
            seq = torch.cat([seq[ar, b_idx], c_idx[..., None]], 2)
            better = t.values[:, 0] > best_score  # a deeper chain replaces the best only if it scores higher
            if better.any():
                best_score = torch.where(better, t.values[:, 0], best_score)
                top = wps[:, 0]  # (E, d, 15)
                padded = torch.cat([top, top[:, -1:].expand(E, n - d, task.GOAL_DIM)], 1)
                best_goals = torch.where(better[:, None, None], padded, best_goals)
                idx = torch.cat([seq[:, 0], seq.new_full((E, n - d), -1)], 1)
                best_index = torch.where(better[:, None], idx, best_index)
                best_depth = torch.where(better, d, best_depth)
            last = Ws[ar, b_idx, c_idx]  # (E, k', 18)
            prod = new_prod.reshape(new_prod.shape[0], E, K * C)[:, ar, t.indices]
            vsum = new_vsum.reshape(E, K * C)[ar, t.indices]
        return best_goals, best_index, best_score, best_depth


__all__ = [
    "Candidates",
    "candidates_from_dataset",
    "candidates_from_maze",
    "leg_values",
    "Planner",
    "Plan",
    "DEFAULT_ALPHA",
    "ChainPlanner",
    "Offsets",
    "synthetic_offsets",
    "offsets_from_spec",
    "chain_length",
]
