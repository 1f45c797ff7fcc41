"""Numba checks of group elements: the one test of a matrix element, and the fast path's checks.

:func:`element_code` is the test of a matrix element everywhere: the factors
validate their measurements with it, the public functions' general path
(:mod:`lie_factors.kernels.public`) runs it over a batch (:func:`worst_code`),
and :func:`lie_factors.kernels.validate.defect` words its codes. The public
functions' fast path (one float64 array of the element's exact shape, validated
and computed in one numba call) checks with :func:`finite`, :func:`element_ok`
and :func:`unit_ok`. They only *accept or
refuse*: a refused input goes on to the general path, which raises the
:class:`~lie_factors.errors.InputError` that names the problem. So these must never accept what it
rejects: they are the same tests, with bounds 1e-15 stricter (and the unit
quaternion test, which the general path runs in numpy, in another summation
order: the margin covers that).
"""

from __future__ import annotations

import math

from lie_factors.kernels.jit import helper_kernel, kernel
from lie_factors.kernels.registry import NO_CORNER, ONE
# The tolerances, and the codes of element_code (defined, and worded, in the numba-free module).
from lie_factors.kernels.validate import (BAD_LAST_ROW, BAD_SCALE, NOT_FINITE, NOT_ORTHONORMAL, OK, ORTHONORMAL_TOL, REFLECTION, UNIT_TOL)

#: The fast path's bounds: the general path's less a margin far above the rounding of
#: RᵀR or ‖q‖ (a few ulp of 1), far below anything a caller could mean.
_FAST_ORTHONORMAL_TOL = ORTHONORMAL_TOL - 1e-15
_FAST_UNIT_TOL = UNIT_TOL - 1e-15


@helper_kernel
def finite(a):
    """True when every entry of the array ``a`` is finite (any shape, any memory order)."""
    for v in a.flat:
        if not math.isfinite(v):
            return False
    return True


@helper_kernel
def element_code(X, d, corner, tol):
    """Validate one (m, m) element; returns OK or the code of the first failure.

    Finite entries; rotation block R = X[:d, :d] with max|RᵀR − I| ≤ ``tol`` and
    det R > 0; then, unless ``corner`` is NO_CORNER, the last row [0 … 0 1]
    (ONE) or [0 … 0 1/s], 1/s > 0 (POSITIVE): the tests of
    :func:`lie_factors.kernels.validate.element`, done on the raw matrix (any
    memory order) in one call. The factors and the general path use it with
    ``tol = ORTHONORMAL_TOL``, the public functions' fast path through :func:`element_ok`.
    """
    if not finite(X):
        return NOT_FINITE
    # RᵀR − I entry by entry, its upper triangle row by row (it is symmetric)
    for i in range(d):
        for j in range(i, d):
            s = 0.0
            for k in range(d):
                s += X[k, i] * X[k, j]
            if i == j:
                s -= 1.0
            if not abs(s) <= tol:
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
def worst_code(X, d, corner):
    """The first code, in :func:`element_code`'s order, that some element of ``X`` (N, m, m)
    fails with ``tol = ORTHONORMAL_TOL`` (OK when none does): each test as if on the whole batch."""
    code = OK
    for i in range(X.shape[0]):
        c = element_code(X[i], d, corner, ORTHONORMAL_TOL)
        if c != OK and (code == OK or c < code):
            code = c
            if code <= NOT_ORTHONORMAL:
                break
    return code


@kernel
def element_ok(X, d, corner):
    """True when :func:`element_code` finds nothing wrong with the orthonormality bound
    1e-15 below ORTHONORMAL_TOL (see the module docstring): the fast path's check."""
    return element_code(X, d, corner, _FAST_ORTHONORMAL_TOL) == OK


@kernel
def unit_ok(q):
    """The fast path's check of a unit quaternion (4,) or unit dual quaternion (8,): the tests
    of :func:`lie_factors.kernels.validate.element` with bounds 1e-15 below UNIT_TOL."""
    if not finite(q):
        return False
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    if not abs(n - 1.0) <= _FAST_UNIT_TOL:
        return False
    if q.shape[0] == 4:
        return True
    # |q_r·q_d| / max(1, ‖q_d‖) on u = q_d / max(1, max|q_d|), as the general path
    scale = max(1.0, abs(q[4]), abs(q[5]), abs(q[6]), abs(q[7]))
    u0, u1, u2, u3 = q[4] / scale, q[5] / scale, q[6] / scale, q[7] / scale
    nu = math.sqrt(u0 * u0 + u1 * u1 + u2 * u2 + u3 * u3)
    return abs(q[0] * u0 + q[1] * u1 + q[2] * u2 + q[3] * u3) / max(1.0, nu) <= _FAST_UNIT_TOL
