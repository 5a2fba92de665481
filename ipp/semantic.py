"""Semantic feature detection worlds (thesis §2.4.2-2.4.3, §2.5.3, §2.6.3).

The thesis maps university campuses from OpenStreetMap to 256 x 256 class rasters at
4 m per cell and keeps one belief map per semantic class plus background. OpenStreetMap
is not reachable here, so the default worlds are *procedural campus maps* with the same
layout ingredients, and :func:`load_class_raster` reads a class raster the user
exported from OpenStreetMap (or anything else) instead.

Classes (index, name): 0 background, 1 building, 2 road, 3 vegetation, 4 water.

Procedural campus (:func:`campus_map`, all array operations, no per-cell loops): a
jittered street grid plus one diagonal avenue (roads, 2-3 cells = 8-12 m wide),
rectangular buildings of 6-22 cells placed off the roads, parks from thresholded
smoothed noise, and a pond (noisy ellipse) and/or a river (a band around a smooth
random curve). Precedence: water > road > building > vegetation > background.

Prior (thesis §2.5.3: "a GMM is approximately fit over each semantic feature ground
truth distribution ... random noise is injected into the weights"): per class, the
class indicator smoothed by a Gaussian (``prior_sigma`` cells; a dense mixture of
Gaussians centred on the class's cells), shifted by a random offset
(``N(0, U[0, shift_max])`` cells per class) and scaled by a random weight
``exp(N(0, weight_noise))``, plus a floor; normalised over the classes per cell. The
prior's deviation from the truth is ``mean_cells -log prior[true class]`` (the KL of the
one-hot truth from the prior, in nats per cell).

Sensor (§2.4.3): the camera returns one label ``z in {0..C-1}`` per footprint cell,
correct with probability ``1 - e(d)`` and otherwise uniformly one of the other ``C-1``
classes; ``e(d) = err0 + err_slope * d`` grows with the Chebyshev distance ``d`` from the
footprint centre. The belief is categorical per cell (the C per-class maps sum to 1);
Bayes' rule in log space is the multi-class form of Eq. 2.2::

    l_c <- l_c + log p(z | m = c),   P(m = c) = softmax(l)_c

and since ``p(z|c)`` is ``1-e`` for ``c = z`` and ``e/(C-1)`` otherwise, the update adds
``log((1-e)(C-1)/e)`` to ``l_z`` alone (constants cancel in the softmax). With two
classes this is exactly Eq. 2.2. A feature cell counts as *detected* once the
probability of its true class reaches the threshold (0.95, §2.4.2).

Raster file formats for :func:`load_class_raster`:

* ``.npy``: a 2-D integer array of class indices ``0..C-1`` (0 = background);
* ``.npz``: the same under the key ``classes`` (or the only array in the file);
* ``.png``: read with ``matplotlib.pyplot.imread``; a greyscale image holds class
  indices as grey levels ``0, 1, 2, ...`` (8-bit values, i.e. ``k/255``); an RGB(A)
  image is matched exactly against :data:`PALETTE` (one colour per class).

The raster is resampled to ``map_size`` x ``map_size`` by nearest-neighbour (a raster
exported at 4 m per cell over 1024 m is already 256 x 256). Any defect raises a
one-line ``ValueError``.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Sequence

import numpy as np

from aerohrl.config import param


CLASSES = ("background", "building", "road", "vegetation", "water")
# RGB palette for PNG rasters (and the figures): one colour per class
PALETTE = np.array([[255, 255, 255], [200, 60, 60], [90, 90, 90], [60, 160, 60], [50, 110, 220]], np.uint8)


@dataclass(frozen=True)
class SemanticConfig:
    """Semantic worlds: procedural campus maps (or a user raster) and wrong priors."""

    map_size: int = param(256, "cells per side (4 m cells: 1024 m)", unit="cells", ge=1)
    cell_m: float = param(4.0, "metres per cell (documentation and figures)", unit="m", gt=0)
    n_classes: int = param(len(CLASSES), "classes, background included", ge=2, le=16)
    raster: str | None = param(None, "class raster file (none: procedural campus maps)")
    prior_sigma: float = param(6.0, "smoothing of the class indicators", unit="cells", ge=0)
    shift_max: float = param(12.0, "std of the per-class prior shift ~ U[0, shift_max]", unit="cells", ge=0)
    weight_noise: float = param(0.5, "std of the log weight noise per class", ge=0)
    prior_floor: float = param(0.02, "added to every class before normalising", ge=0)


# ------------------------------------------------------------------ procedural map
def campus_map(rng: np.random.Generator, size: int = 256) -> np.ndarray:
    """(size, size) int8 class map of a procedural campus (see the module docstring)."""
    from scipy.ndimage import gaussian_filter  # here: the config classes stay scipy-free (--help)

    S = size
    g = np.arange(S, dtype=float)
    X, Y = np.meshgrid(g, g, indexing="xy")
    out = np.zeros((S, S), np.int8)
    # parks: smoothed noise above a random quantile
    noise = gaussian_filter(rng.normal(size=(S, S)), sigma=S / 32)
    veg = noise > np.quantile(noise, rng.uniform(0.55, 0.75))
    # buildings: random rectangles
    k = int(rng.integers(40, 80))
    cx, cy = rng.uniform(0, S, k), rng.uniform(0, S, k)
    hw, hh = rng.uniform(3, 11, k), rng.uniform(3, 11, k)
    bld = (
        (np.abs(X[None] - cx[:, None, None]) < hw[:, None, None]) & (np.abs(Y[None] - cy[:, None, None]) < hh[:, None, None])
    ).any(0)
    # roads: jittered grid plus a diagonal avenue
    road = np.zeros((S, S), bool)
    for axis_coord in (X, Y):
        spacing = rng.uniform(0.18, 0.3) * S
        lines: np.ndarray = np.arange(rng.uniform(0.1, 0.25) * S, S, spacing)
        lines = lines + rng.normal(0, 0.02 * S, len(lines))
        width = rng.uniform(1.0, 1.6, len(lines))
        road |= (np.abs(axis_coord[None] - lines[:, None, None]) < width[:, None, None]).any(0)
    ang = rng.uniform(0, np.pi)
    off = rng.uniform(-0.2, 0.2) * S
    d = (X - S / 2) * np.sin(ang) - (Y - S / 2) * np.cos(ang) - off
    road |= np.abs(d) < rng.uniform(1.0, 1.8)
    # water: a pond (noisy ellipse) and/or a river (band around a smooth curve)
    water = np.zeros((S, S), bool)
    wnoise = gaussian_filter(rng.normal(size=(S, S)), sigma=S / 40)
    wnoise /= wnoise.std() + 1e-12
    if rng.random() < 0.8:
        px, py = rng.uniform(0.2, 0.8, 2) * S
        rx, ry = rng.uniform(0.04, 0.1, 2) * S
        water |= ((X - px) / rx) ** 2 + ((Y - py) / ry) ** 2 < 1 + 0.35 * wnoise
    if rng.random() < 0.5:
        t = rng.normal(size=S)
        curve = gaussian_filter(t, sigma=S / 10) * S / 4 + rng.uniform(0.2, 0.8) * S
        halfw = rng.uniform(2.0, 5.0)
        if rng.random() < 0.5:
            water |= np.abs(Y - curve[None, :]) < halfw
        else:
            water |= np.abs(X - curve[:, None]) < halfw
    # buildings keep clear of roads and water (a 2-cell margin)
    near = gaussian_filter((road | water).astype(float), 1.5) > 0.02
    bld &= ~near
    out[veg] = 3
    out[bld] = 1
    out[road] = 2
    out[water] = 4
    return out


# --------------------------------------------------------------------- raster I/O
def _resample(a: np.ndarray, size: int) -> np.ndarray:
    """Nearest-neighbour resampling of a 2-D class raster to ``size`` x ``size``."""
    H, W = a.shape
    yi = np.minimum(((np.arange(size) + 0.5) * H / size).astype(int), H - 1)
    xi = np.minimum(((np.arange(size) + 0.5) * W / size).astype(int), W - 1)
    return a[yi[:, None], xi[None, :]]


def _from_png(path: Path, n_classes: int) -> np.ndarray:
    import matplotlib.pyplot as plt

    try:
        img = plt.imread(path)
    except Exception as e:
        raise ValueError(f"{path}: cannot read PNG ({type(e).__name__})") from None
    if img.dtype.kind == "f":
        img8 = np.rint(np.asarray(img, float) * 255).astype(np.int64)
    else:
        img8 = np.asarray(img, np.int64)
    if img8.ndim == 2:
        return img8
    if img8.ndim == 3 and img8.shape[2] in (3, 4):
        rgb = img8[..., :3]
        if img8.shape[2] == 4 and np.any(img8[..., 3] < 255):
            raise ValueError(f"{path}: transparent pixels in the class raster")
        if np.all(rgb == rgb[..., :1]):  # grey stored as RGB
            return rgb[..., 0]
        match = np.all(rgb[:, :, None, :] == PALETTE[None, None, :n_classes].astype(np.int64), -1)
        if not match.any(-1).all():
            bad = rgb[~match.any(-1)][0]
            raise ValueError(
                f"{path}: colour {tuple(int(v) for v in bad)} is not in the class palette (see aerohrl.ipp.semantic.PALETTE)"
            )
        return match.argmax(-1)
    raise ValueError(f"{path}: PNG must be greyscale or RGB(A), got shape {img8.shape}")


def load_class_raster(path: str | os.PathLike, size: int = 256, n_classes: int = len(CLASSES)) -> np.ndarray:
    """Read a class raster (``.npy``, ``.npz``, ``.png``; module docstring) -> (size, size) int8."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"class raster {path} not found")
    ext = path.suffix.lower()
    if ext == ".png":
        a = _from_png(path, n_classes)
    elif ext in (".npy", ".npz"):
        try:
            z = np.load(path, allow_pickle=False)
        except Exception as e:
            raise ValueError(f"{path}: not a numpy file ({type(e).__name__})") from None
        if ext == ".npz":
            with z:
                keys = list(z.files)
                if "classes" in keys:
                    a = z["classes"]
                elif len(keys) == 1:
                    a = z[keys[0]]
                else:
                    raise ValueError(f"{path}: no 'classes' array (found {', '.join(keys) or 'none'})")
        else:
            a = z
    else:
        raise ValueError(f"{path}: unsupported raster type {ext or '(none)'} (.npy, .npz, .png)")
    a = np.asarray(a)
    if a.ndim != 2:
        raise ValueError(f"{path}: class raster must be 2-D, got shape {a.shape}")
    if min(a.shape) < 8:
        raise ValueError(f"{path}: class raster {a.shape[1]}x{a.shape[0]} is too small (>= 8x8)")
    if a.dtype.kind == "f":
        if not np.all(np.isfinite(a)) or not np.all(a == np.round(a)):
            raise ValueError(f"{path}: class raster must hold integer class indices")
    elif a.dtype.kind not in "iub":
        raise ValueError(f"{path}: class raster must hold integer class indices, got {a.dtype}")
    a = a.astype(np.int64)
    if a.min() < 0 or a.max() >= n_classes:
        raise ValueError(
            f"{path}: class indices must lie in 0..{n_classes - 1} ({', '.join(CLASSES[:n_classes])}), found {a.min()}..{a.max()}"
        )
    a = _resample(a, size).astype(np.int8)
    if not (a > 0).any():
        raise ValueError(f"{path}: the raster has no feature cells (all background)")
    return a


