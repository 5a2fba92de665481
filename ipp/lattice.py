"""Dispersion-minimising motion-primitive lattice over planar velocity states.

Thesis §2.5.1. A lattice vertex is a planar velocity state ``(vx, vy)`` (position
free, acceleration zero); an edge (a *primitive*) is a minimum-jerk trajectory from
vertex ``i`` at the origin cell to vertex ``j`` at an integer cell displacement
``(dx, dy)``. Because the dynamics are translation invariant and every primitive ends
on a cell centre, a primitive is stored once and *tiled*: executing it at cell
``(x, y)`` is the stored trajectory shifted by ``(x, y)``; so are the cells it senses.

Construction (:func:`build_lattice`):

1. **Vertices** by greedy dispersion minimisation (thesis Eq. 2.3)::

       d(V) = sup_{x in X} min_{v in V} max(J(x, v), J(v, x))

   over a dense sample ``X`` of the velocity disk ``|v| <= v_max``. ``J`` is the
   optimal cost (``rho*T + int |jerk|^2``) of steering the velocity from one state to
   the other with zero boundary accelerations and the acceleration bound
   (:func:`transfer_cost`). Starting from hover, the sample point farthest (in ``J``)
   from the current vertex set is added; ``d(V)`` after each addition is stored and
   never rises.
2. **Candidate primitives** for every vertex pair and displacement in a window: the
   quintic (minimum-jerk) polynomial meeting position, velocity and zero acceleration
   at both ends, whose duration ``T`` minimises ``cost = rho*T + int |jerk|^2`` over a
   grid subject to ``|v(t)| <= v_max`` and ``|a(t)| <= a_max``.
3. **Edges** per vertex: the cheapest candidate to every successor vertex, the
   hover-to-hover cardinal moves of ``hover_moves`` cells (these keep the graph viable
   and allow a boustrophedon sweep), then farthest-point (dispersion-minimising)
   selection over the end states ``(dx, dy, tau*vx, tau*vy)`` up to ``max_edges``.
4. **Sensing** per primitive: the trajectory is sampled every ``sense_dt`` seconds on
   ``(0, T]``; every distinct cell visited by the footprint centre yields one
   measurement of each cell of the ``(2r+1)^2`` footprint, labelled with its Chebyshev
   distance from the centre (the sensor's error level).

File format (``.npz``, :data:`FORMAT` / :data:`VERSION`), arrays (``P`` primitives,
``V`` vertices, ``A`` action slots, ``M`` measurement slots, ``U`` cell slots):

=================  ============  =====================================================
``meta``           0-d str       JSON: format, version, the :class:`LatticeConfig`
``vertices``       (V, 2) f8     vertex velocities, m/s; vertex 0 is hover
``dispersion``     (V,) f8       d(V_k) after adding vertex k (Eq. 2.3); [0] = d({0})
``edges``          (V, A) i4     primitive index of action a at vertex v, -1 = none
``prim_from``      (P,) i4       start vertex
``prim_to``        (P,) i4       end vertex
``prim_disp``      (P, 2) i4     end displacement (dx, dy) in cells
``prim_T``         (P,) f8       duration, s
``prim_cost``      (P,) f8       rho*T + int |jerk|^2 (time + control effort)
``prim_coef``      (P, 2, 6) f8  polynomial coefficients p(t) = sum_k c_k t^k per axis
``prim_bbox``      (P, 4) i4     min dx, max dx, min dy, max dy of visited centre cells
``meas_off``       (P, M, 2) i2  measured cell offsets from the start cell, padded 0
``meas_level``     (P, M) i1     Chebyshev distance to the footprint centre, -1 = pad
``cell_off``       (P, U, 2) i2  distinct sensed cells (offsets), padded 0
``cell_count``     (P, U, L) i2  measurements of each distinct cell per level, pad 0
=================  ============  =====================================================
"""

from __future__ import annotations

import json
import os
from dataclasses import asdict, dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import cast

import numpy as np

from aerohrl.config import ConfigError, param, validate


from aerohrl.atomic import atomic_path

