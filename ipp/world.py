"""Target-search worlds: Gaussian-mixture ground truth, a wrong prior, its KL divergence.

Thesis §2.5.3 "Environment Generation" and docs/spec.md: targets are drawn from a ground
truth Gaussian mixture (3-4 centres); the agent's prior shifts the true centres by a
random amount, mixes in spurious components and adds noise, so it is informative but
wrong to a random degree, measured by ``KL(truth || prior)``.

Every world ``i`` of a suite with seed ``s`` is generated from
``numpy.random.default_rng([s, i])`` alone, so world 7 is the same whatever the batch.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from aerohrl.config import param


TEST_SEED = 1000  # the test suite: worlds 0..n-1 of this suite seed (the bench's, never trained on)


@dataclass(frozen=True)
class WorldConfig:
    map_size: int = param(30, "cells per side (1 m cells)", unit="cells", ge=1)
    n_centres: tuple[int, int] = param((3, 4), "inclusive range of true mixture centres", ge=1)
    var_range: tuple[float, float] = param((30.0, 40.0), "range of the diagonal variances", unit="cells^2", gt=0)
    max_cov: float = param(15.0, "bound on |off-diagonal covariance|", unit="cells^2", ge=0)
    n_targets: tuple[int, int] = param((10, 29), "inclusive range of targets (distinct cells)", ge=0)
    shift_max: float = param(8.0, "prior centre shift std ~ U[0, shift_max]", unit="cells", ge=0)
    n_spurious: tuple[int, int] = param((1, 4), "inclusive range of spurious prior components", ge=0)
    spurious_var: tuple[float, float] = param((40.0, 50.0), "range of the spurious components' variances", unit="cells^2", gt=0)
    prior_peak: float = param(0.8, "prior belief = floor + peak * mixture/max + noise: the peak", ge=0)
    prior_floor: float = param(0.02, "the prior belief's floor", ge=0)
    prior_noise: float = param(0.05, "std of the prior belief's noise", ge=0)
    prior_clip: tuple[float, float] = param((0.01, 0.9), "the prior belief is clipped to this range", gt=0, lt=1)


@dataclass
class Worlds:
    """A batch of worlds (arrays over the inner ``map_size`` square, indexed [n, y, x])."""

    density: np.ndarray  # (N, H, W) true target distribution (sums to 1)
    targets: np.ndarray  # (N, H, W) bool
    prior: np.ndarray  # (N, H, W) prior belief P(target in cell)
    kl: np.ndarray  # (N,) KL(truth || normalised prior), nats
    kl_sym: np.ndarray  # (N,) KL(p||q) + KL(q||p)
    seeds: np.ndarray  # (N, 2) int64 (suite seed, index)

    def __len__(self) -> int:
        return len(self.kl)


def gmm_density(centres: np.ndarray, covs: np.ndarray, weights: np.ndarray, size: int) -> np.ndarray:
    """Mixture density on the cell centres of a ``size`` square (vectorised over cells)."""
    g = np.arange(size) + 0.0
    X, Y = np.meshgrid(g, g, indexing="xy")
    pts = np.stack([X, Y], -1)[None]  # (1, H, W, 2)
    d = pts - centres[:, None, None, :]  # (K, H, W, 2)
    inv = np.linalg.inv(covs)  # (K, 2, 2)
    m = np.einsum("khwi,kij,khwj->khw", d, inv, d)
    norm = 1.0 / (2 * np.pi * np.sqrt(np.linalg.det(covs)))
    return np.einsum("k,khw->hw", weights * norm, np.exp(-0.5 * m))


def _random_covs(rng, k, var_range, max_cov):
    a = rng.uniform(*var_range, size=(k, 2))
    c = rng.uniform(-max_cov, max_cov, size=k)
    return np.stack([np.stack([a[:, 0], c], -1), np.stack([c, a[:, 1]], -1)], 1)


def kl_divergence(p: np.ndarray, q: np.ndarray, eps: float = 1e-12) -> np.ndarray:
    """``sum p log(p/q)`` over the last two axes after normalising both to sum 1."""
    p = p / p.sum(axis=(-2, -1), keepdims=True)
    q = q / q.sum(axis=(-2, -1), keepdims=True)
    return np.sum(p * (np.log(p + eps) - np.log(q + eps)), axis=(-2, -1))


def make_world(cfg: WorldConfig, seed: int, index: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One world from ``default_rng([seed, index])``: (density, targets, prior)."""
    rng = np.random.default_rng([seed, index])
    S = cfg.map_size
    k = int(rng.integers(cfg.n_centres[0], cfg.n_centres[1] + 1))
    mu = rng.uniform(0.15 * S, 0.85 * S, size=(k, 2))
    cov = _random_covs(rng, k, cfg.var_range, cfg.max_cov)
    w = rng.dirichlet(np.full(k, 5.0))
    dens = gmm_density(mu, cov, w, S)
    dens = dens / dens.sum()
    nt = int(rng.integers(cfg.n_targets[0], cfg.n_targets[1] + 1))
    cells = rng.choice(S * S, size=nt, replace=False, p=dens.ravel())
    tg = np.zeros(S * S, bool)
    tg[cells] = True
    # prior: shifted true centres (trust w) + spurious components + noise
    trust = rng.uniform(0.0, 1.0)
    shift = rng.uniform(0.0, cfg.shift_max)
    mu_s = mu + rng.normal(0.0, shift, size=mu.shape) if shift > 0 else mu
    g1 = gmm_density(mu_s, cov, w, S)
    ks = int(rng.integers(cfg.n_spurious[0], cfg.n_spurious[1] + 1))
    g2 = gmm_density(
        rng.uniform(0, S, size=(ks, 2)), _random_covs(rng, ks, cfg.spurious_var, cfg.max_cov), np.full(ks, 1.0 / ks), S
    )
    mix = trust * g1 / g1.max() + (1 - trust) * g2 / g2.max()
    prior = cfg.prior_floor + cfg.prior_peak * mix / mix.max() + cfg.prior_noise * np.abs(rng.normal(size=(S, S)))
    prior = np.clip(prior, *cfg.prior_clip)
    return dens, tg.reshape(S, S), prior


def sample_worlds(cfg: WorldConfig, seed: int, indices: Sequence[int] | np.ndarray) -> Worlds:
    """Worlds ``indices`` of the suite ``seed`` (one Python iteration per world)."""
    idx = np.atleast_1d(np.asarray(indices, np.int64))
    out = [make_world(cfg, seed, int(i)) for i in idx]
    dens = np.stack([o[0] for o in out])
    tg = np.stack([o[1] for o in out])
    prior = np.stack([o[2] for o in out])
    kl = kl_divergence(dens, prior)
    kl_sym = kl + kl_divergence(prior, dens)
    seeds = np.stack([np.full_like(idx, seed), idx], 1)
    return Worlds(dens, tg, prior, kl, kl_sym, seeds)
