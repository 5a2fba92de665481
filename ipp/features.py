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
      sensed cells not yet found (one-measurement equivalent of ``lam``, as in
      :func:`info_gain`), / footprint area
2     belief mass of sensed cells not yet found, / footprint area
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


N_FEAT = 14
EPS = 0.05  # prioritised coverage floor weight (as PlannerConfig.eps)


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
    open_ = ~env.found.reshape(-1)[flat]
    new = ~env.cov.reshape(-1)[flat]
    ig, det = env.plan_ig(b, lam), env.plan_detect(b, lam)
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
    return f.astype(np.float32)
