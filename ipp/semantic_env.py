"""Batched semantic feature detection environment (thesis §2.4.2-2.4.3, §2.6.3).

Same lattice, stepping, validity, cost and coverage as :class:`~aerohrl.ipp.env.SearchEnv`;
what changes (see :mod:`.semantic` for the world, sensor and belief):

* belief: ``L`` (N, Hp, Hp, C) float32 class log-scores, ``P = softmax(L)`` per cell,
  updated per touched cell with the multi-class Eq. 2.2 (one ``np.bincount`` over
  ``cell * C + label``, no per-cell loop);
* observation planes: the C class-probability maps, coverage, boundary (C + 2 planes);
* entropy (Eq. 2.4): categorical entropy in bits summed over the inner map;
* detection: a feature (non-background) cell is detected once ``P(true class)`` reaches
  ``found_threshold`` (0.95);
* rewards (§2.5.2): entropy ``15 * dH / H0``; coverage ``10 * new / S^2``; detection
  ``+20 per semantic category`` spread over its cells, i.e. ``20 * sum_c new_c / n_c``
  over the feature classes (20 * 4 = 80 for detecting every feature cell); cost
  ``-20`` over the budget; invalid ``-1``;
* metrics (Table 2.2): coverage %, entropy reduction %, search efficiency = detected
  feature cells / feature cells, %.
"""

from __future__ import annotations

import numpy as np

from .env import SearchEnv
from .scoring import LAM_CAP, crossing_lam, detect_success
from .sensor import hashed_uniform
from .semantic import SemanticWorlds, entropy_cat_bits, info_gain_cat, label_logratio, measure_labels, softmax