FORMAT = "aerohrl-ipp-lattice"
VERSION = 1
DEFAULT_PATH = Path(__file__).resolve().parent / "data" / "lattice_default.npz"
SEMANTIC_PATH = Path(__file__).resolve().parent / "data" / "lattice_semantic.npz"


@dataclass(frozen=True)
class LatticeConfig:
    """Parameters of :func:`build_lattice` (CLI flags of ``ipp lattice build``)."""

    n_vertices: int = param(9, "lattice vertices (velocity states), hover included", ge=1)
    v_max: float = param(3.0, "speed bound |v|", unit="m/s", gt=0)
    a_max: float = param(3.0, "acceleration bound |a|", unit="m/s^2", gt=0)
    rho: float = param(100.0, "weight of time in the primitive cost rho*T + int |jerk|^2", unit="1/s", gt=0)
    reach: int = param(7, "displacement window |dx|, |dy| <= reach", unit="cells", ge=1)
    max_edges: int = param(20, "primitives per vertex (action slots)", ge=1)
    t_min: float = param(0.5, "shortest primitive duration", unit="s", gt=0)
    t_max: float = param(5.0, "longest primitive duration", unit="s", gt=0)
    t_step: float = param(0.1, "step of the duration grid", unit="s", gt=0)
    tau: float = param(1.0, "velocity weight in the edge-dispersion metric", unit="s", gt=0)
    hover_moves: tuple[int, ...] = param((1, 5), "cardinal hover->hover moves always kept (1..reach)", unit="cells", ge=1)
    footprint_radius: int = param(2, "sensor footprint (2r+1)^2: r", unit="cells", ge=0)
    sense_dt: float = param(0.1, "sampling of the trajectory for sensing", unit="s", gt=0)
    velocity_samples: float = param(0.1, "grid spacing of the dispersion sample X", unit="m/s", gt=0)
    vertex_speed: float = param(0.9, "X is the disk |v| <= vertex_speed * v_max (turns need room)", gt=0, le=0.99)

    def validate(self) -> None:
        """ValueError (one line, naming the setting) for a setting out of its declared range
        (:func:`aerohrl.config.validate`), durations with ``t_min >= t_max``, or a hover
        move beyond ``reach``."""
        try:
            validate(self)
        except ConfigError as e:
            raise ConfigError(f"lattice: {e}") from None
        if self.t_min >= self.t_max:
            raise ConfigError(f"lattice: need t_min < t_max, got {self.t_min:g} and {self.t_max:g}")
        if any(m > self.reach for m in self.hover_moves):
            raise ConfigError("lattice: hover_moves must lie in 1..reach")


# Semantic setting (4 m cells): 5 cells/s = 20 m/s, reach 10 cells, 15 x 15-cell footprint
SEMANTIC_LATTICE = LatticeConfig(v_max=5.0, a_max=5.0, reach=10, footprint_radius=7)


# --------------------------------------------------------------------------- math
def transfer_cost(x: np.ndarray, v: np.ndarray, rho: float, a_max: float) -> np.ndarray:
    """J(x, v): optimal cost of steering velocity ``x`` to ``v`` (broadcast over rows).

    With zero boundary accelerations the minimum-jerk velocity profile is the cubic
    ``x + (v - x)(3s^2 - 2s^3)``, ``s = t/T``: its jerk cost is ``12|dv|^2/T^3`` and its
    peak acceleration ``1.5|dv|/T``. ``J = min_T rho*T + 12|dv|^2/T^3`` subject to
    ``1.5|dv|/T <= a_max``; the unconstrained optimum is ``T = (36|dv|^2/rho)^(1/4)``.
    This ``J`` happens to be symmetric; Eq. 2.3's ``max(J(x,v), J(v,x))`` is kept
    literally in :func:`dispersion` all the same.
    """
    dv = np.linalg.norm(np.asarray(v, float) - np.asarray(x, float), axis=-1)
    t = np.maximum((36.0 * dv**2 / rho) ** 0.25, 1.5 * dv / a_max)
    with np.errstate(divide="ignore", invalid="ignore"):
        j = np.where(dv > 0, rho * t + 12.0 * dv**2 / np.maximum(t, 1e-12) ** 3, 0.0)
    return j