@lru_cache(maxsize=4)
def _cached_raster(path: str, mtime: float, size: int, n_classes: int) -> np.ndarray:
    return load_class_raster(path, size, n_classes)


# ------------------------------------------------------------------------ worlds
@dataclass
class SemanticWorlds:
    """A batch of semantic worlds over the inner ``map_size`` square, indexed [n, y, x]."""

    classes: np.ndarray  # (N, S, S) int8 true class
    prior: np.ndarray  # (N, S, S, C) float32 prior class probabilities
    kl: np.ndarray  # (N,) mean over cells of -log prior[true class], nats
    seeds: np.ndarray  # (N, 2) int64 (suite seed, index)

    def __len__(self) -> int:
        return len(self.kl)

    @property
    def targets(self) -> np.ndarray:  # feature cells (non-background), for counts
        """(N, S, S) bool: the feature cells (class > 0), for the target counts."""
        return self.classes > 0


def semantic_prior(rng: np.random.Generator, classes: np.ndarray, cfg: SemanticConfig) -> np.ndarray:
    """(S, S, C) prior class probabilities: smoothed, shifted, re-weighted indicators."""
    from scipy.ndimage import gaussian_filter, shift as nd_shift

    C = cfg.n_classes
    out = np.empty(classes.shape + (C,), np.float64)
    for c in range(C):  # one filter per class (C = 5), not per cell
        ind = gaussian_filter((classes == c).astype(float), cfg.prior_sigma, mode="nearest")
        sd = rng.uniform(0, cfg.shift_max)
        d = rng.normal(0, sd, 2) if sd > 0 else np.zeros(2)
        ind = nd_shift(ind, d, order=1, mode="nearest")
        out[..., c] = np.clip(ind, 0, None) * np.exp(rng.normal(0, cfg.weight_noise)) + cfg.prior_floor
    out /= out.sum(-1, keepdims=True)
    return out.astype(np.float32)


