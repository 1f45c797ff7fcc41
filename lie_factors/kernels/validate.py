"""Input validation shared by the public functions.

Every public function converts its input with one of these helpers, so wrong
shapes and non-finite values raise ``ValueError`` naming the expected shape
instead of returning garbage.

The single-element fast path of the public functions checks one element inside
its numba call instead (:mod:`lie_factors.kernels.checks`); what it refuses comes here
for the message.
"""

from __future__ import annotations

import numpy as np

#: Largest accepted max|RᵀR − I| (and |det R − 1|) for a rotation block.
ORTHONORMAL_TOL = 1e-9


def _as_float(a, name: str) -> np.ndarray:
    try:
        arr = np.asarray(a, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name}: cannot convert {type(a).__name__} to a float64 array") from exc
    return arr


def _check_finite(arr: np.ndarray, name: str) -> None:
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name}: contains NaN or inf")


def tangent(x, n: int, name: str = "x") -> np.ndarray:
    """Return ``x`` as a finite float64 array of shape ``(..., n)``."""
    arr = _as_float(x, name)
    if arr.ndim < 1 or arr.shape[-1] != n:
        raise ValueError(f"{name}: expected shape (..., {n}), got {arr.shape}")
    _check_finite(arr, name)
    return arr


def square(X, m: int, name: str = "X") -> np.ndarray:
    """Return ``X`` as a finite float64 array of shape ``(..., m, m)``."""
    arr = _as_float(X, name)
    if arr.ndim < 2 or arr.shape[-2:] != (m, m):
        raise ValueError(f"{name}: expected shape (..., {m}, {m}), got {arr.shape}")
    _check_finite(arr, name)
    return arr


def rotation_block(R: np.ndarray, name: str, d: int) -> None:
    """Raise ``ValueError`` unless every ``R[..., :d, :d]`` is a proper rotation."""
    B = R[..., :d, :d]
    gram = np.einsum("...ki,...kj->...ij", B, B) - np.eye(d)
    if gram.size and np.max(np.abs(gram)) > ORTHONORMAL_TOL:
        raise ValueError(
            f"{name}: rotation block is not orthonormal (max|RᵀR - I| = {np.max(np.abs(gram)):.3g})"
        )
    det = np.linalg.det(B) if B.size else np.ones(0)
    if np.any(det < 0):
        raise ValueError(f"{name}: rotation block has determinant -1 (a reflection)")


def bottom_row(X: np.ndarray, name: str, expected: str, last_positive: bool = False) -> None:
    """Check the last row of homogeneous matrices: zeros, then 1 (or any s > 0)."""
    row = X[..., -1, :-1]
    if row.size and np.any(row != 0.0):
        raise ValueError(f"{name}: expected last row {expected}")
    corner = X[..., -1, -1]
    if last_positive:
        if np.any(corner <= 0.0):
            raise ValueError(f"{name}: expected last row {expected} with s > 0")
    elif np.any(corner != 1.0):
        raise ValueError(f"{name}: expected last row {expected}")
