"""Per-primitive look-ahead features for the learned planner (observation design).

The thesis's policy sees only egocentric map windows (§2.5.2 "Observations") and must
learn from them which of the ~20 primitives senses what. Here the policy additionally
gets, for every action slot, a short vector describing what that primitive would sense
from the agent's current state, computed from the agent's *belief* (never the truth)
with the same tiled sensing tables the baselines use (:mod:`.baselines`):

====  =====================================================================
0     expected information gain of the sensed cells, bits / footprint area
      (``IG(b, lam)`` of :func:`aerohrl.ipp.baselines.info_gain`)
1     expected detections: ``sum b * P(posterior >= threshold | target)`` over
      sensed cells not yet believed found (``env.plan_open``: belief below the
      threshold; one-measurement equivalent of ``lam``, as in
      :func:`info_gain`), / footprint area
2     belief mass of sensed cells not yet believed found, / footprint area
3     newly covered cells / footprint area
4     primitive cost / mean primitive cost
5-7   features 0, 1 and 3 per unit cost (x mean cost): the baselines' ratio
8     distance from the end cell to the nearest uncovered cell / map size
9     1 if the primitive is valid here
10    prioritised-coverage mass: ``sum (0.05 + b)`` over sensed, not yet covered
      cells, / footprint area (``b``: P(target), semantic: P(not background))
11    feature 10 per unit cost
12    two-step look-ahead: the best feature 11 over the valid primitives from this
      primitive's end state (overlap with this primitive ignored)
13    the same for newly covered cells per unit cost (feature 7)
14    exact two-step detection rate: ``max_a2 (D1 + D2) / (c1 + c2)`` over the valid
      second primitives, ``D`` the expected new detections
      (``env.plan_detect_gain``; the second primitive's cells that the first one
      sensed count with the first one's log-odds, as in the tree search) / footprint
      area x mean cost, budget-aware (``D2`` only if ``c1 <`` the remaining budget,
      costs capped at it): the score the ``detect`` tree planner maximises
15    feature 14 / its maximum over the valid slots (1 for the best slot)
====  =====================================================================

Invalid slots get zeros except feature 9. Everything is batched over environments,
actions and sensed cells (one ``distance_transform_edt`` call per environment).
The features are a pure function of the agent's state and belief, so the policy stays
a learned planner over the thesis's observation plus what a planner can read off its
own primitive library.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from scipy.ndimage import distance_transform_edt


N_FEAT = 16
EPS = 0.05  # prioritised coverage floor weight (as PlannerConfig.eps)
_MAX_ELEMS = 2_000_000  # feature 14: (env, slot, slot, cell[, class]) elements per chunk


@lru_cache(maxsize=4)
def _rel_table(lat_id, Hp):
    lat = _LATS[lat_id]
    pr = np.maximum(lat.edges, 0)  # (V, A)
    off = lat.cell_off[pr].astype(np.int64)  # (V, A, U, 2)
    has = lat.cell_count[pr].sum(-1) > 0
    rel = off[..., 1] * Hp + off[..., 0]
    return np.where(has, rel, 0), has.astype(np.float32)


_LATS: dict = {}


def _second_step(env, pr, valid, fp, cmean):
    """(N, A) best prioritised-coverage and coverage rate one primitive further on.

    Cheap on purpose (one gather from padded weight maps, no transcendental
    functions) so that the learned planner stays well under 5 ms per decision.
    """
    lat = env.lat
    N, A = pr.shape
    S, Hp, p = env.S, env.Hp, env.pad
    _LATS[id(lat)] = lat
    rel, has = _rel_table(id(lat), Hp)
    end = env.pos[:, None, :] + lat.prim_disp[pr]  # (N, A, 2)
    ex = np.clip(end[..., 0], 0, S - 1)
    ey = np.clip(end[..., 1], 0, S - 1)
    v2 = lat.prim_to[pr]  # (N, A)
    ok2 = env.ok[v2, :, ey, ex] & valid[..., None]  # (N, A, A)
    newmap = (~env.cov & env.inner[None]).astype(np.float32)  # uncovered inner cells
    wmap = newmap * (EPS + env.prio_map())
    base = (np.arange(N)[:, None] * Hp + ey + p) * Hp + ex + p  # (N, A)
    idx = base[..., None, None] + rel[v2]  # (N, A, A, U)
    hv = has[v2]
    nc = (newmap.reshape(-1)[idx] * hv).sum(-1)
    pc = (wmap.reshape(-1)[idx] * hv).sum(-1)
    cost = lat.prim_cost[np.maximum(lat.edges[v2], 0)] / cmean
    pc = np.where(ok2, pc / fp / cost, 0).max(-1)
    nc = np.where(ok2, nc / fp / cost, 0).max(-1)
    return pc, nc


@lru_cache(maxsize=4)
def _pair_table(lat_id, Hp, lam_levels):
    """Per (first primitive p1, second slot a2, cell u of the second primitive), raveled
    over (P, A, U): the cell as a flat offset from p1's start cell ``rel``, the
    second primitive's log-odds magnitude there ``lam2``, p1's own at the same cell
    ``lp`` (the overlap), ``has`` (a real cell), and the second primitive ``p2 (P, A)``
    (-1: empty slot)."""
    lat = _LATS[lat_id]
    lamv = np.asarray(lam_levels, np.float64)
    P = lat.n_prims
    p2 = lat.edges[lat.prim_to]  # (P, A)
    p2c = np.maximum(p2, 0)
    off1 = lat.cell_off.astype(np.int64)  # (P, U, 2)
    cnt = lat.cell_count.astype(np.float64)
    has1 = cnt.sum(-1) > 0  # (P, U)
    off2 = lat.prim_disp[:, None, None, :].astype(np.int64) + off1[p2c]  # (P, A, U, 2)
    has2 = has1[p2c] & (p2 >= 0)[..., None]
    R = int(np.abs(off2).max()) + 1
    W = 2 * R + 1
    win = np.zeros((P, W * W))
    pi, ui = np.nonzero(has1)
    np.add.at(win, (pi, (off1[pi, ui, 1] + R) * W + off1[pi, ui, 0] + R), cnt[pi, ui] @ lamv)
    lp = win[np.arange(P)[:, None, None], (off2[..., 1] + R) * W + off2[..., 0] + R]
    rel = off2[..., 1] * Hp + off2[..., 0]
    lam2 = (cnt @ lamv)[p2c]
    lam2, lp = np.where(has2, lam2, 0).ravel(), np.where(has2, lp, 0).ravel()
    return np.where(has2, rel, 0).ravel(), lam2, lp, has2, p2


def _two_step_detect(env, pr, valid, d1, fp, cmean):
    """(N, A) feature 14 (see the module docstring), batched over the valid
    (environment, first slot, second slot, cell) quadruples."""
    lat = env.lat
    N, A = pr.shape
    S, Hp, p = env.S, env.Hp, env.pad
    _LATS[id(lat)] = lat
    rel, lam2, lp, has2, p2 = _pair_table(id(lat), Hp, tuple(env.lam_levels.tolist()))
    U = has2.shape[-1]
    end = env.pos[:, None, :] + lat.prim_disp[pr]  # (N, A, 2)
    ex = np.clip(end[..., 0], 0, S - 1)
    ey = np.clip(end[..., 1], 0, S - 1)
    v2 = lat.prim_to[pr]
    ok2 = env.ok[v2, :, ey, ex] & valid[..., None]  # (N, A, A)
    base = (np.arange(N) * Hp + env.pos[:, 1] + p) * Hp + env.pos[:, 0] + p
    d2 = np.zeros(N * A * A)
    C = getattr(env, "n_classes", 1)
    step = max(1, _MAX_ELEMS // (A * A * U * C))  # bound the temporaries (semantic maps)
    for s in range(0, N, step):
        sl = slice(s, min(N, s + step))
        j = np.flatnonzero(ok2[sl, ..., None] & has2[pr[sl]])  # over (n, A, A, U)
        na = j // (A * U) + s * A  # n * A + a1
        t = pr.reshape(-1)[na] * (A * U) + j % (A * U)  # row of the pair table
        g = env.plan_detect_gain_flat(base[na // A] + rel[t], lp[t], lam2[t])
        d2[s * A * A:sl.stop * A * A] = np.bincount(j // U, weights=g,
                                                    minlength=(sl.stop - s) * A * A)
    d2 = d2.reshape(N, A, A)
    c1 = lat.prim_cost[pr] / cmean
    c2 = lat.prim_cost[np.maximum(p2[pr], 0)] / cmean
    # budget-aware, as the detect planner: the primitive crossing the end of the budget
    # is charged the remainder only, a second primitive after it never happens
    R = np.maximum(env.remaining, 1e-9)[:, None] / cmean
    d2 = d2 * (c1 < R)[..., None]
    cc = np.minimum(c1[..., None] + c2, R[..., None])
    score = np.where(ok2, (d1[..., None] + d2) / fp / cc, -np.inf).max(-1)
    return np.where(valid, np.where(ok2.any(-1), score, d1 / fp / np.minimum(c1, R)), 0.0)


def action_features(env) -> np.ndarray:
    """(N, A, N_FEAT) float32 features of every action slot (see module docstring).

    The belief enters through the env's planner hooks (``plan_cells``, ``plan_ig``,
    ``plan_detect``, ``plan_prio``), so the same code serves target search and
    semantic detection.
    """
    lat = env.lat
    N, A = env.n, lat.n_actions
    S, Hp, p = env.S, env.Hp, env.pad
    fp = float((2 * lat.config.footprint_radius + 1) ** 2)
    vert, pos = env.vert, env.pos
    prim = lat.edges[vert]  # (N, A)
    pr = np.maximum(prim, 0)
    valid = env.valid_mask()
    off = lat.cell_off[pr].astype(np.int64)  # (N, A, U, 2)
    cnt = lat.cell_count[pr].astype(np.float64)  # (N, A, U, L)
    lam = cnt @ env.lam_levels  # (N, A, U)
    x = pos[:, 0, None, None] + off[..., 0]
    y = pos[:, 1, None, None] + off[..., 1]
    inside = (x >= 0) & (x < S) & (y >= 0) & (y < S) & (cnt.sum(-1) > 0) & valid[..., None]
    # all work below on the sensed, in-map cells of valid slots only (compressed)
    n_i, a_i, _ = np.nonzero(inside)
    flat = (n_i * Hp + y[inside] + p) * Hp + x[inside] + p
    lam = lam[inside]
    b = env.plan_cells(n_i, flat - n_i * Hp * Hp)
    new = ~env.cov.reshape(-1)[flat]
    ig, det = env.plan_ig(b, lam), env.plan_detect(b, lam)
    open_ = env.plan_open(b)  # not yet *believed* found (env.found would need the truth)
    prio = env.plan_prio(b)
    slot = n_i * A + a_i

    def per_slot(w):
        return np.bincount(slot, weights=w, minlength=N * A).reshape(N, A) / fp

    f = np.zeros((N, A, N_FEAT), np.float64)
    f[..., 0] = per_slot(ig)
    f[..., 1] = per_slot(det * open_)
    f[..., 2] = per_slot(prio * open_)
    f[..., 3] = per_slot(new.astype(np.float64))
    f[..., 10] = per_slot(new * (EPS + prio))
    cmean = float(lat.prim_cost.mean())
    c = lat.prim_cost[pr] / cmean
    f[..., 4] = np.where(valid, c, 0)
    f[..., 5] = np.where(valid, f[..., 0] / c, 0)
    f[..., 6] = np.where(valid, f[..., 1] / c, 0)
    f[..., 7] = np.where(valid, f[..., 3] / c, 0)
    # distance to the nearest uncovered inner cell: one EDT per environment (a batched
    # EDT with a huge step on the batch axis is slower on these small maps)
    unc = ~env.cov[:, p:p + S, p:p + S]
    dist = np.full((N, S, S), 2.0 * S)  # fully covered map: capped distance
    for n in np.flatnonzero(unc.reshape(N, -1).any(1)):
        dist[n] = distance_transform_edt(~unc[n])
    end = pos[:, None, :] + lat.prim_disp[pr]
    ex = np.clip(end[..., 0], 0, S - 1)
    ey = np.clip(end[..., 1], 0, S - 1)
    f[..., 8] = np.where(valid, dist[np.arange(N)[:, None], ey, ex] / S, 0)
    f[..., 9] = valid
    f[..., 11] = np.where(valid, f[..., 10] / c, 0)
    f[..., 12], f[..., 13] = _second_step(env, pr, valid, fp, cmean)
    d1 = np.bincount(slot, weights=env.plan_detect_gain(b, np.zeros_like(lam), lam),
                     minlength=N * A).reshape(N, A)
    f[..., 14] = _two_step_detect(env, pr, valid, d1, fp, cmean)
    top = np.where(valid, f[..., 14], 0).max(1, keepdims=True)
    f[..., 15] = np.where(valid, f[..., 14] / np.maximum(top, 1e-12), 0)
    return f.astype(np.float32)