def make_semantic_world(cfg: SemanticConfig, seed: int, index: int) -> tuple[np.ndarray, np.ndarray]:
    """World ``index`` of suite ``seed``: (classes, prior). A raster fixes the classes."""
    rng = np.random.default_rng([seed, index, 2])
    if cfg.raster is not None:
        p = Path(cfg.raster)
        mt = p.stat().st_mtime if p.is_file() else -1.0
        classes = _cached_raster(str(p), mt, cfg.map_size, cfg.n_classes)
    else:
        classes = campus_map(rng, cfg.map_size)
    return classes, semantic_prior(rng, classes, cfg)


def sample_semantic_worlds(cfg: SemanticConfig, seed: int, indices: Sequence[int] | np.ndarray) -> SemanticWorlds:
    """Worlds ``indices`` of suite ``seed``: classes (N, S, S), prior (N, S, S, C), the
    KL(truth || prior) per world and the seeds."""
    idx = np.atleast_1d(np.asarray(indices, np.int64))
    out = [make_semantic_world(cfg, seed, int(i)) for i in idx]
    cls = np.stack([o[0] for o in out])
    prior = np.stack([o[1] for o in out])
    pt = np.take_along_axis(prior, cls[..., None].astype(np.int64), -1)[..., 0]
    kl = -np.log(np.maximum(pt, 1e-12)).reshape(len(idx), -1).mean(1)
    seeds = np.stack([np.full_like(idx, seed), idx], 1)
    return SemanticWorlds(cls, prior, kl.astype(np.float64), seeds)


