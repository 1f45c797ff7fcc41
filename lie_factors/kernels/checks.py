"""Numba checks of one element, for the single-element fast path and the factors.

The public functions' fast path (one float64 array of the element's exact
shape, validated and computed in one numba call) checks with :func:`finite` and
:func:`element_ok`. They only *accept or refuse*: a refused input goes on to the
general path, whose numpy checks (:mod:`lie_factors.kernels.validate`) raise the
``ValueError`` that names the problem. So these must never accept what those
reject: they are the same tests, and the orthonormality bound is 1e-15 stricter
so that a different summation order can never let a borderline block through.
The factors validate their measurements with :func:`element_code` (exact bound)
and turn its codes into their own messages.
"""

from __future__ import annotations

import math

import numpy as np

from lie_factors.kernels.jit import kernel
# ``corner`` of element_code: defined with the groups' facts.
from lie_factors.kernels.registry import NO_CORNER, ONE, POSITIVE  # noqa: F401
from lie_factors.kernels.validate import ORTHONORMAL_TOL

#: The fast path's bound: ORTHONORMAL_TOL less a margin far above the rounding of
#: RᵀR (a few ulp of 1), far below anything a caller could mean.
_FAST_ORTHONORMAL_TOL = ORTHONORMAL_TOL - 1e-15

#: What the fast path of the public functions accepts: ``type(x) is NDARRAY and
#: x.dtype is F64`` (native-endian float64; numpy keeps one such dtype object).
NDARRAY = np.ndarray
F64 = np.dtype(np.float64)



@kernel
def finite(a):
    """True when every entry of the array ``a`` is finite (any shape, any memory order)."""
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
