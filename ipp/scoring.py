"""Shared scoring of sensed cells: the one module both the environments and the planners use.

Every function is a pure, batched numpy function of arrays (any shape, broadcast):

* :func:`info_gain` — expected entropy reduction (bits) of a cell of belief ``b`` sensed
  with summed log-odds magnitude ``lam`` (thesis Eq. 2.2 for the update, Eq. 2.4–2.5
  for the entropy): the measurements are taken as one with error ``e = sigmoid(-lam)``,
  ``IG = H(b) - E_z H(b | z)``, ``P(z=1) = b(1-e) + (1-b)e``.
* :func:`detect_prob` — P(the cell is a target *and* its belief crosses the found
  threshold) after sensing with ``lam`` (the same one-measurement equivalent).
* :func:`detect_success`, :func:`crossing_lam`, :data:`LAM_CAP` — the categorical
  (semantic, ``C`` classes) counterparts used by the semantic environment and the
  features' fast path.

The dependency graph of :mod:`aerohrl.ipp` is acyclic: ``sensor`` / ``scoring`` <-
``env`` <- ``semantic_env`` <- ``factory``; planners (``baselines``, ``policy``) import
environments, never the reverse (tests/test_ipp_imports.py checks it).
"""

from __future__ import annotations

import numpy as np

from .sensor import entropy_bits, logit, sigmoid

LAM_CAP = 50.0  # cap of the summed label log-ratio in the detection model (exp overflow)


def info_gain(b: np.ndarray, lam: np.ndarray) -> np.ndarray:
    """Expected entropy reduction (bits) of a cell with belief ``b`` sensed with ``lam``."""
    e = sigmoid(-lam)
    pz1 = b * (1 - e) + (1 - b) * e
    pz1 = np.clip(pz1, 1e-12, 1 - 1e-12)
    post1 = b * (1 - e) / pz1
    post0 = b * e / (1 - pz1)
    return entropy_bits(b) - pz1 * entropy_bits(post1) - (1 - pz1) * entropy_bits(post0)


def detect_prob(b: np.ndarray, lam: np.ndarray, threshold: float) -> np.ndarray:
    """P(target and detected) of a cell of belief ``b`` sensed with ``lam`` (Eq. 2.2 as one
    measurement of error ``sigmoid(-lam)``; detected = posterior >= ``threshold``)."""
    L = logit(np.clip(b, 1e-12, 1 - 1e-12))
    thr = logit(threshold)
    e = sigmoid(-lam)
    return b * ((1 - e) * (L + lam >= thr) + e * (L - lam >= thr))


def detect_success(lam_e: np.ndarray, n_classes: int) -> np.ndarray:
    """``1 - e``: the one-measurement equivalent of summed label log-ratio ``lam_e``
    (already capped) returns the true class."""
    return 1.0 - 1.0 / (1.0 + np.exp(lam_e) / (n_classes - 1))


def crossing_lam(b: np.ndarray, threshold: float) -> np.ndarray:
    """``logit(threshold) - logit(b)``: the summed label log-ratio at which a class of
    probability ``b`` reaches ``threshold`` (+inf for b = 0, -inf for b = 1)."""
    with np.errstate(divide="ignore"):
        return logit(threshold) - (np.log(b) - np.log1p(-b))


__all__ = ["LAM_CAP", "info_gain", "detect_prob", "detect_success", "crossing_lam"]