# ------------------------------------------------------------------------ sensor
def label_logratio(err: np.ndarray, n_classes: int) -> np.ndarray:
    """``log((1-e)(C-1)/e)``: what one label with error ``e`` adds to ``l_z``."""
    err = np.asarray(err, float)
    return np.log1p(-err) + np.log(n_classes - 1) - np.log(err)


def measure_labels(truth: np.ndarray, err: np.ndarray, u1: np.ndarray, u2: np.ndarray, n_classes: int) -> np.ndarray:
    """Labels: the true class, or (where ``u1 < err``) one of the other classes by ``u2``."""
    wrong = u1 < err
    k = np.minimum((u2 * (n_classes - 1)).astype(np.int64), n_classes - 2)
    other = k + (k >= truth)  # skip the true class
    return np.where(wrong, other, truth).astype(np.int64)


def categorical_update(l: np.ndarray, z: np.ndarray, err: np.ndarray) -> np.ndarray:
    """Multi-class Eq. 2.2 for one label per row: ``l[..., z] += log((1-e)(C-1)/e)``."""
    l = np.array(l, float, copy=True)
    zi = np.asarray(z, np.int64)[..., None]
    inc = label_logratio(np.broadcast_to(err, zi.shape[:-1]), l.shape[-1])[..., None]
    np.put_along_axis(l, zi, np.take_along_axis(l, zi, -1) + inc, -1)
    return l


