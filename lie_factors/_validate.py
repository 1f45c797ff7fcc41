"""Input validation shared by the public functions.

Every public function converts its input with one of these helpers, so wrong
shapes and non-finite values raise ``ValueError`` naming the expected shape
instead of returning garbage.

The single-element fast path of the public functions (one float64 array of the
element's exact shape) validates inside its numba call with :func:`finite` and
:func:`element_ok`. They only *accept or refuse*: a refused element is handed
to the general path, whose checks here raise the ``ValueError`` that names the
problem. So the fast checks must never accept what the general ones reject;
they are the same checks, and the orthonormality test is stricter by 1e-15 so
that a different summation order can never let a borderline block through.
"""

from __future__ import annotations

import math

import numpy as np

from lie_factors._jit import kernel

#: Largest accepted max|RᵀR − I| (and |det R − 1|) for a rotation block.
ORTHONORMAL_TOL = 1e-9

#: The fast path's bound: ORTHONORMAL_TOL less a margin far above the rounding of
#: RᵀR (a few ulp of 1), far below anything a caller could mean.
_FAST_ORTHONORMAL_TOL = ORTHONORMAL_TOL - 1e-15

#: What the fast path of the public functions accepts: ``type(x) is NDARRAY and
#: x.dtype is F64`` (native-endian float64; numpy keeps one such dtype object).
NDARRAY = np.ndarray
F64 = np.dtype(np.float64)

#: ``corner`` of :func:`element_ok`: no homogeneous row (a bare rotation); last
#: row [0 … 0 1]; last row [0 … 0 s] with s > 0.
NO_CORNER, ONE, POSITIVE = 0, 1, 2


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


# ---------------------------------------------------------------- numba checks of one element


@kernel
def finite(a):
    """True when every entry of the C-contiguous array ``a`` is finite (any shape)."""
    for v in a.flat:
        if not math.isfinite(v):
            return False
    return True


#: Codes of :func:`element_code` (the factors turn them into messages).
OK, NOT_FINITE, NOT_ORTHONORMAL, REFLECTION, BAD_LAST_ROW, BAD_SCALE = range(6)


@kernel
def element_code(X, d, corner, tol):
    """Validate one (m, m) element; returns OK or the code of the first failure.

    Finite entries; rotation block R = X[:d, :d] with max|RᵀR − I| ≤ ``tol`` and
    det R > 0; then, unless ``corner`` is NO_CORNER, the last row [0 … 0 1]
    (ONE) or [0 … 0 s], s > 0 (POSITIVE). The tests :func:`square`,
    :func:`rotation_block` and :func:`bottom_row` run on batches, done on the
    raw matrix (any memory order) in one call. The factors use it with
    ``tol = ORTHONORMAL_TOL``, the public functions' fast path through
    :func:`element_ok`.
    """
    if not finite(X):
        return NOT_FINITE
    for i in range(d):
        for j in range(i, d):  # RᵀR is symmetric
            acc = 0.0
            for k in range(d):
                acc += X[k, i] * X[k, j]
            if i == j:
                acc -= 1.0
            if not abs(acc) <= tol:
                return NOT_ORTHONORMAL
    if d == 2:
        det = X[0, 0] * X[1, 1] - X[0, 1] * X[1, 0]
    else:
        det = (X[0, 0] * (X[1, 1] * X[2, 2] - X[1, 2] * X[2, 1])
               - X[0, 1] * (X[1, 0] * X[2, 2] - X[1, 2] * X[2, 0])
               + X[0, 2] * (X[1, 0] * X[2, 1] - X[1, 1] * X[2, 0]))
    if det < 0.0:
        return REFLECTION
    if corner == NO_CORNER:
        return OK
    m = X.shape[0]
    for j in range(m - 1):
        if X[m - 1, j] != 0.0:
            return BAD_LAST_ROW
    if corner == ONE:
        if X[m - 1, m - 1] != 1.0:
            return BAD_LAST_ROW
    elif not X[m - 1, m - 1] > 0.0:
        return BAD_SCALE
    return OK


@kernel
def element_ok(X, d, corner):
    """True when :func:`element_code` finds nothing wrong with the orthonormality bound
    1e-15 below ORTHONORMAL_TOL (see the module docstring): the fast path's check."""
    return element_code(X, d, corner, _FAST_ORTHONORMAL_TOL) == OK