def dispersion(samples: np.ndarray, vertices: np.ndarray, rho: float, a_max: float) -> float:
    """Eq. 2.3: ``sup_x min_v max(J(x, v), J(v, x))`` over the sample set."""
    x = samples[:, None, :]
    v = vertices[None, :, :]
    d = np.maximum(transfer_cost(x, v, rho, a_max), transfer_cost(v, x, rho, a_max))
    return float(d.min(axis=1).max())


def velocity_samples(v_max: float, spacing: float) -> np.ndarray:
    """Dense grid sample of the velocity disk ``|v| <= v_max`` (the set X of Eq. 2.3)."""
    g = np.arange(-v_max, v_max + 1e-9, spacing)
    vx, vy = np.meshgrid(g, g, indexing="xy")
    pts = np.stack([vx.ravel(), vy.ravel()], axis=1)
    return pts[np.linalg.norm(pts, axis=1) <= v_max + 1e-9]


def select_vertices(cfg: LatticeConfig) -> tuple[np.ndarray, np.ndarray]:
    """Greedy dispersion minimisation: returns ``(vertices (V,2), d(V_k) (V,))``.

    Vertex 0 is hover; vertex k is the sample maximising ``min_v max(J(x,v), J(v,x))``
    over the first k vertices (farthest-point insertion, a 2-approximation of the
    dispersion-optimal set). ``d`` is non-increasing by construction.
    """
    X = velocity_samples(cfg.vertex_speed * cfg.v_max, cfg.velocity_samples)
    verts = [np.zeros(2)]
    near = np.maximum(transfer_cost(X, verts[0], cfg.rho, cfg.a_max), transfer_cost(verts[0], X, cfg.rho, cfg.a_max))
    disp = [float(near.max())]
    for _ in range(1, cfg.n_vertices):
        k = int(np.argmax(near))
        verts.append(X[k].copy())
        dk = np.maximum(transfer_cost(X, X[k], cfg.rho, cfg.a_max), transfer_cost(X[k], X, cfg.rho, cfg.a_max))
        near = np.minimum(near, dk)
        disp.append(float(near.max()))
    return np.array(verts), np.array(disp)


def quintic_coefficients(
    p0: float | np.ndarray, v0: float | np.ndarray, p1: float | np.ndarray, v1: float | np.ndarray, T: float | np.ndarray
) -> np.ndarray:
    """Minimum-jerk quintic with zero boundary accelerations, batched.

    ``p0, v0, p1, v1``: (..., 2); ``T``: (...). Returns (..., 2, 6) with
    ``p(t) = sum_k c_k t^k`` (c2 = 0 since a0 = 0).
    """
    p0, v0, p1, v1 = (np.asarray(a, float) for a in (p0, v0, p1, v1))
    T = np.asarray(T, float)[..., None]
    dp = p1 - p0 - v0 * T
    dv = v1 - v0
    c = np.zeros(np.broadcast_shapes(p0.shape, p1.shape, v0.shape, T.shape) + (6,))
    c[..., 0] = p0
    c[..., 1] = v0
    c[..., 3] = (20 * dp - 8 * dv * T) / (2 * T**3)
    c[..., 4] = (-30 * dp + 14 * dv * T) / (2 * T**4)
    c[..., 5] = (12 * dp - 6 * dv * T) / (2 * T**5)
    return c


def poly_eval(coef: np.ndarray, t: np.ndarray, deriv: int = 0) -> np.ndarray:
    """Evaluate ``d^k/dt^k sum_j c_j t^j``; ``coef`` (..., 6), ``t`` broadcastable to (..., S)."""
    out: np.ndarray | float = 0.0
    for j in range(deriv, 6):
        fac = 1.0
        for m in range(deriv):
            fac *= j - m
        out = out + fac * coef[..., j, None] * t ** (j - deriv)
    return cast(np.ndarray, out)  # an array once a term is added (deriv < 6)


