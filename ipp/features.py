"""Per-primitive look-ahead features for the learned planner (observation design).

The thesis's policy sees only egocentric map windows (§2.5.2 "Observations") and must
learn from them which of the ~20 primitives senses what. Here the policy additionally
gets, for every action slot, a short vector describing what that primitive would sense
from the agent's current state, computed from the agent's *belief* (never the truth)
with the same tiled sensing tables the baselines use (:mod:`.baselines`):

====  =====================================================================
0     expected information gain of the sensed cells, bits / footprint area
      (``IG(b, lam)`` of :func:`aerohrl.ipp.scoring.info_gain`)
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
from typing import TYPE_CHECKING

import numpy as np
from scipy.ndimage import distance_transform_edt

if TYPE_CHECKING:
    from .env import SearchEnv


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


def _pair_geometry(lat, lamv: np.ndarray) -> dict:
    """What a first primitive p1 and the primitive p2 in each slot a2 after it sense:
    ``off1`` (P, U, 2) p1's cell offsets, ``has1`` (P, U) real cells, ``lam1`` (P, U) p1's
    log-odds magnitude per cell; ``p2`` (P, A) (-1: empty slot), ``p2c`` (clipped),
    ``off2`` (P, A, U, 2) p2's cells as offsets from p1's start, ``has2``, and ``lp``
    (P, A, U) p1's own magnitude at p2's cells (the overlap of the two)."""
    P = lat.n_prims
    p2 = lat.edges[lat.prim_to]  # (P, A)
    p2c = np.maximum(p2, 0)
    off1 = lat.cell_off.astype(np.int64)  # (P, U, 2)
    cnt = lat.cell_count.astype(np.float64)
    has1 = cnt.sum(-1) > 0  # (P, U)
    lam1 = cnt @ lamv  # (P, U)
    off2 = lat.prim_disp[:, None, None, :].astype(np.int64) + off1[p2c]  # (P, A, U, 2)
    has2 = has1[p2c] & (p2 >= 0)[..., None]
    R = int(np.abs(off2).max()) + 1
    W = 2 * R + 1
    win = np.zeros((P, W * W))
    pi, ui = np.nonzero(has1)
    np.add.at(win, (pi, (off1[pi, ui, 1] + R) * W + off1[pi, ui, 0] + R), cnt[pi, ui] @ lamv)
    lp = win[np.arange(P)[:, None, None], (off2[..., 1] + R) * W + off2[..., 0] + R]
    return {"off1": off1, "has1": has1, "lam1": lam1, "cnt": cnt, "p2": p2, "p2c": p2c, "off2": off2, "has2": has2, "lp": lp}


@lru_cache(maxsize=4)
def _pair_table(lat_id, Hp, lam_levels):
    """Per (first primitive p1, second slot a2, cell u of the second primitive), raveled
    over (P, A, U): the cell as a flat offset from p1's start cell ``rel``, the
    second primitive's log-odds magnitude there ``lam2``, p1's own at the same cell
    ``lp`` (the overlap), ``has`` (a real cell), and the second primitive ``p2 (P, A)``
    (-1: empty slot)."""
    lat = _LATS[lat_id]
    g = _pair_geometry(lat, np.asarray(lam_levels, np.float64))
    off2, has2, p2 = g["off2"], g["has2"], g["p2"]
    lp = g["lp"]
    rel = off2[..., 1] * Hp + off2[..., 0]
    lam2 = g["lam1"][g["p2c"]]
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
        d2[s * A * A : sl.stop * A * A] = np.bincount(j // U, weights=g, minlength=(sl.stop - s) * A * A)
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


def action_features(env: SearchEnv) -> np.ndarray:
    """(N, A, N_FEAT) float32 features of every action slot (see module docstring).

    Target search: :func:`action_features_reference`. Semantic worlds: the same values
    from :func:`semantic_fast` (windows around the agents and sparse products instead
    of per-(slot, slot, cell) arrays; equal to the reference up to float rounding, a
    test checks).
    """
    if fast_path_applies(env):
        return semantic_fast(env)[0]
    return action_features_reference(env)


def action_features_reference(env: SearchEnv) -> np.ndarray:
    """The direct computation of :func:`action_features` for any env kind.

    The belief enters through the env's planner hooks (``plan_cells``, ``plan_ig``,
    ``plan_detect``, ``plan_prio``), so the same code serves target search and
    semantic detection (there it costs ~60 ms per decision on 256 x 256 maps).
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
    unc = ~env.cov[:, p : p + S, p : p + S]
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
    d1 = np.bincount(slot, weights=env.plan_detect_gain(b, np.zeros_like(lam), lam), minlength=N * A).reshape(N, A)
    f[..., 14] = _two_step_detect(env, pr, valid, d1, fp, cmean)
    top = np.where(valid, f[..., 14], 0).max(1, keepdims=True)
    f[..., 15] = np.where(valid, f[..., 14] / np.maximum(top, 1e-12), 0)
    return f.astype(np.float32)


