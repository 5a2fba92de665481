"""Distance-dependent binary sensor and the log-odds belief update (thesis Eq. 2.2).

A downward camera measures every cell of its ``(2r+1)^2`` footprint; the label of a
cell at Chebyshev distance ``d`` from the footprint centre is wrong with probability
``e(d) = err0 + err_slope * d`` (0.01, 0.11, 0.21 by default). With the symmetric
forward model ``p(z=1|m) = 1 - e``, ``p(z=1|~m) = e``, Eq. 2.2 becomes a sum of
log-likelihood ratios added to the prior log-odds::

    L(m | z_1:t) = L(m) + sum_t s_t * log((1 - e_t) / e_t),   s_t = +1 if z_t = 1 else -1

Measurement noise is drawn by a counter-based hash of (world seed, step, slot), so a
world sees the same noise sequence whatever the batch it runs in and whichever planner
drives it (common random numbers across planners).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from aerohrl.config import param


@dataclass(frozen=True)
class SensorConfig:
    err0: float = param(0.01, "classification error probability at the footprint centre", ge=0, le=0.5)
    err_slope: float = param(0.1, "error probability added per cell of Chebyshev distance from the centre", unit="1/cell", ge=0)
    logodds_clip: float = param(20.0, "bound on |log-odds| (numerical safety only)", gt=0)

    def error_levels(self, n_levels: int) -> np.ndarray:
        """Per sensing level (n_levels,): the classification error ``err0 + err_slope * level``,
        clipped to [1e-9, 0.5]."""
        e = self.err0 + self.err_slope * np.arange(n_levels)
        return np.clip(e, 1e-9, 0.5)


def logodds_step(err: np.ndarray) -> np.ndarray:
    """``log((1 - e) / e)``: the magnitude a measurement with error ``e`` adds (Eq. 2.2)."""
    err = np.asarray(err, float)
    return np.log1p(-err) - np.log(err)


def logodds_update(L: np.ndarray, z: np.ndarray, err: np.ndarray) -> np.ndarray:
    """Eq. 2.2 for one measurement per element: ``L + (+1 if z else -1) * log((1-e)/e)``."""
    return L + np.where(z, 1.0, -1.0) * logodds_step(err)


def measure(truth: np.ndarray, err: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Binary labels: the truth, flipped where the uniform draw ``u < err``."""
    return np.logical_xor(truth, u < err)


def sigmoid(L: np.ndarray) -> np.ndarray:
    """The logistic function ``1 / (1 + exp(-L))`` (log-odds -> probability), elementwise,
    as ``(1 + tanh(L / 2)) / 2`` (no overflow)."""
    return 0.5 * (1.0 + np.tanh(0.5 * L))


def logit(b: np.ndarray | float) -> np.ndarray:
    """Log-odds ``log(b) - log(1 - b)`` of probabilities ``b``, elementwise."""
    b = np.asarray(b, float)
    return np.log(b) - np.log1p(-b)


def entropy_bits(b: np.ndarray) -> np.ndarray:
    """Binary entropy in bits, safe at 0 and 1 (thesis Eq. 2.4 summand)."""
    b = np.clip(b, 1e-15, 1 - 1e-15)
    return -(b * np.log(b) + (1 - b) * np.log1p(-b)) * (1.0 / np.log(2.0))


def hashed_uniform(seed: np.ndarray, step: np.ndarray, slot: np.ndarray | int) -> np.ndarray:
    """Uniform [0,1) from splitmix64 of (seed, step, slot); arrays broadcast."""
    with np.errstate(over="ignore"):
        x = (
            np.asarray(seed, np.uint64) * np.uint64(0x9E3779B97F4A7C15)
            ^ np.asarray(step, np.uint64) * np.uint64(0xBF58476D1CE4E5B9)
            ^ np.asarray(slot, np.uint64) * np.uint64(0x94D049BB133111EB)
        )
        x = x + np.uint64(0x9E3779B97F4A7C15)
        x = (x ^ (x >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        x = (x ^ (x >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
        x = x ^ (x >> np.uint64(31))
    return (x >> np.uint64(11)).astype(np.float64) * (1.0 / (1 << 53))
