"""Batched target-search environment on a motion-primitive lattice (thesis §2.4-2.5.2).

``N`` environments live in arrays: log-odds belief, coverage and truth maps of shape
``(N, Hp, Wp)`` (the ``map_size`` square padded by ``pad`` cells on every side so that
footprints and observation windows never index out of range). A step gathers the
precomputed measurement list of each chosen primitive, shifted to the agent's cell
(translation invariance), draws the labels, and scatters the log-odds increments with
one ``np.bincount``: no per-cell Python loop.

Rewards (thesis §2.5.2, docs/spec.md), per step, as columns of ``terms``:

* ``entropy``  ``15 * (H(M_t) - H(M_{t+1})) / H(M_0)`` (Eq. 2.4-2.5, inner map, bits);
  sums to ``15 * entropy reduction``: +15 for the whole map.
* ``coverage`` ``10 * (newly covered cells) / (H*W)``: +10 for the whole map.
* ``target``   ``+20`` per target whose cell belief first reaches ``found_threshold``.
* ``cost``     ``-20 * min(cost, remaining) / budget``: exactly -20 over a full budget.
* ``invalid``  ``-1`` for an invalid primitive (the agent stays; the cost is charged).

The episode ends when the budget is spent (the primitive that crosses zero is
executed in full; its charge is capped so the cost term sums to -20).

Valid primitives: the footprint centre stays on the inner map along the whole
primitive *and* the end state is viable, i.e. lies in the viability kernel of the
lattice on this map (a valid successor exists forever). The kernel is a fixed point
computed once per (lattice, map size); it removes the dead ends a fast vertex near
the boundary would otherwise run into. (The thesis/original code only penalise
leaving the map; see :func:`viability`.)
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np

from aerohrl.config import param, section, validate

from .lattice import Lattice
from .scoring import detect_prob, info_gain
from .sensor import SensorConfig, entropy_bits, hashed_uniform, logit, logodds_step, measure, sigmoid
from .semantic import SemanticConfig
from .world import WorldConfig, Worlds

TERMS = ("entropy", "coverage", "target", "cost", "invalid")

PAD_ORIG = 5  # the original code's padding per side: 30 x 30 inner map in a 40 x 40 world
H_PAD = 0.0  # entropy (bits) of that padding ring there: belief 0 -> 0 bits

# Budgets in primitive-cost units (rho*T + int |jerk|^2 of our lattice). The default buys
# the original code's *ground track*: its budget (paper-era commit 0d6a531, 10 x 10000 of
# its own cost units) flies about 72 primitives, 224 cells of path and 267 s; 9250 of ours
# flies ~224 cells in ~47 primitives and ~88 s (our primitives are faster: ~2.5 vs ~0.8
# cells/s). Measured by ``ipp bench --budgets`` (ipp/README.md). TIGHT is the earlier
# default (about 20-26 primitives, ~120 cells, ~48 s).
BUDGET_DEFAULT = 9250.0
BUDGET_TIGHT = 5000.0
BUDGETS = {"default": BUDGET_DEFAULT, "tight": BUDGET_TIGHT}


@dataclass(frozen=True)
class EnvConfig:
    """Environment parameters; ``budget`` is in primitive-cost units."""

    map_size: int = param(30, "map side", unit="cells", ge=1, le=512)
    budget: float = param(
        BUDGET_DEFAULT, "cost budget (sum of rho*T + int |jerk|^2 over the primitives flown)", unit="primitive-cost units", gt=0
    )
    found_threshold: float = param(0.95, "a target is found when its cell's belief first reaches this", gt=0.5, lt=1)
    start: str = param("center", "start cell: the centre, or a random valid, viable hover start", choices=("center", "random"))
    r_entropy: float = param(15.0, "reward for the whole map's entropy reduction", ge=0)
    r_coverage: float = param(10.0, "reward for covering the whole map", ge=0)
    r_target: float = param(20.0, "reward per target found", ge=0)
    r_cost: float = param(20.0, "penalty for spending the whole budget", ge=0)
    r_invalid: float = param(1.0, "penalty per invalid primitive", ge=0)
    obs_radius: int = param(4, "observation windows are 2R x 2R cells at each scale: R", unit="cells", ge=1)
    obs_scales: tuple[int, ...] = param((1, 2, 4), "pooling factor of each observation window", ge=1)
    sensor: SensorConfig = section(SensorConfig, "the downward camera's errors")
    world: WorldConfig = section(WorldConfig, "target worlds (kind targets)")
    kind: str = param(
        "targets", "target search (Table 2.1) or semantic feature detection (Table 2.2)", choices=("targets", "semantic")
    )
    semantic: SemanticConfig = section(SemanticConfig, "semantic worlds (kind semantic)")

    def validate(self, lattice: Lattice) -> None:
        """ValueError (one line) for a setting out of its declared range
        (:func:`aerohrl.config.validate`), a map the lattice's footprint does not fit, a
        budget that cannot pay for the cheapest primitive, or a world whose map size
        differs from ``map_size``."""
        validate(self)
        if self.map_size < 2 * lattice.config.footprint_radius + 2:
            raise ValueError(
                f"map size {self.map_size} is too small for the lattice (needs >= {2 * lattice.config.footprint_radius + 2})"
            )
        if self.budget < lattice.prim_cost.min():
            raise ValueError(
                f"budget {self.budget:g} cannot pay for a single primitive (cheapest costs {lattice.prim_cost.min():.1f})"
            )
        if self.kind == "targets" and self.world.map_size != self.map_size:
            raise ValueError("world.map_size must equal map_size")
        if self.kind == "semantic" and self.semantic.map_size != self.map_size:
            raise ValueError("semantic.map_size must equal map_size")


def viability(lattice: Lattice, size: int) -> np.ndarray:
    """``ok[v, a, y, x]``: action ``a`` at vertex ``v`` in cell ``(x, y)`` is valid.

    Valid = the primitive exists, its visited centre cells stay on the ``size`` map
    (bounding box test) and its end state is viable. The viable set is the greatest
    fixed point of ``viable[v,y,x] = any_a ok[v,a,y,x]`` (vectorised over cells).
    """
    return _viability(
        lattice.edges.tobytes(),
        lattice.edges.shape,
        lattice.prim_bbox.tobytes(),
        lattice.prim_disp.tobytes(),
        lattice.prim_to.tobytes(),
        size,
    ).copy()


@lru_cache(maxsize=8)
def _viability(edges_b, eshape, bbox_b, disp_b, to_b, size):
    edges = np.frombuffer(edges_b, np.int32).reshape(eshape)
    P = len(np.frombuffer(to_b, np.int32))
    bbox = np.frombuffer(bbox_b, np.int32).reshape(P, 4)
    disp = np.frombuffer(disp_b, np.int32).reshape(P, 2)
    to = np.frombuffer(to_b, np.int32)
    V, A = edges.shape
    g = np.arange(size)
    X, Y = np.meshgrid(g, g, indexing="xy")  # (H, W)
    e = np.maximum(edges, 0)
    exists = (edges >= 0)[:, :, None, None]
    bb = bbox[e]  # (V, A, 4)
    inb = (
        (X + bb[..., 0, None, None] >= 0)
        & (X + bb[..., 1, None, None] < size)
        & (Y + bb[..., 2, None, None] >= 0)
        & (Y + bb[..., 3, None, None] < size)
    ) & exists
    ex = np.clip(X + disp[e][..., 0, None, None], 0, size - 1)
    ey = np.clip(Y + disp[e][..., 1, None, None], 0, size - 1)
    tv = np.broadcast_to(to[e][..., None, None], ex.shape)
    viable = np.ones((V, size, size), bool)
    while True:
        ok = inb & viable[tv, ey, ex]
        new = ok.any(axis=1)
        if np.array_equal(new, viable):
            return ok
        viable = new


class SearchEnv:
    """``N`` target-search environments stepped together (arrays, no per-cell loops)."""

    # (state key, features) of the last fast_features call, set there
    _fast_cache: tuple
    # a learned belief (aerohrl.ipp.belief.BeliefModel) whose prediction replaces the
    # hand-written posterior plane of observe(); None: the posterior (set by a policy that
    # was trained to observe it, and by `ipp train --belief-input`)
    obs_belief: Any = None

    def __init__(self, cfg: EnvConfig, lattice: Lattice):
        cfg.validate(lattice)
        self.cfg, self.lat = cfg, lattice
        S = cfg.map_size
        r = lattice.config.footprint_radius
        reach = int(np.abs(lattice.meas_off).max()) if lattice.n_prims else r
        self.pad = int(max(cfg.obs_radius * max(cfg.obs_scales), reach + 1, r + 1))
        self.S, self.Hp = S, S + 2 * self.pad
        self.ok = viability(lattice, S)  # (V, A, S, S)
        e = cfg.sensor.error_levels(lattice.n_levels)
        self.err_levels = e
        self.lam_levels = logodds_step(e)
        inner = np.zeros((self.Hp, self.Hp), bool)
        inner[self.pad : self.pad + S, self.pad : self.pad + S] = True
        self.inner = inner
        self.boundary = (~inner).astype(np.float32)
        self.n = 0
        self.lazy_obs = False  # True: step() returns obs=None (planners that do not need it)
        self.keep_trace = True  # per-step path records (figures); off in the Gymnasium wrapper
        self.version = 0  # bumped by reset() and step(): caches of derived quantities key on it

    # ----------------------------------------------------------------- set-up
    def reset(self, worlds: Worlds, start: np.ndarray | None = None) -> dict:
        """Start one episode per world. ``start``: (N, 2) cells (x, y), else per config."""
        cfg, S, p = self.cfg, self.S, self.pad
        N = len(worlds)
        self.n, self.worlds = N, worlds
        sl = (slice(None), slice(p, p + S), slice(p, p + S))
        self.truth = np.zeros((N, self.Hp, self.Hp), bool)
        self.truth[sl] = worlds.targets
        self.L = np.full((N, self.Hp, self.Hp), -cfg.sensor.logodds_clip)
        self.L[sl] = logit(worlds.prior)
        self.cov = np.zeros((N, self.Hp, self.Hp), bool)
        self.cov_ring = np.zeros((N, self.Hp, self.Hp), bool)  # sensed cells off the map
        self.found = np.zeros((N, self.Hp, self.Hp), bool)
        # observation planes kept up to date incrementally: belief (0 off the map),
        # coverage, boundary; float32 (N, 3, Hp, Hp)
        self.planes = np.zeros((N, 3, self.Hp, self.Hp), np.float32)
        self.planes[:, 0][sl] = worlds.prior
        self.planes[:, 2] = self.boundary
        self._common_reset(worlds, start)
        self.n_targets = worlds.targets.reshape(N, -1).sum(1)
        return self.observe()

    def reset_rows(self, rows: np.ndarray, worlds: Worlds, start: np.ndarray | None = None) -> None:
        """Start new episodes in environments ``rows`` only (the others keep running):
        the rows of every per-environment array are replaced by those of a fresh batch
        reset on ``worlds`` (target search). Traces are not kept per row (the Gymnasium
        wrapper runs with ``keep_trace = False``)."""
        rows = np.asarray(rows, np.int64)
        if len(rows) != len(worlds):
            raise ValueError("reset_rows: one world per row")
        fresh = SearchEnv(self.cfg, self.lat)
        fresh.keep_trace = False
        fresh.reset(worlds, start)
        N, k = self.n, len(rows)
        for name, val in vars(fresh).items():
            cur = getattr(self, name, None)
            if (
                isinstance(val, np.ndarray)
                and isinstance(cur, np.ndarray)
                and val.ndim
                and val.shape[0] == k
                and cur.shape[0] == N
                and cur.shape[1:] == val.shape[1:]
            ):
                cur[rows] = val
        w = self.worlds
        for f in ("density", "targets", "prior", "kl", "kl_sym", "seeds"):
            getattr(w, f)[rows] = getattr(worlds, f)
        self.version += 1

    def _common_reset(self, worlds, start) -> None:
        """Start cells, lattice state, budget, entropy, counters (both env kinds)."""
        cfg, S, N = self.cfg, self.S, self.n
        if start is None:
            if cfg.start == "center":
                start = np.full((N, 2), S // 2)
            else:
                viable0 = np.argwhere(self.ok[0].any(axis=0))  # (k, 2) as (y, x)
                h = hashed_uniform(worlds.seeds[:, 0], worlds.seeds[:, 1], 7)
                pick = viable0[(h * len(viable0)).astype(int)]
                start = pick[:, ::-1]
        self.pos = np.asarray(start, np.int64).reshape(N, 2).copy()
        if not self.ok[0][:, self.pos[:, 1], self.pos[:, 0]].any(axis=0).all():
            raise ValueError("a start cell has no valid primitive on this map")
        self.vert = np.zeros(N, np.int64)
        self.last_action = np.full(N, -1, np.int64)
        self.remaining = np.full(N, float(cfg.budget))
        self.steps = np.zeros(N, np.int64)
        self.done = np.zeros(N, bool)
        self.H0 = self._entropy()
        self.H = self.H0.copy()
        self.n_cov = np.zeros(N, np.int64)
        self.n_found = np.zeros(N, np.int64)
        # flight actually bought by the budget (valid primitives only; invalid ones stay)
        self.n_flown = np.zeros(N, np.int64)
        self.path_cells = np.zeros(N)
        self.flight_s = np.zeros(N)
        self.trace = [self.pos.copy()] if self.keep_trace else []
        self.trace_prim: list[np.ndarray] = []
        self.trace_budget = [self.remaining.copy()] if self.keep_trace else []
        self.version += 1
        self._seed_key = worlds.seeds[:, 0].astype(np.uint64) * np.uint64(1_000_003) + worlds.seeds[:, 1].astype(np.uint64)

    # ---------------------------------------------------------------- queries
    def belief(self) -> np.ndarray:
        """(N, S, S) current belief on the inner map."""
        p, S = self.pad, self.S
        return sigmoid(self.L[:, p : p + S, p : p + S])

    def _entropy(self) -> np.ndarray:
        return entropy_bits(self.belief()).reshape(self.n, -1).sum(1)

    def valid_mask(self) -> np.ndarray:
        """(N, A) bool: valid primitives at each agent's state (all False when done)."""
        m = self.ok[self.vert, :, self.pos[:, 1], self.pos[:, 0]]
        m[self.done] = False
        return m

    def flat_index(self, off: np.ndarray, idx: np.ndarray | None = None) -> np.ndarray:
        """Flat indices into (N, Hp, Wp) for offsets (n, ..., 2) from the agents' cells."""
        idx = np.arange(self.n) if idx is None else idx
        sh = (-1,) + (1,) * (off.ndim - 2)
        x = self.pos[idx, 0].reshape(sh) + self.pad + off[..., 0]
        y = self.pos[idx, 1].reshape(sh) + self.pad + off[..., 1]
        return (idx.reshape(sh) * self.Hp + y) * self.Hp + x

    def metrics(self) -> dict[str, np.ndarray]:
        """Thesis Table 2.1 metrics per environment, in %, over both denominators.

        * ``coverage``: covered cells / the inner ``S x S`` map (900 cells at S = 30);
          ``coverage_padded``: the same cells / the padded ``(S + 2*PAD_ORIG)^2`` map
          (1,600 cells), as the thesis and the original code (``env/Metrics.py``) divide;
          its numerator also counts footprint cells in the 5-cell ring around the map
          (the original's world holds them; the thesis's Coverage row, 62.2 % of 1,600
          = 995 cells, exceeds the 900 inner cells, so it must). Our sensor never
          *measures* off the map: the ring counts only for this column.
        * ``entropy_reduction`` = ``1 - H_T / H_0`` (Eq. 2.4) over the inner map;
          ``entropy_reduction_padded`` adds the padding ring's entropy to both sums, as
          the original does. Its padding holds belief 0 (entropy 0), so the two are equal
          by construction; the column is printed so that the match is visible.
        * ``search_efficiency`` = targets found / targets.
        * ``primitives``, ``path_cells`` (arc length, cells = m), ``flight_s``: the flight
          the budget bought (valid primitives executed).
        """
        p, S = self.pad, self.S
        ncov = self.cov[:, p : p + S, p : p + S].reshape(self.n, -1).sum(1)
        nring = self.cov_ring.reshape(self.n, -1).sum(1)
        Sp = S + 2 * PAD_ORIG
        er = 100.0 * (1.0 - self.H / self.H0)
        return {
            "coverage": 100.0 * ncov / (S * S),
            "coverage_padded": 100.0 * (ncov + nring) / (Sp * Sp),
            "entropy_reduction": er,
            "entropy_reduction_padded": 100.0 * (1.0 - (self.H + H_PAD) / (self.H0 + H_PAD)),
            "search_efficiency": 100.0 * self.n_found / np.maximum(self.n_targets, 1),
            "kl": self.worlds.kl.copy(),
            "steps": self.steps.copy(),
            "primitives": self.n_flown.copy(),
            "path_cells": self.path_cells.copy(),
            "flight_s": self.flight_s.copy(),
        }

    def action_features(self) -> np.ndarray:
        """(N, A, F) per-primitive look-ahead features (:mod:`.features`)."""
        from .features import action_features

        return action_features(self)

    # ------------------------------------------------------------------- step
    def step(self, actions: np.ndarray) -> tuple[dict[str, np.ndarray] | None, np.ndarray, np.ndarray, np.ndarray]:
        """Execute one primitive per environment. Returns (obs, reward, terms, done); ``obs``
        is None with ``lazy_obs``.

        ``actions`` (N,) int action slots; entries of finished environments are ignored.
        ``terms`` (N, 5) holds the reward terms in the order of :data:`TERMS`.
        """
        cfg, lat = self.cfg, self.lat
        a = np.asarray(actions, np.int64).reshape(self.n)
        terms = np.zeros((self.n, len(TERMS)))
        act = ~self.done
        if not act.any():
            return self.observe(), terms.sum(1), terms, self.done.copy()
        if np.any((a[act] < 0) | (a[act] >= lat.n_actions)):
            raise ValueError(f"action outside 0..{lat.n_actions - 1}")
        valid = self.valid_mask()[np.arange(self.n), np.clip(a, 0, lat.n_actions - 1)] & act
        prim = lat.edges[self.vert, np.clip(a, 0, lat.n_actions - 1)]
        inval = act & ~valid
        # cost (invalid: the primitive's cost, or the dearest one if the slot is empty)
        cost = np.where(prim >= 0, lat.prim_cost[np.maximum(prim, 0)], lat.prim_cost.max())
        charged = np.where(act, np.minimum(cost, self.remaining), 0.0)
        terms[:, 3] = -cfg.r_cost * charged / cfg.budget
        terms[:, 4] = -cfg.r_invalid * inval
        idx = np.flatnonzero(valid)
        if len(idx):
            pr = prim[idx]
            Hn, ncov, nf, rt = self._apply(idx, pr)
            self.pos[idx] += lat.prim_disp[pr]
            self.vert[idx] = lat.prim_to[pr]
            self.n_flown[idx] += 1
            self.path_cells[idx] += lat.prim_length[pr]
            self.flight_s[idx] += lat.prim_T[pr]
        else:
            Hn, ncov = self.H, self.n_cov
            nf, rt = np.zeros(self.n, np.int64), np.zeros(self.n)
        self.last_action[act] = a[act]
        self.remaining[act] -= cost[act]
        self.steps[act] += 1
        # rewards: entropy (Eq. 2.4-2.5), coverage, targets; zero where inactive
        terms[:, 0] = np.where(act, cfg.r_entropy * (self.H - Hn) / self.H0, 0.0)
        self.H = Hn
        terms[:, 1] = cfg.r_coverage * (ncov - self.n_cov) / (self.S * self.S)
        self.n_cov = ncov
        self.n_found += nf
        terms[:, 2] = rt
        # termination: budget spent, or (cannot happen from viable states) no valid move
        stuck = act & ~self.done & (self.remaining > 0) & ~self.valid_mask().any(1)
        if stuck.any():  # forfeit the rest of the budget so the cost term still sums to -20
            terms[stuck, 3] -= cfg.r_cost * self.remaining[stuck] / cfg.budget
            self.remaining[stuck] = 0.0
        self.done |= act & (self.remaining <= 1e-9 * cfg.budget)
        if self.keep_trace:
            self.trace.append(self.pos.copy())
            self.trace_prim.append(np.where(valid, prim, -1))
            self.trace_budget.append(np.maximum(self.remaining, 0.0))
        self.version += 1
        obs = None if self.lazy_obs else self.observe()
        return obs, terms.sum(1), terms, self.done.copy()

    def _apply(self, idx: np.ndarray, pr: np.ndarray):
        """Sense along primitives ``pr`` from the cells of envs ``idx`` and update the maps.

        Returns the new map entropy (N,), covered-cell counts (N,), newly found targets
        (N,) and the target reward (N,). Eq. 2.2 per touched cell, batched.
        """
        lat = self.lat
        return self._apply_meas(idx, lat.meas_off[pr].astype(np.int64), lat.meas_level[pr].astype(np.int64))

    def _apply_meas(self, idx: np.ndarray, off: np.ndarray, lev: np.ndarray):
        """:meth:`_apply` for explicit measurement lists: cell offsets ``off`` (k, M, 2)
        from the agents' cells and Chebyshev levels ``lev`` (k, M), -1 = none (the ideal
        primitives' lists, or those of a flown path, :mod:`.flown`)."""
        cfg = self.cfg
        flat = self.flat_index(off, idx)
        x = self.pos[idx, 0, None] + off[..., 0]
        y = self.pos[idx, 1, None] + off[..., 1]
        use = (lev >= 0) & (x >= 0) & (x < self.S) & (y >= 0) & (y < self.S)
        # the original's 40 x 40 world: footprint cells in its 5-cell ring count as covered
        # for the padded denominator (never measured here: off the map)
        ring = (lev >= 0) & ~use & (x >= -PAD_ORIG) & (x < self.S + PAD_ORIG) & (y >= -PAD_ORIG) & (y < self.S + PAD_ORIG)
        if ring.any():
            self.cov_ring.reshape(-1)[flat[ring]] = True
        levc = np.maximum(lev, 0)
        # noise keyed by the measurement itself, (footprint centre cell, footprint slot),
        # not by its place in the list: the same measurements draw the same labels
        # whichever list they come from (ideal primitive tables or a flown path, .flown)
        r = self.lat.config.footprint_radius
        F = (2 * r + 1) ** 2
        fidx = np.arange(lev.shape[1]) % F
        fx = fidx % (2 * r + 1) - r
        fy = fidx // (2 * r + 1) - r
        cx = x - fx[None, :] + 512
        cy = y - fy[None, :] + 512
        slot = (cy * 2048 + cx) * F + fidx[None, :]
        u = hashed_uniform(self._seed_key[idx, None], self.steps[idx, None], slot)
        z = measure(self.truth.ravel()[flat], self.err_levels[levc], u)
        dl = np.where(z, 1.0, -1.0) * self.lam_levels[levc]
        f, w = flat[use], dl[use]
        # Eq. 2.2 summed per touched cell; everything below touches only those cells
        cells, inv = np.unique(f, return_inverse=True)
        Lf = self.L.reshape(-1)
        old = Lf[cells]
        new = np.clip(old + np.bincount(inv, weights=w, minlength=len(cells)), -cfg.sensor.logodds_clip, cfg.sensor.logodds_clip)
        Lf[cells] = new
        env_of = cells // (self.Hp * self.Hp)
        dH = entropy_bits(sigmoid(new)) - entropy_bits(sigmoid(old))
        Hn = self.H + np.bincount(env_of, weights=dH, minlength=self.n)
        covf = self.cov.reshape(-1)
        newcov = ~covf[cells]
        covf[cells] = True
        ncov = self.n_cov + np.bincount(env_of[newcov], minlength=self.n)
        pl = self.planes.reshape(-1)
        pidx = env_of * (3 * self.Hp * self.Hp) + cells % (self.Hp * self.Hp)
        pl[pidx] = sigmoid(new)
        pl[pidx + self.Hp * self.Hp] = 1.0
        foundf = self.found.reshape(-1)
        hit = (new >= logit(cfg.found_threshold)) & self.truth.reshape(-1)[cells] & ~foundf[cells]
        foundf[cells[hit]] = True
        nf = np.bincount(env_of[hit], minlength=self.n)
        return Hn, ncov, nf, cfg.r_target * nf

    # ------------------------------------------------- planner hooks (baselines.py)
    def plan_cells(self, n_idx: np.ndarray, flat: np.ndarray) -> np.ndarray:
        """Belief at padded flat cell indices ``flat`` of envs ``n_idx`` (broadcast)."""
        return sigmoid(self.L.reshape(self.n, -1)[n_idx, flat])

    def plan_ig(self, b: np.ndarray, lam: np.ndarray) -> np.ndarray:
        """Expected information gain (bits) of sensing cells ``b`` with total ``lam``."""
        return info_gain(b, lam)

    def plan_prio(self, b: np.ndarray) -> np.ndarray:
        """Probability that the cell holds something of interest (a target)."""
        return b

    def plan_entropy(self, b: np.ndarray) -> np.ndarray:
        """The planner's entropy term: Shannon entropy (bits) of belief ``b`` per cell."""
        return entropy_bits(b)

    def prio_map(self) -> np.ndarray:
        """(N, Hp, Hp) float32 :meth:`plan_prio` of every cell (valid on the inner map)."""
        return self.planes[:, 0]

    def plan_detect(self, b: np.ndarray, lam: np.ndarray) -> np.ndarray:
        """P(the cell is a target and is detected) after sensing with ``lam`` (as one
        measurement with error ``sigma(-lam)``)."""
        return detect_prob(b, lam, self.cfg.found_threshold)

    def plan_open(self, b: np.ndarray) -> np.ndarray:
        """Cells the agent does not yet believe found (belief below the threshold)."""
        return b < self.cfg.found_threshold

    def plan_detect_gain(self, b: np.ndarray, lp: np.ndarray, lam: np.ndarray) -> np.ndarray:
        """Expected new detections of sensing cells (belief ``b``, already sensed with
        ``lp`` earlier in the sequence) with ``lam`` more: ``detect(b, lp + lam) -
        detect(b, lp)`` on cells not believed found, else 0 (the ``detect`` planner's
        utility and feature 14)."""
        g = self.plan_detect(b, lp + lam) - self.plan_detect(b, lp)
        return np.where(self.plan_open(b), g, 0.0)

    def plan_detect_gain_flat(self, gflat: np.ndarray, lp: np.ndarray, lam: np.ndarray) -> np.ndarray:
        """:meth:`plan_detect_gain` at flat indices into the ``(N, Hp, Hp)`` maps; reads
        the log-odds directly (no ``logit``): the hot path of feature 14."""
        L = self.L.reshape(-1)[gflat]
        thr = logit(self.cfg.found_threshold)
        lt = lp + lam
        et, ep = sigmoid(-lt), sigmoid(-lp)
        g = (1 - et) * (L + lt >= thr) + et * (L - lt >= thr) - (1 - ep) * (L + lp >= thr) - ep * (L - lp >= thr)
        return np.where(L < thr, sigmoid(L) * g, 0.0)

    # ----------------------------------------------------------- observations
    def observe(self) -> dict[str, np.ndarray]:
        """Egocentric multi-scale maps and the vector features (SPEC "Observations").

        ``maps`` (N, C*len(scales), 2R, 2R) float32: for each scale s the 2Rs x 2Rs
        window of the C planes (belief, coverage, boundary; semantic: one belief plane
        per class, coverage, boundary) around the agent, max-pooled by s; the belief plane
        is the learned belief's prediction with :attr:`obs_belief` set.
        ``vec`` (N, 2 + (A+1) + V + 1): position / map size, one-hot last action
        (slot A = none yet), one-hot lattice vertex, remaining budget fraction.
        """
        cfg, R = self.cfg, self.cfg.obs_radius
        smax = max(cfg.obs_scales)
        half = R * smax
        planes = self.planes
        if self.obs_belief is not None:  # the learned belief on the inner map, 0 off it as before
            p, S = self.pad, self.S
            planes = planes.copy()
            planes[:, 0, p : p + S, p : p + S] = self.obs_belief.predict(self)
        C = planes.shape[1]
        # the 2h x 2h window of every env: one rectangular slice each (a copy of whole
        # rows, much cheaper than a fancy-index gather on the 192-cell semantic windows)
        y0 = self.pos[:, 1] + self.pad - half
        x0 = self.pos[:, 0] + self.pad - half
        win = np.empty((self.n, C, 2 * half, 2 * half), np.float32)
        for n in range(self.n):
            win[n] = planes[n, :, y0[n] : y0[n] + 2 * half, x0[n] : x0[n] + 2 * half]
        outs = []
        for s in cfg.obs_scales:
            w = R * s
            crop = win[:, :, half - w : half + w, half - w : half + w]
            k = s
            while k > 1 and k % 2 == 0:  # max-pool by 2 repeatedly (composes exactly)
                crop = np.maximum(
                    np.maximum(crop[:, :, 0::2, 0::2], crop[:, :, 1::2, 0::2]),
                    np.maximum(crop[:, :, 0::2, 1::2], crop[:, :, 1::2, 1::2]),
                )
                k //= 2
            if k > 1:
                crop = crop.reshape(self.n, C, 2 * R, k, 2 * R, k).max(axis=5).max(axis=3)
            outs.append(crop)
        maps = np.ascontiguousarray(np.concatenate(outs, 1))
        A, V = self.lat.n_actions, self.lat.n_vertices
        vec = np.zeros((self.n, 2 + A + 1 + V + 1), np.float32)
        vec[:, :2] = self.pos / self.S
        la = np.where(self.last_action < 0, A, self.last_action)
        vec[np.arange(self.n), 2 + la] = 1
        vec[np.arange(self.n), 3 + A + self.vert] = 1
        vec[:, -1] = np.maximum(self.remaining, 0) / self.cfg.budget
        return {"maps": maps, "vec": vec, "valid": self.valid_mask()}


SEMANTIC_BUDGET = 30000.0  # about 200 primitives: a third of the map by coverage


def semantic_config(
    budget: float | None = None, raster: str | None = None, start: str = "center", map_size: int = 256
) -> EnvConfig:
    """The thesis's semantic setting (§2.5.2, §2.6.3): 256 x 256 cells of 4 m, C class
    maps; 48/96/192-cell egocentric windows pooled to 24 x 24 (scales 2, 4, 8); a
    15 x 15-cell (60 m) footprint whose label error grows 0.10 -> 0.45 from its centre
    to its edge (used with :data:`aerohrl.ipp.lattice.SEMANTIC_LATTICE`). The noise is
    high enough that one pass does not always identify a cell (revisits matter)."""
    return EnvConfig(
        kind="semantic",
        map_size=map_size,
        budget=SEMANTIC_BUDGET if budget is None else budget,
        start=start,
        obs_radius=12,
        obs_scales=(2, 4, 8),
        sensor=SensorConfig(err0=0.1, err_slope=0.05),
        world=WorldConfig(map_size=map_size),
        semantic=SemanticConfig(map_size=map_size, raster=raster),
    )