# ------------------------------------------------------------------ semantic fast path
# On the 256 x 256 semantic maps the direct computation above evaluates feature 14 on
# ~(20 x 20 slot pairs x 430 cells) x 5 classes per environment (~60 ms per decision).
# The fast path gives the same values within the 5 ms decision budget:
#
# * everything a decision reads lies in a (2 Rw + 1)^2 window around the agent (Rw:
#   the farthest cell two primitives sense), so per-cell quantities are computed on
#   that window only;
# * the features that are sums of a per-cell map over a primitive's cells (2, 3, 10,
#   and the second-step sums of 12, 13) are one sparse matrix product per lattice
#   vertex: rows = first slots and (first, second) slot pairs, columns = window cells;
# * the expected detections (1, 14) are not linear in the cells: a cell's detection
#   term is ``s(lam) * sum_c b_c [lam >= tau_c]`` (``semantic_env.plan_detect``,
#   ``tau_c = logit(thr) - logit(b_c)``) with ``lam`` the summed label log-ratio of the
#   sensing primitive(s), a constant of the lattice. With breakpoints ``0 = Lam_0 <
#   ... < Lam_{K-1}`` of the lattice's ``lam`` values and ``k(lam)`` the bin of
#   ``lam``, ``[lam >= tau] = [tau <= Lam_k] + [Lam_k < tau <= lam]``. The first part
#   is a sparse product with the per-cell maps ``M_k = sum_c b_c [tau_c <= Lam_k]``
#   (columns = (bin, window cell)); the second, the *residual*, is non-zero only for
#   the few (cell, class) whose ``tau`` falls inside the bin of an element of that
#   cell, and is evaluated element by element from a table sorted by (cell, bin, lam).
#   Exact: both parts are the same indicator tests as ``plan_detect``.
#
# The ``detect`` teacher on semantic worlds reads its scores from here as well (its
# depth-2, budget-aware score is feature 14, scaled), so features and teacher at one
# state share one computation (cached on ``env.version`` and the agents' state).

_K_FREQ = 24  # detection look-up breakpoints at the most frequent lam values ...
_K_QUANT = 24  # ... and at quantiles (time/memory balance only; any choice is exact)
_FAST_CHUNK = 16  # environments per sparse product (bounds the (K x window) maps)


def fast_path_applies(env: SearchEnv) -> bool:
    """True for semantic environments whose padding holds the fast path's window."""
    if getattr(env, "n_classes", None) is None:
        return False
    return env.pad >= _sem_tables_for(env)["Rw"]


def _sem_tables_for(env):
    _LATS[id(env.lat)] = env.lat
    return _sem_tables(id(env.lat), tuple(env.lam_levels.tolist()), env.n_classes)