class SemanticEnv(SearchEnv):
    """``N`` semantic feature detection environments stepped together."""

    def __init__(self, cfg, lattice):
        super().__init__(cfg, lattice)
        self.n_classes = C = cfg.semantic.n_classes
        self.lam_levels = label_logratio(self.err_levels, C)

    def reset(self, worlds: SemanticWorlds, start: np.ndarray | None = None) -> dict:
        """Start every env on ``worlds``: class log-beliefs from the prior, nothing covered or
        found, agents at the start cells; returns the observation."""
        S, p, C = self.S, self.pad, self.n_classes
        N = len(worlds)
        self.n, self.worlds = N, worlds
        sl = (slice(None), slice(p, p + S), slice(p, p + S))
        self.truth = np.zeros((N, self.Hp, self.Hp), np.int8)
        self.truth[sl] = worlds.classes
        self.L = np.zeros((N, self.Hp, self.Hp, C), np.float32)
        self.L[sl] = np.log(np.maximum(worlds.prior, 1e-12))
        self.cov = np.zeros((N, self.Hp, self.Hp), bool)
        self.cov_ring = np.zeros((N, self.Hp, self.Hp), bool)
        self.found = np.zeros((N, self.Hp, self.Hp), bool)
        self.planes = np.zeros((N, C + 2, self.Hp, self.Hp), np.float32)
        self.planes[:, :C][:, :, p : p + S, p : p + S] = np.moveaxis(worlds.prior, -1, 1)
        self.planes[:, C + 1] = self.boundary
        cls = worlds.classes.reshape(N, -1).astype(np.int64)
        self.n_class = np.stack([np.bincount(c, minlength=C) for c in cls])  # (N, C)
        self._common_reset(worlds, start)
        self.n_targets = self.n_class[:, 1:].sum(1)
        return self.observe()

    # ---------------------------------------------------------------- queries
    def probs(self) -> np.ndarray:
        """(N, S, S, C) current class probabilities on the inner map."""
        p, S = self.pad, self.S
        return softmax(self.L[:, p : p + S, p : p + S].astype(np.float64))

    def belief(self) -> np.ndarray:
        """(N, S, S) probability that a cell holds a feature (not background)."""
        return 1.0 - self.probs()[..., 0]

    def _entropy(self) -> np.ndarray:
        return entropy_cat_bits(self.probs()).reshape(self.n, -1).sum(1)

    def detected_by_class(self) -> np.ndarray:
        """(N, C) detected cells per class (column 0, background, is never counted)."""
        p, S, C = self.pad, self.S, self.n_classes
        f = self.found[:, p : p + S, p : p + S].reshape(self.n, -1)
        t = self.worlds.classes.reshape(self.n, -1).astype(np.int64)
        return np.stack([np.bincount(t[n][f[n]], minlength=C) for n in range(self.n)])

    # ------------------------------------------------------------------ update
    def _apply(self, idx: np.ndarray, pr: np.ndarray):
        cfg, lat, C = self.cfg, self.lat, self.n_classes
        HH = self.Hp * self.Hp
        lev = lat.meas_level[pr].astype(np.int64)  # (k, M)
        off = lat.meas_off[pr].astype(np.int64)
        flat = self.flat_index(off, idx)
        x = self.pos[idx, 0, None] + off[..., 0]
        y = self.pos[idx, 1, None] + off[..., 1]
        use = (lev >= 0) & (x >= 0) & (x < self.S) & (y >= 0) & (y < self.S)
        levc = np.maximum(lev, 0)
        slot = np.arange(lev.shape[1])[None, :]
        u1 = hashed_uniform(self._seed_key[idx, None], self.steps[idx, None], 2 * slot)
        u2 = hashed_uniform(self._seed_key[idx, None], self.steps[idx, None], 2 * slot + 1)
        truth = self.truth.reshape(-1)[flat].astype(np.int64)
        z = measure_labels(truth, self.err_levels[levc], u1, u2, C)
        f, zz, w = flat[use], z[use], self.lam_levels[levc][use]
        cells, inv = np.unique(f, return_inverse=True)
        # multi-class Eq. 2.2: each label adds log((1-e)(C-1)/e) to its class's score
        add = np.bincount(inv * C + zz, weights=w, minlength=len(cells) * C).reshape(-1, C)
        Lc = self.L.reshape(-1, C)
        old = Lc[cells].astype(np.float64)
        new = old + add
        new -= new.max(-1, keepdims=True)  # softmax-invariant re-centring
        new = np.maximum(new, -60.0)
        Lc[cells] = new
        p_old, p_new = softmax(old), softmax(new)
        env_of = cells // HH
        local = cells % HH
        dH = entropy_cat_bits(p_new) - entropy_cat_bits(p_old)
        Hn = self.H + np.bincount(env_of, weights=dH, minlength=self.n)
        covf = self.cov.reshape(-1)
        newcov = ~covf[cells]
        covf[cells] = True
        ncov = self.n_cov + np.bincount(env_of[newcov], minlength=self.n)
        P = C + 2
        pl = self.planes.reshape(-1)
        base = env_of * (P * HH) + local
        pl[base[:, None] + np.arange(C)[None, :] * HH] = p_new
        pl[base + C * HH] = 1.0
        tc = self.truth.reshape(-1)[cells].astype(np.int64)
        foundf = self.found.reshape(-1)
        hit = (tc > 0) & (p_new[np.arange(len(cells)), tc] >= cfg.found_threshold) & ~foundf[cells]
        foundf[cells[hit]] = True
        nf = np.bincount(env_of[hit], minlength=self.n)
        # +r_target per semantic category, spread over the category's cells
        frac = 1.0 / np.maximum(self.n_class[env_of[hit], tc[hit]], 1)
        rt = cfg.r_target * np.bincount(env_of[hit], weights=frac, minlength=self.n)
        return Hn, ncov, nf, rt

    # ------------------------------------------------- planner hooks (baselines.py)
    def plan_cells(self, n_idx: np.ndarray, flat: np.ndarray) -> np.ndarray:
        """(…, C) class probabilities at padded flat cells ``flat`` of envs ``n_idx``
        (read from the observation planes, which hold softmax(L) on the inner map)."""
        C, HH = self.n_classes, self.Hp * self.Hp
        pl = self.planes.reshape(self.n, -1)
        n_idx, flat = np.broadcast_arrays(n_idx, flat)
        return pl[n_idx[..., None], flat[..., None] + np.arange(C) * HH]  # float32: speed

    def plan_ig(self, b: np.ndarray, lam: np.ndarray | float) -> np.ndarray:
        """Expected information gain (bits) of sensing cells with class beliefs ``b`` (..., C)
        with total log-ratio ``lam``."""
        return info_gain_cat(b, np.asarray(lam, b.dtype))

    def plan_prio(self, b: np.ndarray) -> np.ndarray:
        """Probability that the cell holds a feature: ``1 - P(background)`` of ``b`` (..., C)."""
        return 1.0 - b[..., 0]

    def plan_entropy(self, b: np.ndarray) -> np.ndarray:
        """The planner's entropy term: categorical entropy (bits) of ``b`` (..., C) per cell."""
        return entropy_cat_bits(b)

    def prio_map(self) -> np.ndarray:
        """(N, Hp, Hp) float32 :meth:`plan_prio` of every cell (valid on the inner map)."""
        return 1.0 - self.planes[:, 0]

    def plan_detect(self, b: np.ndarray, lam: np.ndarray | float) -> np.ndarray:
        """sum_{c>0} P(c) P(label c) [posterior of c after label c >= threshold].

        One label with the equivalent error ``e = 1 / (1 + exp(lam)/(C-1))`` (``lam``
        capped at 50) is correct with probability ``s = 1 - e``; after label ``c`` the
        posterior of ``c`` is ``b_c (1-e) / (b_c (1-e) + (1-b_c) e/(C-1))``, which reaches
        the threshold exactly when ``logit(b_c) + lam >= logit(threshold)`` (the
        likelihood ratio of the label is ``(1-e)(C-1)/e = exp(lam)``). That threshold
        form is what is computed (the fast path of :mod:`.features` uses the same test)."""
        lam_e = np.minimum(lam, LAM_CAP)
        bf = np.asarray(b, np.float64)[..., 1:]
        return detect_success(lam_e, self.n_classes) * (
            bf * (lam_e[..., None] >= crossing_lam(bf, self.cfg.found_threshold))
        ).sum(-1)

    def plan_detect_gain_flat(self, gflat: np.ndarray, lp: np.ndarray, lam: np.ndarray) -> np.ndarray:
        """:meth:`plan_detect_gain` at flat indices into the ``(N, Hp, Hp)`` maps."""
        HH = self.Hp * self.Hp
        return self.plan_detect_gain(self.plan_cells(gflat // HH, gflat % HH), lp, lam)

    def plan_open(self, b: np.ndarray) -> np.ndarray:
        """Cells whose most likely feature class is still below the threshold."""
        return b[..., 1:].max(-1) < self.cfg.found_threshold


__all__ = ["SemanticEnv", "LAM_CAP", "detect_success", "crossing_lam"]