def softmax(l: np.ndarray) -> np.ndarray:
    """``softmax(l)`` over the last axis (class log-odds -> probabilities), shape kept."""
    e = np.exp(l - l.max(-1, keepdims=True))
    return e / e.sum(-1, keepdims=True)


def entropy_cat_bits(p: np.ndarray) -> np.ndarray:
    """Categorical entropy in bits over the last axis (Eq. 2.4 summand, C classes)."""
    p = np.clip(p, 1e-15, 1.0)
    return -(p * np.log(p)).sum(-1) / np.log(2.0)


def info_gain_cat(p: np.ndarray, lam: np.ndarray) -> np.ndarray:
    """Expected entropy reduction (bits) of a cell with class probabilities ``p`` (..., C)
    sensed with total label log-ratio ``lam``, as one label with the equivalent error
    ``e = 1 / (1 + exp(lam)/(C-1))``: ``H(p) - sum_z P(z) H(p | z)``.

    The symmetric confusion model makes every posterior a rescaling of ``p``, so the
    expectation is O(C) per cell (not O(C^2)):
    ``P(z) = (1-e) p_z + q (1 - p_z)`` with ``q = e/(C-1)``, and
    ``P(z) H(p|z) = -(1-e) p_z ln post_z - q [sum_{c!=z} p_c ln p_c + (1-p_z) ln(q/P(z))]``.
    """
    C = p.shape[-1]
    p = np.clip(p, 1e-15 if p.dtype == np.float64 else 1e-30, 1.0)
    e = (1.0 / (1.0 + np.exp(np.minimum(lam, 50.0)) / (C - 1)))[..., None].astype(p.dtype)
    q = e / (C - 1)
    pz = (1 - e) * p + q * (1 - p)
    plnp = p * np.log(p)
    S_ = plnp.sum(-1, keepdims=True)
    post_z = (1 - e) * p / pz
    eh = -(1 - e) * p * np.log(post_z) - q * ((S_ - plnp) + (1 - p) * np.log(q / pz))
    return (-S_[..., 0] - eh.sum(-1)) / np.log(2.0)


def _info_gain_cat_direct(p: np.ndarray, lam: np.ndarray) -> np.ndarray:
    """O(C^2) reference of :func:`info_gain_cat` (tests)."""
    C = p.shape[-1]
    e = 1.0 / (1.0 + np.exp(np.minimum(lam, 50.0)) / (C - 1))
    lik = np.where(np.eye(C, dtype=bool), (1 - e)[..., None, None], (e / (C - 1))[..., None, None])  # (..., z, c)
    joint = lik * p[..., None, :]
    pz = joint.sum(-1)
    post = joint / np.maximum(pz[..., None], 1e-300)
    return entropy_cat_bits(p) - (pz * entropy_cat_bits(post)).sum(-1)


def class_rgb(classes: np.ndarray) -> np.ndarray:
    """RGB colours (..., 3) of class indices ``classes`` (:data:`PALETTE`)."""
    return PALETTE[np.asarray(classes, np.int64)]