def _run_matrix(rows, xs, W, nrow):
    """Sparse (nrow, W*(W+1)) matrix summing a map over the cells ``(rows, xs)`` from its
    row-wise prefix sums: +1 after and -1 at the start of every horizontal run."""
    from scipy.sparse import csr_matrix

    y, x = xs // W, xs % W
    o = np.lexsort((x, y, rows))
    r, y, x = rows[o], y[o], x[o]
    brk = np.ones(len(r), bool)
    brk[1:] = (r[1:] != r[:-1]) | (y[1:] != y[:-1]) | (x[1:] != x[:-1] + 1)
    s_i = np.flatnonzero(brk)
    e_i = np.append(s_i[1:], len(r)) - 1
    W1 = W + 1
    cols = np.concatenate([y[s_i] * W1 + x[e_i] + 1, y[s_i] * W1 + x[s_i]])
    vals = np.concatenate([np.ones(len(s_i)), -np.ones(len(s_i))])
    return csr_matrix((vals, (np.concatenate([r[s_i], r[s_i]]), cols)), shape=(nrow, W * W1))


@lru_cache(maxsize=2)
def _sem_tables(lat_id, lam_levels, n_classes):
    """Per lattice vertex: the sparse matrices and the residual table (see above)."""
    from scipy.sparse import csr_matrix

    from .scoring import LAM_CAP, detect_success

    lat = _LATS[lat_id]
    lamv = np.asarray(lam_levels, np.float64)
    C = n_classes
    A, V = lat.n_actions, lat.n_vertices
    g = _pair_geometry(lat, lamv)  # lp: the first primitive's lam at the second one's cells
    has1, lam1, off1 = g["has1"], g["lam1"], g["off1"]
    p2c, off2, has2, lp = g["p2c"], g["off2"], g["has2"], g["lp"]
    lam2 = lam1[p2c]
    Rw = int(max(np.abs(off2[has2]).max(), np.abs(off1[has1]).max()))
    W = 2 * Rw + 1
    WW = W * W
    AA = A * A
    items = []
    for v in range(V):
        p1 = lat.edges[v]
        P1 = np.maximum(p1, 0)
        a1, a2, u = np.nonzero((p1 >= 0)[:, None, None] & has2[P1])
        pp = P1[a1]
        o = off2[pp, a2, u]
        x2 = (o[:, 1] + Rw) * W + o[:, 0] + Rw
        l0 = lp[pp, a2, u]
        l1 = l0 + lam2[pp, a2, u]  # the same sum as the tree search's lp + lam
        r2 = a1 * A + a2
        b1, u1 = np.nonzero((p1 >= 0)[:, None] & has1[P1])
        o1 = off1[P1[b1], u1]
        x1 = (o1[:, 1] + Rw) * W + o1[:, 0] + Rw
        lf = lam1[P1[b1], u1]
        ov = l0 > 0  # lp = 0: the detection term at lam 0 vanishes on open cells
        it_l = np.minimum(np.concatenate([l1, l0[ov], lf]), LAM_CAP)
        # feature 0: mutual information of the class and the equivalent label,
        # H(z) - H(z | class); per element constants of H(z | class) = Hn
        e = 1.0 / (1.0 + np.exp(np.minimum(lf, LAM_CAP)) / (C - 1))
        q = e / (C - 1)
        items.append(
            {
                "x": np.concatenate([x2, x2[ov], x1]),
                "lam": it_l,
                "w": np.concatenate([np.ones(len(l1)), -np.ones(int(ov.sum())), np.ones(len(b1))]) * detect_success(it_l, C),
                "row": np.concatenate([r2, r2[ov], AA + b1]),
                "lin1": _run_matrix(b1, x1, W, A),
                "lin2": _run_matrix(r2, x2, W, AA),
                "ig_x": x1,
                "ig_a": b1,
                "ig_q": q.astype(np.float32),
                "ig_k": (1.0 - e - q).astype(np.float32),
                "ig_hn": -(1 - e) * np.log1p(-e) - e * np.log(q),
            }
        )
    every = np.concatenate([it["lam"] for it in items])
    vals, counts = np.unique(every, return_counts=True)
    freq = vals[np.argsort(-counts, kind="stable")[:_K_FREQ]]
    quant = np.quantile(every, np.linspace(0, 1, _K_QUANT + 1)[1:-1])
    Lam = np.unique(np.concatenate([[0.0], freq, quant]))
    Lam = Lam[Lam >= 0]
    K = len(Lam)
    nrow = AA + A
    per_v = []
    for it in items:
        k = np.searchsorted(Lam, it["lam"], side="right") - 1  # Lam_k <= lam < Lam_k+1
        det = csr_matrix((it["w"], (it["row"], k * WW + it["x"])), shape=(nrow, K * WW))
        # residual table: elements strictly above their bin's breakpoint, sorted by
        # (cell, bin, lam); an element at the breakpoint never has Lam_k < tau <= lam
        rest = it["lam"] > Lam[k]
        x, kk, lam, w, row = (a[rest] for a in (it["x"], k, it["lam"], it["w"], it["row"]))
        order = np.lexsort((lam, kk, x))
        key = x[order] * K + kk[order]
        per_v.append(
            {
                "det": det,
                "lin1": it["lin1"],
                "lin2": it["lin2"],
                "ptr": np.searchsorted(key, np.arange(WW * K + 1)),
                "r_lam": lam[order],
                "r_w": w[order],
                "r_row": row[order],
                **{k_: it[k_] for k_ in ("ig_x", "ig_a", "ig_q", "ig_k", "ig_hn")},
            }
        )
    return {"Rw": Rw, "W": W, "Lam": Lam, "K": K, "nrow": nrow, "v": per_v}


