"""Rotation helpers on batches of 3x3 matrices (docs/spec.md: R maps body to world,
flattened row-major; body rates in the body frame).

Conversions (quaternions, Euler angles, rotation vectors) are delegated to
:class:`scipy.spatial.transform.Rotation`. ``hat``/``vee`` and the polar
re-orthonormalisation are written out by hand: they are one-liners on arrays of any
leading shape, and SciPy has no batched skew-matrix map (going through ``Rotation``
would also force a normalisation we do not want inside the dynamics).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

__all__ = [
    "hat",
    "vee",
    "orthonormalize",
    "geodesic_angle",
    "from_quat",
    "to_quat",
    "from_euler",
]


def hat(w: np.ndarray) -> np.ndarray:
    """Skew matrix of ``w`` (..., 3) -> (..., 3, 3): ``hat(w) @ x == cross(w, x)``."""
    w = np.asarray(w, dtype=np.float64)
    z = np.zeros(w.shape[:-1])
    x, y, zz = w[..., 0], w[..., 1], w[..., 2]
    return np.stack(
        [
            np.stack([z, -zz, y], -1),
            np.stack([zz, z, -x], -1),
            np.stack([-y, x, z], -1),
        ],
        -2,
    )


def vee(S: np.ndarray) -> np.ndarray:
    """Inverse of :func:`hat` (..., 3, 3) -> (..., 3), using the skew part of ``S``."""
    S = np.asarray(S, dtype=np.float64)
    return 0.5 * np.stack([S[..., 2, 1] - S[..., 1, 2], S[..., 0, 2] - S[..., 2, 0], S[..., 1, 0] - S[..., 0, 1]], -1)


def orthonormalize(R: np.ndarray, iterations: int = 1) -> np.ndarray:
    """Newton-Schulz step(s) towards the polar factor: ``R <- 1.5 R - 0.5 R R^T R``.

    Symmetric in the three axes (unlike Gram-Schmidt) and quadratically convergent: an
    orthonormality error e becomes O(e^2) per iteration, so one step per control step
    keeps an integrated rotation orthonormal to round-off.
    """
    R = np.asarray(R, dtype=np.float64)
    for _ in range(iterations):
        R = 1.5 * R - 0.5 * R @ np.swapaxes(R, -1, -2) @ R
    return R


def geodesic_angle(R1: np.ndarray, R2: np.ndarray) -> np.ndarray:
    """Angle of ``R1^T R2`` (rad), for (..., 3, 3) matrices."""
    c = (np.einsum("...ij,...ij->...", R1, R2) - 1.0) * 0.5
    return np.arccos(np.clip(c, -1.0, 1.0))


def from_quat(q: np.ndarray, scalar_first: bool = False) -> np.ndarray:
    """Quaternions (..., 4) (``[x, y, z, w]`` unless ``scalar_first``) -> (..., 3, 3)."""
    q = np.asarray(q, dtype=np.float64)
    return Rotation.from_quat(q.reshape(-1, 4), scalar_first=scalar_first).as_matrix().reshape(q.shape[:-1] + (3, 3))


def to_quat(R: np.ndarray, scalar_first: bool = False) -> np.ndarray:
    """(..., 3, 3) -> quaternions (..., 4) (``[x, y, z, w]`` unless ``scalar_first``)."""
    R = np.asarray(R, dtype=np.float64)
    return Rotation.from_matrix(R.reshape(-1, 3, 3)).as_quat(scalar_first=scalar_first).reshape(R.shape[:-2] + (4,))


def from_euler(seq: str, angles, degrees: bool = False) -> np.ndarray:
    """Euler angles -> rotation matrices (SciPy conventions: 'xyz' extrinsic, 'XYZ' intrinsic)."""
    return Rotation.from_euler(seq, angles, degrees=degrees).as_matrix()
