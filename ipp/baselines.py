"""The five baselines of thesis Table 2.1 on the lattice's primitives, batched over envs.

All planners score candidate primitive sequences from the agents' current states
with a per-cell utility of the cells each primitive senses (precomputed per primitive
in the lattice, tiled to the agent's cell) and pick by *utility per unit cost* (the
budget is spent in cost units, so this is the budget-efficient ratio):

=============  =====  =================================================================
planner        depth  utility of a sensed cell (``b`` belief, ``c`` covered)
=============  =====  =================================================================
greedy         1      thesis: ``I(q) = f1*b + f2*H(b)`` (revisits count again)
dp             2      expected information gain of the sequence (receding horizon:
                      execute the first primitive, replan)
cmaes          5      the same information gain; CMA-ES (``cmaes`` package) over the
                      sequence, executed open-loop for 5 primitives, then replanned
coverage       2      1 for a cell neither covered nor sensed earlier in the sequence
prio_coverage  2      ``eps + b`` for such a cell (coverage prioritised by belief)
detect         2      expected *new detections* of the sequence (``env.plan_detect_gain``,
                      overlap exact as for ``dp``; ``+ info_weight x`` the information
                      gain if set, default 0), budget-aware (below): not a thesis
                      baseline; the teacher of the learned planner's warm start (train.py)
=============  =====  =================================================================

Budget-aware scoring (``PlannerConfig.budget_aware``; default on for ``detect`` only):
the primitive that crosses the end of the budget is executed in full but charged only
the remainder, and primitives after it never happen, so a sequence scores
``utility of the primitives started with budget left / min(cost, remaining budget)``.
The thesis baselines divide by the full cost (``--budget-aware`` turns it on for them).

Information gain of a cell sensed with total log-odds magnitude ``lam`` (the sum of
``log((1-e)/e)`` over its measurements) is computed as for one measurement with error
``sigma(-lam)``: ``IG = H(b) - E_z H(b | z)`` with ``P(z=1) = b(1-e) + (1-b)e``.
Overlap inside a sequence is exact: a cell sensed again later adds
``IG(b, lam_prev + lam) - IG(b, lam_prev)``.

When every candidate scores zero (nothing new in reach: coverage planners late in an
episode), the planner heads for the nearest uncovered cell instead (distance
transform), so it never dithers.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import distance_transform_edt

from aerohrl.config import param, validate


from .env import SearchEnv
from .scoring import info_gain  # noqa: F401  (re-exported: tests, features' docs)

PLANNERS = ("greedy", "dp", "cmaes", "coverage", "prio_coverage")  # thesis Table 2.1
TEACHERS = ("detect",)  # training-time teachers; `ipp bench --planner detect`, not in --all
THESIS_NAMES = {
    "greedy": "Greedy-IPP",
    "dp": "DP-IPP",
    "cmaes": "CMAES-IPP",
    "coverage": "Coverage",
    "prio_coverage": "Prioritised Coverage",
    # learned rows are named by policy.describe_policy (what trained them);
    # these two are the thesis's own names, for its columns only
    "rl_nolstm": "Ours-noLSTM (thesis)",
    "rl": "Ours-LSTM (thesis)",
    "detect": "Detection tree (teacher)",
}


@dataclass(frozen=True)
class PlannerConfig:
    """Planner knobs (CLI flags of ``ipp bench``)."""

    depth: int | None = param(None, "tree depth in primitives (none: the planner's own)", ge=1)
    f1: float = param(1.0, "greedy: weight of belief", ge=0)
    f2: float = param(1.0, "greedy: weight of entropy", ge=0)
    eps: float = param(0.05, "prioritised coverage: floor weight of a new cell", ge=0)
    horizon: int = param(5, "CMA-ES sequence length in primitives (thesis: 5)", ge=1)
    popsize: int = param(12, "CMA-ES population", ge=2)
    generations: int = param(15, "CMA-ES generations per replan", ge=1)
    sigma0: float = param(0.3, "CMA-ES initial step size on [0, 1]^horizon", gt=0)
    max_nodes: int = param(2_000_000, "memory bound per chunk for dense overlap maps", ge=1)
    budget_aware: bool | None = param(None, "tree planners score by min(cost, remaining budget) (none: detect only)")
    scoring: str = param(
        "ratio", "utility per unit cost, or utility - w * cost (the original's form)", choices=("ratio", "additive")
    )
    cost_weight: float = param(
        0.0, "additive scoring: w per cost unit (0: utility alone, as the original's coverage planners)", ge=0
    )
    prio_revisit: bool = param(
        True,
        "prioritised coverage scores the belief mass of every sensed cell, covered or not (the original); false: new cells only",
    )
    info_weight: float = param(
        0.0,
        "detect: + this x the expected information gain (bits) of the sensed cells, "
        "a value for cells one pass cannot confirm (0: detections alone)",
        ge=0,
    )
    cmaes_tol: float = param(
        0.0,
        "CMA-ES: stop an environment's search when the std of its generation-best "
        "score over the last 10 generations is <= tol * |mean| (the original: absolute "
        "std < 0.1 in its reward units); 0: run every generation",
        ge=0,
    )

    def validate(self) -> None:
        """ValueError (one line, naming the setting) for a setting out of its declared
        range or choices (:func:`aerohrl.config.validate`)."""
        validate(self)


def sequence_score(util: np.ndarray, cost: np.ndarray, cfg: "PlannerConfig") -> np.ndarray:
    """Score of primitive sequences from their summed utility and cost (batched).

    ``ratio`` (default): ``util / cost``, utility per unit of budget. ``additive``:
    ``util - w * cost`` (the original code's form: its coverage planners maximise the
    summed utility alone, ``w = 0``; its greedy planner subtracts the cost)."""
    if cfg.scoring == "additive":
        return util - cfg.cost_weight * cost
    return util / cost


class Planner:
    name = "planner"

    def __init__(self, env: SearchEnv, cfg: PlannerConfig | None = None):
        self.env, self.cfg = env, cfg or PlannerConfig()
        self.cfg.validate()

    def reset(self) -> None:
        """Forget any per-episode state (a new episode starts)."""
        pass

    def act(self) -> np.ndarray:  # (N,) action slots
        """One action slot per environment (N,) int for the current state."""
        raise NotImplementedError


class TreePlanner(Planner):
    """Exhaustive search over primitive sequences of length ``depth`` (batched)."""

    def __init__(self, env, cfg=None, kind="info", depth=2, budget_aware=False):
        super().__init__(env, cfg)
        self.kind = kind
        # budget-aware scoring: a primitive started with budget left is executed in full
        # but charged only the remainder; later ones never happen. Off for the thesis
        # baselines (their score is utility / full cost), on for the detect teacher.
        self.budget_aware = bool(budget_aware if self.cfg.budget_aware is None else self.cfg.budget_aware)
        self.depth = int(depth if self.cfg.depth is None else self.cfg.depth)
        if not 1 <= self.depth <= 4:
            raise ValueError(f"planner depth must be in 1..4, got {self.depth}")
        self.name = kind

    # utility of cells: b belief, c covered, lp previous lam in sequence, lam this prim
    def _util(self, b, c, lp, lam):
        env = self.env
        if self.kind == "detect":
            g = env.plan_detect_gain(b, lp, lam)
            if self.cfg.info_weight > 0:
                g = g + self.cfg.info_weight * self._ig_gain(b, lp, lam)
            return g
        if self.kind == "info":
            return self._ig_gain(b, lp, lam)
        new = (~c) & (lp == 0)
        if self.kind == "coverage":
            return new.astype(float)
        if self.kind == "prio":
            if self.cfg.prio_revisit:  # the original: belief mass of every sensed cell (once
                # per sequence), covered or not, so likely targets are revisited and confirmed
                return (lp == 0) * env.plan_prio(b) + self.cfg.eps * new
            return new * (self.cfg.eps + env.plan_prio(b))
        if self.kind == "greedy":
            return self.cfg.f1 * env.plan_prio(b) + self.cfg.f2 * env.plan_entropy(b)
        raise ValueError(f"unknown utility {self.kind!r}")

    def _ig_gain(self, b, lp, lam):
        """Information gain of sensing with ``lam`` more after ``lp`` earlier in the sequence."""
        g = self.env.plan_ig(b, lp + lam)
        seen = lp > 0
        if seen.any():
            g[seen] -= self.env.plan_ig(b[seen], lp[seen])
        return g

    def act(self) -> np.ndarray:
        """One action slot per live environment (N,): the first primitive of the best sequence of
        length ``depth`` (exhaustive, batched)."""
        env = self.env
        N = env.n
        out = np.zeros(N, np.int64)
        A = env.lat.n_actions
        lat = env.lat
        W = 2 * self._window_radius() + 1
        C = getattr(env, "n_classes", 1)
        per_env = A ** max(self.depth - 1, 0) * max(W * W, A * lat.cell_off.shape[1] * C)
        chunk = max(1, int(self.cfg.max_nodes // max(per_env, 1)))
        live = np.flatnonzero(~env.done)
        if self._fast() and len(live):  # semantic detect tree: the features' fast path
            from .features import semantic_fast

            first = semantic_fast(env)[1][live]
            best = first.argmax(1)
            flat_zero = ~(first.max(1) > 1e-9)
            if flat_zero.any():
                best[flat_zero] = self._frontier(live[flat_zero])
            out[live] = best
            return out
        for s in range(0, len(live), chunk):
            idx = live[s : s + chunk]
            out[idx] = self._plan(idx)
        return out

    def _fast(self) -> bool:
        """The depth-2 budget-aware detection tree on semantic worlds scores exactly what
        feature 14 computes (:func:`aerohrl.ipp.features.semantic_fast`, sparse products
        on a window instead of the (slot, slot, cell, class) arrays; same values up to
        float rounding, a test checks): use it (75 -> ~2 ms per decision)."""
        if not (self.kind == "detect" and self.depth == 2 and self.budget_aware and self.cfg.info_weight == 0 and self.use_fast):
            return False
        from .features import fast_path_applies

        return fast_path_applies(self.env)

    use_fast = True  # False: always the generic tree search (tests compare the two)

    def _window_radius(self) -> int:
        """Cells sensed by the first ``depth-1`` primitives lie within this Chebyshev
        radius of the agent: the overlap maps only need that window, not the map."""
        lat = self.env.lat
        return int((self.depth - 1) * np.abs(lat.prim_disp).max() + np.abs(lat.cell_off).max() + 1)

    def _plan(self, idx: np.ndarray) -> np.ndarray:
        env, lat = self.env, self.env.lat
        A, Hp, S = lat.n_actions, env.Hp, env.S
        n = len(idx)
        Rw = self._window_radius()
        Wn = 2 * Rw + 1
        x0 = env.pos[idx, 0][:, None, None, None]
        y0 = env.pos[idx, 1][:, None, None, None]
        c_all = env.cov[idx].reshape(n, -1)
        lamv = env.lam_levels
        # node state: (n, K) with K = A^k
        pos = env.pos[idx][:, None, :].copy()
        vert = env.vert[idx][:, None].copy()
        alive = np.ones((n, 1), bool)
        util = np.zeros((n, 1))
        cost = np.zeros((n, 1))
        lmap = None  # (n, K, Hp*Hp) lam already sensed by the sequence
        rows = np.arange(n)[:, None, None, None]
        for k in range(self.depth):
            K = pos.shape[1]
            ok = env.ok[vert, :, np.clip(pos[..., 1], 0, S - 1), np.clip(pos[..., 0], 0, S - 1)]
            ok &= alive[..., None]  # (n, K, A)
            prim = lat.edges[vert]  # (n, K, A)
            pr = np.maximum(prim, 0)
            off = lat.cell_off[pr].astype(np.int64)  # (n, K, A, U, 2)
            cnt = lat.cell_count[pr].astype(float)  # (n, K, A, U, L)
            lam = cnt @ lamv  # (n, K, A, U)
            x = pos[..., 0][:, :, None, None] + off[..., 0]
            y = pos[..., 1][:, :, None, None] + off[..., 1]
            inside = (x >= 0) & (x < S) & (y >= 0) & (y < S) & (cnt.sum(-1) > 0)
            flat = np.clip(y + env.pad, 0, Hp - 1) * Hp + np.clip(x + env.pad, 0, Hp - 1)
            # window-local index of each cell (the overlap maps live on the window)
            wl = np.clip(y - y0 + Rw, 0, Wn - 1) * Wn + np.clip(x - x0 + Rw, 0, Wn - 1)
            c = c_all[rows, flat]
            if lmap is None:
                lp = np.zeros_like(lam)
            else:
                lp = lmap[np.arange(n)[:, None, None, None], np.arange(K)[None, :, None, None], wl]
            uc = np.zeros(lam.shape)
            b_in = None if self.kind == "coverage" else env.plan_cells(idx[np.nonzero(inside)[0]], flat[inside])
            uc[inside] = self._util(b_in, c[inside], lp[inside], lam[inside])
            u = uc.sum(-1)  # (n, K, A)
            if self.budget_aware:  # steps that start after the budget is spent count 0
                u = u * (cost < env.remaining[idx, None])[..., None]
            util = (util[..., None] + u).reshape(n, K * A)
            cost = (cost[..., None] + lat.prim_cost[pr]).reshape(n, K * A)
            alive = ok.reshape(n, K * A)
            if k + 1 < self.depth:
                w = np.where(inside, lam, 0.0)
                ii = np.arange(n * K * A)[:, None] * (Wn * Wn) + wl.reshape(n * K * A, -1)
                nl = np.bincount(ii.ravel(), weights=w.reshape(-1), minlength=n * K * A * Wn * Wn).reshape(n, K, A, Wn * Wn)
                if lmap is not None:
                    nl += lmap[:, :, None, :]
                lmap = nl.reshape(n, K * A, Wn * Wn)
            pos = (pos[:, :, None, :] + lat.prim_disp[pr]).reshape(n, K * A, 2)
            vert = lat.prim_to[pr].reshape(n, K * A)
        if self.budget_aware:
            cost = np.minimum(cost, env.remaining[idx, None])
        score = np.where(alive, sequence_score(util, cost, self.cfg), -np.inf)
        first = score.reshape(n, A, -1).max(-1)  # best continuation per first action
        best = first.argmax(1)
        flat_zero = ~(first.max(1) > 1e-9)
        if flat_zero.any():  # nothing to gain in reach: go to the nearest uncovered cell
            best[flat_zero] = self._frontier(idx[flat_zero])
        return best

    def _frontier(self, idx: np.ndarray) -> np.ndarray:
        env, lat = self.env, self.env.lat
        S, p = env.S, env.pad
        out = np.zeros(len(idx), np.int64)
        for j, n in enumerate(idx):  # one distance transform per env (not per cell)
            unc = ~env.cov[n, p : p + S, p : p + S]
            okm = env.ok[env.vert[n], :, env.pos[n, 1], env.pos[n, 0]]
            if not unc.any():
                out[j] = int(np.argmax(okm))
                continue
            dist = distance_transform_edt(~unc)
            prim = np.maximum(lat.edges[env.vert[n]], 0)
            end = env.pos[n] + lat.prim_disp[prim]
            d = dist[np.clip(end[:, 1], 0, S - 1), np.clip(end[:, 0], 0, S - 1)]
            d = d + 1e-3 * lat.prim_cost[prim] / lat.prim_cost.mean()
            out[j] = int(np.argmin(np.where(okm, d, np.inf)))
        return out


class CMAESPlanner(Planner):
    """CMA-ES over ``horizon``-primitive sequences (``cmaes.CMA``), open-loop execution.

    A candidate ``x in [0,1]^h`` decodes step by step: at each state the valid actions
    are listed in slot order and ``x_k`` picks ``floor(x_k * n_valid)``; decoding never
    leaves the viable set. The best sequence seen over the generations is executed
    (the original code returned a fresh sample; that bug is not reproduced).
    """

    name = "cmaes"

    def __init__(self, env, cfg=None):
        super().__init__(env, cfg)
        try:
            import cmaes  # noqa: F401
        except ImportError:
            raise ValueError("planner cmaes needs the 'cmaes' package (pip install cmaes)") from None
        self.reset()

    def reset(self) -> None:
        """Empty the per-environment action queues and replan counters."""
        self.queue = np.full((self.env.n, 0), -1, np.int64)
        self.replans = np.zeros(self.env.n, np.int64)  # per env: seeds do not depend on the batch

    def _decode(self, X: np.ndarray, env_idx: np.ndarray):
        """X (C, h) -> actions (C, h), info utility (C,), cost (C,) for envs env_idx (C,)."""
        env, lat = self.env, self.env.lat
        C, h = X.shape
        S, Hp = env.S, env.Hp
        pos = env.pos[env_idx].copy()
        vert = env.vert[env_idx].copy()
        acts = np.zeros((C, h), np.int64)
        flats, lams = [], []
        cost = np.zeros(C)
        for k in range(h):
            ok = env.ok[vert, :, pos[:, 1], pos[:, 0]]  # (C, A)
            nv = ok.sum(1)
            pick = np.minimum((X[:, k] * nv).astype(np.int64), np.maximum(nv - 1, 0))
            csum = np.cumsum(ok, 1)
            a = np.argmax(csum > pick[:, None], axis=1)
            acts[:, k] = a
            pr = lat.edges[vert, a]
            off = lat.cell_off[pr].astype(np.int64)
            cnt = lat.cell_count[pr].astype(float)
            x = pos[:, 0, None] + off[..., 0]
            y = pos[:, 1, None] + off[..., 1]
            inside = (x >= 0) & (x < S) & (y >= 0) & (y < S) & (cnt.sum(-1) > 0)
            flats.append(np.arange(C)[:, None] * Hp * Hp + (y + env.pad) * Hp + x + env.pad)
            lams.append(np.where(inside, cnt @ env.lam_levels, 0.0))
            cost += lat.prim_cost[pr]
            pos = pos + lat.prim_disp[pr]
            vert = lat.prim_to[pr]
        f = np.concatenate(flats, 1).ravel()
        w = np.concatenate(lams, 1).ravel()
        # total lam per (candidate, cell), sparse: memory ~ measurements, not map size
        cells, inv = np.unique(f, return_inverse=True)
        tot = np.bincount(inv, weights=w, minlength=len(cells))
        keep = tot > 0
        cells, tot = cells[keep], tot[keep]
        cand = cells // (Hp * Hp)
        b = env.plan_cells(env_idx[cand], cells % (Hp * Hp))
        util = np.bincount(cand, weights=env.plan_ig(b, tot), minlength=C)
        return acts, util, cost

    def act(self) -> np.ndarray:
        """One action slot per environment (N,): the next slot of its CMA-ES-optimised
        sequence, replanned when the queue runs out."""
        from cmaes import CMA

        env, cfg = self.env, self.cfg
        if self.queue.shape[0] != env.n:
            self.reset()
        need = np.flatnonzero(~env.done & (self.queue[:, 0] < 0 if self.queue.shape[1] else True))
        if len(need):
            h = cfg.horizon
            newq = np.full((env.n, h), -1, np.int64)
            newq[:, : self.queue.shape[1]] = self.queue[:, :h] if self.queue.shape[1] else -1
            opts = []
            for n in need:
                self.replans[n] += 1
                opts.append(
                    CMA(
                        mean=np.full(h, 0.5),
                        sigma=cfg.sigma0,
                        bounds=np.tile([0.0, 1.0], (h, 1)),
                        population_size=cfg.popsize,
                        seed=int(env.worlds.seeds[n, 1] * 7919 + self.replans[n]),
                    )
                )
            best_f = np.full(len(need), np.inf)
            best_a = np.zeros((len(need), h), np.int64)
            P = cfg.popsize
            hist = np.zeros((0, len(need)))
            active = np.ones(len(need), bool)  # envs whose search has not settled
            self.evaluations = getattr(self, "evaluations", 0)
            self.generations_run = getattr(self, "generations_run", 0)
            for _ in range(cfg.generations):
                act_j = np.flatnonzero(active)
                X = np.array([[opts[j].ask() for _ in range(P)] for j in act_j])  # (E, P, h)
                acts, util, cost = self._decode(X.reshape(-1, h), np.repeat(need[act_j], P))
                self.evaluations += X.shape[0] * P
                self.generations_run += len(act_j)
                f = (-sequence_score(util, cost, cfg)).reshape(len(act_j), P)
                for r, j in enumerate(act_j):
                    opts[j].tell(list(zip(X[r], f[r])))
                k = f.argmin(1)
                fk = f[np.arange(len(act_j)), k]
                better = fk < best_f[act_j]
                best_f[act_j[better]] = fk[better]
                best_a[act_j[better]] = acts.reshape(len(act_j), P, h)[np.arange(len(act_j)), k][better]
                gen_best = np.full(len(need), np.nan)
                gen_best[act_j] = fk
                hist = np.vstack([hist, gen_best])
                if cfg.cmaes_tol > 0 and len(hist) >= 10:
                    # the original's stop (std of the generation's best over the last 10
                    # generations), relative to its magnitude: our scores are per cost unit
                    w = hist[-10:]
                    with np.errstate(invalid="ignore"):
                        settled = np.std(w, 0) <= cfg.cmaes_tol * np.abs(np.mean(w, 0))
                    active &= ~settled
                    if not active.any():
                        break
            newq[need] = best_a
            self.queue = newq
        a = np.where(self.queue[:, 0] >= 0, self.queue[:, 0], 0)
        self.queue = np.concatenate([self.queue[:, 1:], np.full((env.n, 1), -1)], 1)
        return a


def make_planner(name: str, env: SearchEnv, cfg: PlannerConfig | None = None) -> Planner:
    """Planner by name (see :data:`PLANNERS`); unknown names raise ValueError."""
    cfg = cfg or PlannerConfig()
    p: Planner
    if name == "greedy":
        p = TreePlanner(env, cfg, "greedy", 1)
    elif name == "dp":
        p = TreePlanner(env, cfg, "info", 2)
    elif name == "coverage":
        p = TreePlanner(env, cfg, "coverage", 2)
    elif name == "prio_coverage":
        p = TreePlanner(env, cfg, "prio", 2)
    elif name == "detect":
        p = TreePlanner(env, cfg, "detect", 2, budget_aware=True)
    elif name == "cmaes":
        p = CMAESPlanner(env, cfg)
    else:
        raise ValueError(f"unknown planner {name!r} (choose from {', '.join(PLANNERS + TEACHERS)})")
    p.name = name
    return p