def _windows(arr, idx, y0, x0, W):
    """(len(idx), ..., W, W) copies of the W x W windows of ``arr[n, ..., y, x]``."""
    return np.stack([arr[n, ..., y0[n] : y0[n] + W, x0[n] : x0[n] + W] for n in idx])


def _sem_sums(env, T, idx, v):
    """For the envs ``idx`` at vertex ``v``: detection sums D (G, A*A + A) (pairs, then
    first slots), the linear sums of the first slots (G, A, 3) (new cells, prioritised
    new cells, open prioritised cells) and of the pairs (G, A*A, 2), and the
    information gain of the first slots (G, A)."""
    from .scoring import crossing_lam

    C, W, K, Lam = env.n_classes, T["W"], T["K"], T["Lam"]
    WW, R, tv = W * W, T["nrow"], T["v"][v]
    A = env.lat.n_actions
    G = len(idx)
    y0 = env.pos[:, 1] + env.pad - T["Rw"]
    x0 = env.pos[:, 0] + env.pad - T["Rw"]
    pw = _windows(env.planes, idx, y0, x0, W)  # (G, C+2, W, W) float32
    feat = pw[:, 1:C].reshape(G, C - 1, WW)
    open_ = feat.max(1) < env.cfg.found_threshold  # plan_open
    inner = np.stack([env.inner[y0[n] : y0[n] + W, x0[n] : x0[n] + W] for n in idx])  # (G, W, W)
    cov = _windows(env.cov, idx, y0, x0, W)
    prio = 1.0 - pw[:, 0]  # plan_prio / prio_map (float32)
    new = (~cov & inner).astype(np.float32)
    X = np.stack([new, new * (EPS + prio), (inner & open_.reshape(G, W, W)) * prio])
    pfx = np.zeros((3, G, W, W + 1))  # row-wise prefix sums for the run matrices
    np.cumsum(X, axis=-1, out=pfx[..., 1:])
    pfx = pfx.reshape(3, G, W * (W + 1)).transpose(2, 1, 0)  # (cells, G, 3)
    lin1 = (tv["lin1"] @ pfx.reshape(-1, G * 3)).reshape(A, G, 3).transpose(1, 0, 2)
    lin2 = tv["lin2"] @ np.ascontiguousarray(pfx[..., :2]).reshape(-1, G * 2)
    lin2 = lin2.reshape(A * A, G, 2).transpose(1, 0, 2)
    # feature 0: H(z) - H(z | class) of the equivalent label, in-map cells only
    pz = tv["ig_q"] + tv["ig_k"] * pw[:, :C].reshape(G, C, WW)[:, :, tv["ig_x"]]
    pz *= np.log(pz)
    hz = -pz[:, 0]
    for c in range(1, C):
        hz -= pz[:, c]
    ig = np.where(inner.reshape(G, WW)[:, tv["ig_x"]], hz - tv["ig_hn"], 0.0) / np.log(2.0)
    IG = np.bincount((np.arange(G)[:, None] * A + tv["ig_a"]).ravel(), weights=ig.ravel(), minlength=G * A).reshape(G, A)
    # detection: M_k maps (columns (bin, cell)) and the residual
    bb = np.where(open_[:, None, :], feat.astype(np.float64), 0.0)  # (G, C-1, WW)
    tau = crossing_lam(bb, env.cfg.found_threshold)
    j = np.searchsorted(Lam, tau, side="left")  # [tau <= Lam_k] <=> k >= j
    g_i, _, x_i = np.indices(bb.shape, sparse=True)
    use = (j < K) & (bb > 0)
    key = ((j * WW + x_i) * G + g_i)[use]
    M = np.bincount(key, weights=bb[use], minlength=K * WW * G).reshape(K, WW * G)
    for k in range(1, K):  # cumulative over the bins (faster than cumsum on axis 0)
        M[k] += M[k - 1]
    D = (tv["det"] @ M.reshape(K * WW, G)).T  # (G, R)
    # residual: tau strictly inside bin j - 1, elements of that bin with lam >= tau
    jc = np.minimum(j, K - 1)
    res = (bb > 0) & ((j == K) | (Lam[jc] > tau))
    qg, _, qx = np.nonzero(res)
    qt, qb = tau[res], bb[res]
    seg = qx * K + j[res] - 1
    st = tv["ptr"][seg]
    ln = tv["ptr"][seg + 1] - st
    rep = np.repeat(np.arange(len(st)), ln)
    pos = np.arange(int(ln.sum())) + np.repeat(st - (np.cumsum(ln) - ln), ln)
    hit = tv["r_lam"][pos] >= qt[rep]
    rep, pos = rep[hit], pos[hit]
    D += np.bincount(qg[rep] * R + tv["r_row"][pos], weights=qb[rep] * tv["r_w"][pos], minlength=G * R).reshape(G, R)
    return D, lin1, lin2, IG