def path_length(coef: np.ndarray, T: np.ndarray, n: int = 200) -> np.ndarray:
    """Arc length ``int_0^T |p'(t)| dt`` of polynomials ``coef`` (P, 2, 6) of durations
    ``T`` (P,), batched (trapezoid rule on ``n`` samples each)."""
    T = np.asarray(T, float)
    t = np.linspace(0.0, 1.0, n)[None, :] * T[:, None]  # (P, n)
    v = poly_eval(coef, t[:, None, :], deriv=1)  # (P, 2, n)
    sp = np.hypot(v[:, 0], v[:, 1])
    return np.trapezoid(sp, t, axis=1)


def jerk_cost(coef: np.ndarray, T: np.ndarray) -> np.ndarray:
    """``int_0^T |jerk|^2 dt`` summed over axes, closed form. coef (..., 2, 6), T (...)."""
    j0, j1, j2 = 6 * coef[..., 3], 24 * coef[..., 4], 60 * coef[..., 5]
    T = np.asarray(T, float)[..., None]
    val = j0**2 * T + j0 * j1 * T**2 + (j1**2 + 2 * j0 * j2) * T**3 / 3 + j1 * j2 * T**4 / 2 + j2**2 * T**5 / 5
    return val.sum(-1)


def peak_speed_accel(coef: np.ndarray, T: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Sampled maxima of |v(t)| and |a(t)| on [0, T] with ``n`` samples."""
    s = np.linspace(0.0, 1.0, n)
    t = np.asarray(T, float)[..., None, None] * s  # (..., 1, n) broadcast over axes
    v = poly_eval(coef, t, 1)
    a = poly_eval(coef, t, 2)
    return np.linalg.norm(v, axis=-2).max(-1), np.linalg.norm(a, axis=-2).max(-1)


# --------------------------------------------------------------------------- build
@dataclass
class Lattice:
    """A loaded or built lattice; see the module docstring for the arrays."""

    config: LatticeConfig
    vertices: np.ndarray
    dispersion: np.ndarray
    edges: np.ndarray
    prim_from: np.ndarray
    prim_to: np.ndarray
    prim_disp: np.ndarray
    prim_T: np.ndarray
    prim_cost: np.ndarray
    prim_coef: np.ndarray
    prim_bbox: np.ndarray
    meas_off: np.ndarray
    meas_level: np.ndarray
    cell_off: np.ndarray
    cell_count: np.ndarray
    _extra: dict = field(default_factory=dict, repr=False)

    @property
    def n_vertices(self) -> int:
        """The number of lattice vertices (velocity states)."""
        return len(self.vertices)

    @property
    def n_actions(self) -> int:
        """The number of action slots per vertex (outgoing edges, invalid ones padded)."""
        return self.edges.shape[1]

    @property
    def n_prims(self) -> int:
        """The number of motion primitives."""
        return len(self.prim_T)

    @property
    def n_levels(self) -> int:
        """The number of sensing levels (altitudes / footprint sizes) of the measurements."""
        return self.cell_count.shape[2]

    def positions(self, prim: int, origin: tuple[int, int] | np.ndarray = (0, 0), n: int = 50) -> np.ndarray:
        """Tiled trajectory of primitive ``prim`` started at cell ``origin``: (n, 2)."""
        t = np.linspace(0.0, self.prim_T[prim], n)
        p = poly_eval(self.prim_coef[prim], t[None, :])  # (2, n)
        return p.T + np.asarray(origin, float)

    @property
    def prim_length(self) -> np.ndarray:
        """(P,) arc length of every primitive in cells, ``int_0^T |p'(t)| dt`` (trapezoid
        on 200 samples; cached on the lattice)."""
        if "prim_length" not in self._extra:
            self._extra["prim_length"] = path_length(self.prim_coef, self.prim_T)
        return self._extra["prim_length"]

    def sensed_cells(self, prim: int, origin: tuple[int, int] | np.ndarray = (0, 0)) -> tuple[np.ndarray, np.ndarray]:
        """Tiled measurements of ``prim`` at ``origin``: cells (m, 2) and levels (m,)."""
        keep = self.meas_level[prim] >= 0
        return self.meas_off[prim][keep].astype(int) + np.asarray(origin, int), self.meas_level[prim][keep].astype(int)


def _candidates(cfg: LatticeConfig, verts: np.ndarray):
    """All feasible (i, j, d) primitives with their optimal durations (vectorised)."""
    V = len(verts)
    r = np.arange(-cfg.reach, cfg.reach + 1)
    D = np.stack(np.meshgrid(r, r, indexing="xy"), -1).reshape(-1, 2)
    I, J, K = np.meshgrid(np.arange(V), np.arange(V), np.arange(len(D)), indexing="ij")
    I, J, K = I.ravel(), J.ravel(), K.ravel()
    null = (I == J) & (np.abs(D[K]).sum(1) == 0) & (np.linalg.norm(verts[I], axis=1) == 0)
    I, J, K = I[~null], J[~null], K[~null]
    Ts = np.arange(cfg.t_min, cfg.t_max + 1e-9, cfg.t_step)
    best_T = np.full(len(I), np.nan)
    best_c = np.full(len(I), np.inf)
    for T in Ts:  # one vectorised pass per duration (a few dozen)
        coef = quintic_coefficients(0.0, verts[I], D[K].astype(float), verts[J], np.full(len(I), T))
        cost = cfg.rho * T + jerk_cost(coef, np.full(len(I), T))
        vpk, apk = peak_speed_accel(coef, np.full(len(I), T), 41)
        ok = (vpk <= cfg.v_max * 0.99) & (apk <= cfg.a_max * 0.99) & (cost < best_c)
        best_c[ok] = cost[ok]
        best_T[ok] = T
    feas = np.isfinite(best_c)
    return I[feas], J[feas], D[K[feas]], best_T[feas], best_c[feas]


def _select_edges(cfg: LatticeConfig, verts, I, J, D, T, C) -> list[int]:
    """Per vertex: seeds (cheapest to each successor, hover moves), then farthest-point."""
    chosen: list[int] = []
    for i in range(len(verts)):
        idx = np.flatnonzero(I == i)
        if len(idx) == 0:
            continue
        seeds: list[int] = []
        for j in range(len(verts)):
            cj = idx[J[idx] == j]
            if len(cj):
                seeds.append(int(cj[np.argmin(np.round(C[cj], 6))]))
        if i == 0:
            for m in cfg.hover_moves:
                for d in ((m, 0), (-m, 0), (0, m), (0, -m)):
                    hit = idx[(J[idx] == 0) & (D[idx, 0] == d[0]) & (D[idx, 1] == d[1])]
                    if len(hit):
                        seeds.append(int(hit[0]))
        seeds = list(dict.fromkeys(seeds))[: cfg.max_edges]
        feat = np.concatenate([D[idx].astype(float), cfg.tau * verts[J[idx]]], axis=1)
        pos = {int(p): k for k, p in enumerate(idx)}
        sel = [pos[s] for s in seeds]
        dmin = np.min(np.linalg.norm(feat[:, None] - feat[sel][None], axis=-1), axis=1)
        while len(sel) < min(cfg.max_edges, len(idx)):
            # rounded: ties between mirror images break by index, not by the last bit
            k = int(np.argmax(np.round(dmin, 9)))
            if dmin[k] <= 0:
                break
            sel.append(k)
            dmin = np.minimum(dmin, np.linalg.norm(feat - feat[k], axis=1))
        chosen.extend(int(idx[k]) for k in sel)
    return chosen


def _sensing(cfg: LatticeConfig, coef: np.ndarray, T: float):
    """Measurements of one primitive: offsets (m,2), levels (m,), visited centres (c,2)."""
    t: np.ndarray = np.arange(cfg.sense_dt, T + 1e-9, cfg.sense_dt)
    if len(t) == 0 or t[-1] < T - 1e-9:
        t = np.append(t, T)
    p = poly_eval(coef, t[None, :]).T  # (S, 2)
    cells = np.floor(p + 0.5).astype(int)
    centres = list(dict.fromkeys(map(tuple, cells)))
    r = cfg.footprint_radius
    fx, fy = np.meshgrid(np.arange(-r, r + 1), np.arange(-r, r + 1), indexing="xy")
    foot = np.stack([fx.ravel(), fy.ravel()], 1)
    lev = np.maximum(np.abs(foot[:, 0]), np.abs(foot[:, 1]))
    c = np.array(centres)
    off = (c[:, None, :] + foot[None]).reshape(-1, 2)
    return off, np.tile(lev, len(c)), c


def build_lattice(cfg: LatticeConfig | None = None) -> Lattice:
    """Build the lattice (a few seconds for the defaults)."""
    cfg = cfg or LatticeConfig()
    cfg.validate()
    verts, disp = select_vertices(cfg)
    I, J, D, T, C = _candidates(cfg, verts)
    if len(I) == 0:
        raise ValueError("lattice: no feasible primitive; raise t_max, v_max or a_max")
    chosen = _select_edges(cfg, verts, I, J, D, T, C)
    # order primitives by (from vertex, cost, displacement). Costs are rounded first: mirror-image
    # primitives have equal costs up to the last bit, and which bit wins depends on the machine's
    # SIMD summation order; unrounded, the shipped file's order would change from CPU to CPU.
    chosen = sorted(chosen, key=lambda k: (I[k], round(float(C[k]), 6), D[k, 0], D[k, 1], J[k]))
    I, J, D, T, C = I[chosen], J[chosen], D[chosen], T[chosen], C[chosen]
    P, V = len(I), len(verts)
    coef = quintic_coefficients(0.0, verts[I], D.astype(float), verts[J], T)
    # exact cost from the final coefficients (identical to the grid cost)
    C = cfg.rho * T + jerk_cost(coef, T)
    nlev = cfg.footprint_radius + 1
    sens = [_sensing(cfg, coef[p], T[p]) for p in range(P)]
    M = max(len(s[0]) for s in sens)
    cells = []
    for off, lev, _ in sens:
        u, inv = np.unique(off, axis=0, return_inverse=True)
        cnt = np.zeros((len(u), nlev), np.int64)
        np.add.at(cnt, (inv.ravel(), lev), 1)
        cells.append((u, cnt))
    U = max(len(u) for u, _ in cells)
    meas_off = np.zeros((P, M, 2), np.int16)
    meas_level = np.full((P, M), -1, np.int8)
    cell_off = np.zeros((P, U, 2), np.int16)
    cell_count = np.zeros((P, U, nlev), np.int16)
    bbox = np.zeros((P, 4), np.int32)
    for p, ((off, lev, cen), (u, cnt)) in enumerate(zip(sens, cells)):
        meas_off[p, : len(off)] = off
        meas_level[p, : len(off)] = lev
        cell_off[p, : len(u)] = u
        cell_count[p, : len(u)] = cnt
        bbox[p] = [cen[:, 0].min(), cen[:, 0].max(), cen[:, 1].min(), cen[:, 1].max()]
    A = max(int(np.bincount(I, minlength=V).max()), 1)
    edges = np.full((V, A), -1, np.int32)
    for v in range(V):
        ids = np.flatnonzero(I == v)
        edges[v, : len(ids)] = ids
    return Lattice(
        cfg,
        verts,
        disp,
        edges,
        I.astype(np.int32),
        J.astype(np.int32),
        D.astype(np.int32),
        T,
        C,
        coef,
        bbox,
        meas_off,
        meas_level,
        cell_off,
        cell_count,
    )


# ------------------------------------------------------------------------ file I/O
_ARRAYS = {  # name: (dtype kind, ndim)
    "vertices": ("f", 2),
    "dispersion": ("f", 1),
    "edges": ("i", 2),
    "prim_from": ("i", 1),
    "prim_to": ("i", 1),
    "prim_disp": ("i", 2),
    "prim_T": ("f", 1),
    "prim_cost": ("f", 1),
    "prim_coef": ("f", 3),
    "prim_bbox": ("i", 2),
    "meas_off": ("i", 3),
    "meas_level": ("i", 2),
    "cell_off": ("i", 3),
    "cell_count": ("i", 3),
}


def save_lattice(lat: Lattice, path: str | os.PathLike) -> Path:
    """Write ``lat`` to ``path`` (.npz) atomically (temp file, then rename)."""
    path = Path(path)
    meta = {"format": FORMAT, "version": VERSION, "config": asdict(lat.config)}
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            np.savez_compressed(f, meta=np.array(json.dumps(meta)), **{k: getattr(lat, k) for k in _ARRAYS})
    return path


def load_lattice(path: str | os.PathLike) -> Lattice:
    """Read and validate a lattice file; any defect raises a one-line ValueError."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"lattice file not found: {path}")
    try:
        with np.load(path, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
    except Exception as err:  # zipfile.BadZipFile, ValueError, OSError, ...
        raise ValueError(f"{path}: not a lattice file ({type(err).__name__})") from None
    try:
        meta = json.loads(str(data.pop("meta")))
    except Exception:
        raise ValueError(f"{path}: lattice file has no readable 'meta' entry") from None
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        raise ValueError(f"{path}: not a {FORMAT} file")
    if meta.get("version") != VERSION:
        raise ValueError(f"{path}: lattice format version {meta.get('version')} is not supported (expected {VERSION})")
    for k, (kind, nd) in _ARRAYS.items():
        if k not in data:
            raise ValueError(f"{path}: lattice file lacks array '{k}'")
        a = data[k]
        if a.ndim != nd or a.dtype.kind not in (kind + ("u" if kind == "i" else "")):
            raise ValueError(f"{path}: lattice array '{k}' has shape {a.shape} / dtype {a.dtype}")
    try:
        cfg_d = dict(meta["config"])
        cfg_d["hover_moves"] = tuple(cfg_d.get("hover_moves", ()))
        cfg = LatticeConfig(**cfg_d)
    except Exception:
        raise ValueError(f"{path}: lattice 'meta' has an invalid config") from None
    P = len(data["prim_T"])
    V = len(data["vertices"])
    e = data["edges"]
    checks = [
        (data["vertices"].shape[1] == 2, "vertices must be (V, 2)"),
        (len(data["dispersion"]) == V, "dispersion must have one entry per vertex"),
        (e.shape[0] == V and e.min(initial=-1) >= -1 and e.max(initial=-1) < P, "edges index outside the primitive table"),
        (
            all(
                len(data[k]) == P
                for k in (
                    "prim_from",
                    "prim_to",
                    "prim_disp",
                    "prim_cost",
                    "prim_coef",
                    "prim_bbox",
                    "meas_off",
                    "meas_level",
                    "cell_off",
                    "cell_count",
                )
            ),
            "primitive arrays disagree in length",
        ),
        (
            P == 0
            or (
                data["prim_from"].min() >= 0
                and data["prim_from"].max() < V
                and data["prim_to"].min() >= 0
                and data["prim_to"].max() < V
            ),
            "primitive vertex index out of range",
        ),
        (data["prim_coef"].shape[1:] == (2, 6), "prim_coef must be (P, 2, 6)"),
        (
            np.all(np.isfinite(data["prim_T"]))
            and np.all(data["prim_T"] > 0)
            and np.all(np.isfinite(data["prim_cost"]))
            and np.all(data["prim_cost"] > 0),
            "durations and costs must be positive and finite",
        ),
        (data["cell_count"].shape[2] == cfg.footprint_radius + 1, "cell_count levels disagree with footprint_radius"),
        (P > 0, "lattice has no primitives"),
    ]
    for ok, msg in checks:
        if not ok:
            raise ValueError(f"{path}: {msg}")
    return Lattice(cfg, **{k: data[k] for k in _ARRAYS})


@lru_cache(maxsize=4)
def _cached_build(cfg: LatticeConfig) -> Lattice:
    return build_lattice(cfg)


def default_lattice() -> Lattice:
    """The shipped lattice (ipp/data/lattice_default.npz), else built in memory."""
    if DEFAULT_PATH.is_file():
        return load_lattice(DEFAULT_PATH)
    return _cached_build(LatticeConfig())


def semantic_lattice() -> Lattice:
    """The shipped semantic lattice (ipp/data/lattice_semantic.npz = SEMANTIC_LATTICE):
    cells of 4 m, so 5 cells/s = 20 m/s, a 15 x 15-cell (60 m) footprint."""
    if SEMANTIC_PATH.is_file():
        return load_lattice(SEMANTIC_PATH)
    return _cached_build(SEMANTIC_LATTICE)


def get_lattice(path: str | os.PathLike | None, kind: str = "targets") -> Lattice:
    """The lattice at ``path`` (an ``ipp lattice build`` file), else the default lattice of
    ``kind`` (targets or semantic)."""
    if path is not None:
        return load_lattice(path)
    return semantic_lattice() if kind == "semantic" else default_lattice()


# ---------------------------------------------------------------------------- plot
def plot_lattice(lat: Lattice, path: str | os.PathLike) -> Path:
    """Figure: vertices in velocity space with d(V_k), and primitives per vertex."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    V = lat.n_vertices
    ncol = min(V, 5)
    nrow = 1 + (V + ncol - 1) // ncol
    fig, axes = plt.subplots(nrow, ncol, figsize=(3 * ncol, 3 * nrow), squeeze=False)
    for ax in axes.ravel():
        ax.set_visible(False)
    ax = axes[0, 0]
    ax.set_visible(True)
    th = np.linspace(0, 2 * np.pi, 100)
    ax.plot(lat.config.v_max * np.cos(th), lat.config.v_max * np.sin(th), "k:", lw=0.8)
    ax.scatter(lat.vertices[:, 0], lat.vertices[:, 1], c=np.arange(V), cmap="viridis")
    for k, v in enumerate(lat.vertices):
        ax.annotate(str(k), v, fontsize=7)
    ax.set_aspect("equal")
    ax.set_xlabel("v_x (m/s)", fontsize=8)
    ax.set_ylabel("v_y (m/s)", fontsize=8)
    ax.set_title(f"vertices (dotted: |v| = v_max = {lat.config.v_max:g} m/s)", fontsize=8)
    ax = axes[0, 1] if ncol > 1 else None
    if ax is not None:
        ax.set_visible(True)
        ax.plot(np.arange(1, V + 1), lat.dispersion, "o-")
        ax.set_xlabel("number of vertices k", fontsize=8)
        ax.set_ylabel("d(V_k) (cost units: rho*T + int |jerk|^2)", fontsize=7)
        ax.set_title("dispersion d(V) (Eq. 2.3)", fontsize=9)
    for v in range(V):
        ax = axes[1 + v // ncol, v % ncol]
        ax.set_visible(True)
        cmap = plt.get_cmap("viridis")
        for p in lat.edges[v][lat.edges[v] >= 0]:
            xy = lat.positions(int(p))
            ax.plot(xy[:, 0], xy[:, 1], lw=0.7, color=cmap(lat.prim_to[p] / max(V - 1, 1)))
        ax.plot(0, 0, "k.")
        ax.set_aspect("equal")
        ax.set_xlabel("x (cells = m)", fontsize=7)
        ax.set_ylabel("y (cells = m)", fontsize=7)
        ax.tick_params(labelsize=7)
        ax.set_title(f"vertex {v}: v=({lat.vertices[v, 0]:.1f},{lat.vertices[v, 1]:.1f})", fontsize=8)
    fig.tight_layout()
    sm = plt.cm.ScalarMappable(cmap="viridis", norm=plt.Normalize(0, max(V - 1, 1)))
    fig.colorbar(sm, ax=axes.ravel().tolist(), shrink=0.4, pad=0.01, label="vertex index (end vertex of a primitive)")
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=90, format="png")
    plt.close(fig)
    return Path(path)