def _window_edt(env, live, ends, R):
    """(N, A) distance from the cells ``ends`` (N, A, 2) to the nearest uncovered inner
    cell, from a distance transform on a window of radius ``R`` around the agent; a
    value is kept only where no cell outside the window can be nearer, otherwise (and
    for a fully covered map) the environment falls back to the whole-map transform,
    so the result equals the reference's."""
    S, p = env.S, env.pad
    out = np.zeros(ends.shape[:2])
    for n in live:
        cx, cy = env.pos[n]
        xa, xb = max(cx - R, 0), min(cx + R + 1, S)
        ya, yb = max(cy - R, 0), min(cy + R + 1, S)
        unc = ~env.cov[n, p + ya : p + yb, p + xa : p + xb]
        ex, ey = np.clip(ends[n, :, 0], 0, S - 1), np.clip(ends[n, :, 1], 0, S - 1)
        inside = (ex >= xa) & (ex < xb) & (ey >= ya) & (ey < yb)
        if unc.any() and inside.all():
            d = distance_transform_edt(~unc)[ey - ya, ex - xa]
            # the nearest cell outside the window (sides that are not the map's edge)
            big = np.full(ex.shape, np.inf)
            m = np.minimum.reduce(
                [
                    ex - xa + 1.0 if xa > 0 else big,
                    xb - ex + 0.0 if xb < S else big,
                    ey - ya + 1.0 if ya > 0 else big,
                    yb - ey + 0.0 if yb < S else big,
                ]
            )
            if np.all(d <= m):
                out[n] = d
                continue
        full = ~env.cov[n, p : p + S, p : p + S]
        dist = distance_transform_edt(~full) if full.any() else np.full((S, S), 2.0 * S)
        out[n] = dist[ey, ex]
    return out


def semantic_fast(env: SearchEnv) -> tuple[np.ndarray, np.ndarray]:
    """(features (N, A, N_FEAT) float32, detect scores (N, A)) on a semantic env; the
    scores are the ``detect`` tree's depth-2 budget-aware ``utility / cost`` of each
    first slot (-inf where invalid). Cached per state (``env.version`` and the agents'
    cells, vertices, budgets, done flags)."""
    key = (env.version, env.pos.tobytes(), env.vert.tobytes(), env.remaining.tobytes(), env.done.tobytes())
    hit = getattr(env, "_fast_cache", None)
    if hit is not None and hit[0] == key:
        return hit[1]
    lat = env.lat
    T = _sem_tables_for(env)
    N, A = env.n, lat.n_actions
    AA, S = A * A, env.S
    fp = float((2 * lat.config.footprint_radius + 1) ** 2)
    cmean = float(lat.prim_cost.mean())
    valid = env.valid_mask()
    pr = np.maximum(lat.edges[env.vert], 0)
    live = np.flatnonzero(~env.done)
    D = np.zeros((N, T["nrow"]))
    L2: np.ndarray  # reshaped to (N, A, A, 2) below
    L1, L2 = np.zeros((N, A, 3)), np.zeros((N, AA, 2))
    IG = np.zeros((N, A))
    for v in np.unique(env.vert[live]):
        at = live[env.vert[live] == v]
        for s in range(0, len(at), _FAST_CHUNK):
            ch = at[s : s + _FAST_CHUNK]
            D[ch], L1[ch], L2[ch], IG[ch] = _sem_sums(env, T, ch, int(v))
    f = np.zeros((N, A, N_FEAT), np.float64)
    d1 = np.where(valid, D[:, AA:], 0.0)
    f[..., 0] = np.where(valid, IG, 0) / fp
    f[..., 1] = d1 / fp
    f[..., 2] = np.where(valid, L1[..., 2], 0) / fp
    f[..., 3] = np.where(valid, L1[..., 0], 0) / fp
    f[..., 10] = np.where(valid, L1[..., 1], 0) / fp
    c = lat.prim_cost[pr] / cmean
    f[..., 4] = np.where(valid, c, 0)
    f[..., 5] = np.where(valid, f[..., 0] / c, 0)
    f[..., 6] = np.where(valid, f[..., 1] / c, 0)
    f[..., 7] = np.where(valid, f[..., 3] / c, 0)
    end = env.pos[:, None, :] + lat.prim_disp[pr]
    Rd = int(np.abs(lat.prim_disp).max()) + 2 * lat.config.footprint_radius + 8
    f[..., 8] = np.where(valid, _window_edt(env, live, end, Rd) / S, 0)
    f[..., 9] = valid
    f[..., 11] = np.where(valid, f[..., 10] / c, 0)
    # second step (12, 13) and the exact two-step detection rate (14), as the reference
    ex = np.clip(end[..., 0], 0, S - 1)
    ey = np.clip(end[..., 1], 0, S - 1)
    ok2 = env.ok[lat.prim_to[pr], :, ey, ex] & valid[..., None]  # (N, A, A)
    c2 = lat.prim_cost[np.maximum(lat.edges[lat.prim_to][pr], 0)] / cmean
    L2 = L2.reshape(N, A, A, 2)
    f[..., 12] = np.where(ok2, L2[..., 1] / fp / c2, 0).max(-1)
    f[..., 13] = np.where(ok2, L2[..., 0] / fp / c2, 0).max(-1)
    d2 = D[:, :AA].reshape(N, A, A)
    Rb = np.maximum(env.remaining, 1e-9)[:, None] / cmean
    d2 = d2 * (c < Rb)[..., None]
    cc = np.minimum(c[..., None] + c2, Rb[..., None])
    score = np.where(ok2, (d1[..., None] + d2) / fp / cc, -np.inf).max(-1)
    f[..., 14] = np.where(valid, np.where(ok2.any(-1), score, d1 / fp / np.minimum(c, Rb)), 0.0)
    top = np.where(valid, f[..., 14], 0).max(1, keepdims=True)
    f[..., 15] = np.where(valid, f[..., 14] / np.maximum(top, 1e-12), 0)
    first = np.where(valid, f[..., 14] * (fp / cmean), -np.inf)
    out = (f.astype(np.float32), first)
    env._fast_cache = (key, out)
    return out
