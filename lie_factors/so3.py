"""SO(3), GTSAM's Rot3: tangent x = [ω1, ω2, ω3], elements 3×3 rotation matrices.

Shapes: ``hat`` (..., 3) → (..., 3, 3); ``exp`` (..., 3) → (..., 3, 3);
``log`` (..., 3, 3) → (..., 3) with |ω| ≤ π; ``ad``/``dexp``/``dlog``
(..., 3) → (..., 3, 3); ``Ad`` (..., 3, 3) → (..., 3, 3).

``dexp(x)`` is Eade's D_exp (Eq. 35), the LEFT Jacobian:
exp(x + ε) ≈ exp(dexp(x) ε) · exp(x). GTSAM's ``Rot3.ExpmapDerivative(x)`` is
the right Jacobian and equals ``dexp(-x)``. ``dlog(x) = dexp(x)⁻¹`` in closed
form (Eade, Eqs. 55–57), valid for |x| < 2π.

Each formula is one numba core (``_exp(x, out)`` ...) shared with the factors;
the public functions validate and broadcast over leading axes.
"""

from __future__ import annotations

import math

import numpy as np

from lie_factors.kernels import checks as _check, jit as _jit, validate as _validate
from lie_factors.kernels.coeffs import a_theta, b_theta, c_theta, e_omega, norm3
from lie_factors.kernels.jit import kernel

DIM = 3
MAT = 3

#: log: for cos θ below this the axis is taken from the symmetric part of R.
#: s = vee(R − Rᵀ)/2 = sin θ · n carries an absolute error ~ε, so the axis
#: s/|s| has error ~ε/sin θ and is worthless near π; the symmetric part
#: (R + Rᵀ)/2 − cos θ I = (1 − cos θ) n nᵀ is accurate there but loses
#: everything near 0. At cos θ = 0 both are accurate to ~1 ulp.
LOG_SYM_COS = 0.0


# ---------------------------------------------------------------- cores


@kernel
def _hat(x, out):
    out[0, 0] = 0.0
    out[0, 1] = -x[2]
    out[0, 2] = x[1]
    out[1, 0] = x[2]
    out[1, 1] = 0.0
    out[1, 2] = -x[0]
    out[2, 0] = -x[1]
    out[2, 1] = x[0]
    out[2, 2] = 0.0


@kernel
def _vee(X, out):
    out[0] = X[2, 1]
    out[1] = X[0, 2]
    out[2] = X[1, 0]


@kernel
def _rodrigues(w0, w1, w2, p, q, out):
    """out = I + p ω× + q ω×², using ω×² = ωωᵀ − θ² I (Eade, Eq. 47).

    The diagonal of ω×² is written −(ω_j² + ω_k²) so that no θ² − ω_i²
    cancellation occurs.
    """
    out[0, 0] = 1.0 - q * (w1 * w1 + w2 * w2)
    out[1, 1] = 1.0 - q * (w0 * w0 + w2 * w2)
    out[2, 2] = 1.0 - q * (w0 * w0 + w1 * w1)
    q01 = q * w0 * w1
    q02 = q * w0 * w2
    q12 = q * w1 * w2
    out[0, 1] = q01 - p * w2
    out[1, 0] = q01 + p * w2
    out[0, 2] = q02 + p * w1
    out[2, 0] = q02 - p * w1
    out[1, 2] = q12 - p * w0
    out[2, 1] = q12 + p * w0


@kernel
def _exp(x, out):
    # Rodrigues: exp(ω×) = I + a_θ ω× + b_θ ω×² (Jackson, SO(3) boxed formula).
    th = norm3(x[0], x[1], x[2])
    _rodrigues(x[0], x[1], x[2], a_theta(th), b_theta(th), out)


@kernel
def _log(X, out):
    # θ from atan2(|s|, c): acos(c) would lose half the digits near 0 and π.
    s0 = 0.5 * (X[2, 1] - X[1, 2])
    s1 = 0.5 * (X[0, 2] - X[2, 0])
    s2 = 0.5 * (X[1, 0] - X[0, 1])
    c = 0.5 * (X[0, 0] + X[1, 1] + X[2, 2] - 1.0)
    sn = norm3(s0, s1, s2)
    th = math.atan2(sn, c)
    if c > LOG_SYM_COS:
        # ω = θ/sin θ · s (Jackson: log R = θ/(2 sin θ) (R − Rᵀ)).
        k = th / sn if sn > 0.0 else 1.0
        out[0] = k * s0
        out[1] = k * s1
        out[2] = k * s2
        return
    # Near π: (R + Rᵀ)/2 − c I = (1 − c) n nᵀ; its largest-diagonal column is
    # the best-conditioned multiple of n. The sign comes from s = sin θ n.
    d0 = X[0, 0] - c
    d1 = X[1, 1] - c
    d2 = X[2, 2] - c
    if d0 >= d1 and d0 >= d2:
        n0 = d0
        n1 = 0.5 * (X[1, 0] + X[0, 1])
        n2 = 0.5 * (X[2, 0] + X[0, 2])
    elif d1 >= d2:
        n0 = 0.5 * (X[0, 1] + X[1, 0])
        n1 = d1
        n2 = 0.5 * (X[2, 1] + X[1, 2])
    else:
        n0 = 0.5 * (X[0, 2] + X[2, 0])
        n1 = 0.5 * (X[1, 2] + X[2, 1])
        n2 = d2
    k = th / norm3(n0, n1, n2)
    if n0 * s0 + n1 * s1 + n2 * s2 < 0.0:
        k = -k
    out[0] = k * n0
    out[1] = k * n1
    out[2] = k * n2


@kernel
def _ad(x, out):
    # ad_ω = ω× (Eade, Eq. 43).
    _hat(x, out)


@kernel
def _Ad(X, out):
    for i in range(3):
        for j in range(3):
            out[i, j] = X[i, j]


@kernel
def _dexp(x, out):
    # D_exp(ω) = I + b_θ ω× + c_θ ω×² (Eade, Eq. 46; = Eq. 53).
    th = norm3(x[0], x[1], x[2])
    _rodrigues(x[0], x[1], x[2], b_theta(th), c_theta(th), out)


@kernel
def _dlog(x, out):
    # D_exp⁻¹(ω) = I − ½ ω× + e_θ ω×² (Eade, Eq. 55), |ω| < 2π.
    _rodrigues(x[0], x[1], x[2], -0.5, e_omega(x[0], x[1], x[2]), out)


@kernel
def _compose(X, Y, out):
    for i in range(3):
        for j in range(3):
            out[i, j] = X[i, 0] * Y[0, j] + X[i, 1] * Y[1, j] + X[i, 2] * Y[2, j]


@kernel
def _inverse(X, out):
    for i in range(3):
        for j in range(3):
            out[i, j] = X[j, i]


# ---------------------------------------------------------------- one element, one numba call
# The public functions below try these first: a float64 array of exactly the
# element's shape is validated and computed in ONE numba call (through its entry
# point, _jit.one_element) instead of the general path's numpy checks and
# batching (see docs/benchmarks.md, "One element per call", for the cost).
# Each returns True when ``out`` holds the result and False when the input must
# take the general path, which raises the ValueError naming the problem
# (_check.finite / element_ok make the same checks as the general path).
# They are compiled for inputs of any memory order (GTSAM's ``.matrix()`` is
# Fortran-ordered); ``np.ascontiguousarray`` copies the input (at most 16
# numbers, ≈0.02 µs) so that the cores only ever see, and are only compiled
# for, C-ordered arrays, as on the general path.


@kernel
def _hat1(x, out):
    x = np.ascontiguousarray(x)
    if not _check.finite(x):
        return False
    _hat(x, out)
    return True


@kernel
def _vee1(X, out):
    X = np.ascontiguousarray(X)
    if not _check.finite(X):
        return False
    _vee(X, out)
    return True


@kernel
def _exp1(x, out):
    x = np.ascontiguousarray(x)
    if not _check.finite(x):
        return False
    _exp(x, out)
    return True


@kernel
def _log1(X, out):
    X = np.ascontiguousarray(X)
    if not _check.element_ok(X, 3, _check.NO_CORNER):
        return False
    _log(X, out)
    return True


@kernel
def _ad1(x, out):
    x = np.ascontiguousarray(x)
    if not _check.finite(x):
        return False
    _ad(x, out)
    return True


@kernel
def _Ad1(X, out):
    X = np.ascontiguousarray(X)
    if not _check.element_ok(X, 3, _check.NO_CORNER):
        return False
    _Ad(X, out)
    return True


@kernel
def _dexp1(x, out):
    x = np.ascontiguousarray(x)
    if not _check.finite(x):
        return False
    _dexp(x, out)
    return True


@kernel
def _dlog1(x, out):
    x = np.ascontiguousarray(x)
    if not _check.finite(x):
        return False
    _dlog(x, out)
    return True


@kernel
def _compose1(X, Y, out):
    X = np.ascontiguousarray(X)
    Y = np.ascontiguousarray(Y)
    if not (_check.finite(X) and _check.finite(Y)):
        return False
    _compose(X, Y, out)
    return True


@kernel
def _inverse1(X, out):
    X = np.ascontiguousarray(X)
    if not _check.element_ok(X, 3, _check.NO_CORNER):
        return False
    _inverse(X, out)
    return True


# Python's handles on the wrappers above: their compiled entry points, bound on first use.
_hat_one = _jit.one_element(_hat1, (1,), 2, globals(), "_hat_one")
_vee_one = _jit.one_element(_vee1, (2,), 1, globals(), "_vee_one")
_exp_one = _jit.one_element(_exp1, (1,), 2, globals(), "_exp_one")
_log_one = _jit.one_element(_log1, (2,), 1, globals(), "_log_one")
_ad_one = _jit.one_element(_ad1, (1,), 2, globals(), "_ad_one")
_Ad_one = _jit.one_element(_Ad1, (2,), 2, globals(), "_Ad_one")
_dexp_one = _jit.one_element(_dexp1, (1,), 2, globals(), "_dexp_one")
_dlog_one = _jit.one_element(_dlog1, (1,), 2, globals(), "_dlog_one")
_compose_one = _jit.one_element(_compose1, (2, 2), 2, globals(), "_compose_one")
_inverse_one = _jit.one_element(_inverse1, (2,), 2, globals(), "_inverse_one")


# ---------------------------------------------------------------- public API
# Each public function first tries its one-element fast path (``_exp_one`` …): taken when
# the input is an ndarray of exactly the element's shape and dtype float64 (any memory
# order); batches, lists, other dtypes and refused inputs take the general path.
# Both run the same cores.

_ND, _F64, _empty = _check.NDARRAY, _check.F64, np.empty
_V, _M, _J = (DIM,), (MAT, MAT), (DIM, DIM)


def _rotations(X, name="X"):
    X = _validate.square(X, MAT, name)
    _validate.rotation_block(X, name, 3)
    return X


def hat(x):
    """(..., 3) → (..., 3, 3): ω×."""
    if type(x) is _ND and x.shape == _V and x.dtype is _F64:
        out = _empty(_M)
        if _hat_one(x, out):
            return out
    return _jit.apply(_hat, _validate.tangent(x, DIM), 1, (MAT, MAT))


def vee(X):
    """(..., 3, 3) → (..., 3): [X21, X02, X10], the inverse of :func:`hat`."""
    if type(X) is _ND and X.shape == _M and X.dtype is _F64:
        out = _empty(_V)
        if _vee_one(X, out):
            return out
    return _jit.apply(_vee, _validate.square(X, MAT), 2, (DIM,))


def exp(x):
    """(..., 3) → (..., 3, 3): exp(ω×), Rodrigues' formula (Jackson)."""
    if type(x) is _ND and x.shape == _V and x.dtype is _F64:
        out = _empty(_M)
        if _exp_one(x, out):
            return out
    return _jit.apply(_exp, _validate.tangent(x, DIM), 1, (MAT, MAT))


def log(X):
    """(..., 3, 3) → (..., 3): principal log, |ω| ≤ π (at π one of the two axes).

    Raises ValueError unless every X is a rotation (max|XᵀX − I| ≤ 1e-9, det > 0).
    """
    if type(X) is _ND and X.shape == _M and X.dtype is _F64:
        out = _empty(_V)
        if _log_one(X, out):
            return out
    return _jit.apply(_log, _rotations(X), 2, (DIM,))


def ad(x):
    """(..., 3) → (..., 3, 3): ad_ω = ω× (Eade, Eq. 43)."""
    if type(x) is _ND and x.shape == _V and x.dtype is _F64:
        out = _empty(_J)
        if _ad_one(x, out):
            return out
    return _jit.apply(_ad, _validate.tangent(x, DIM), 1, (DIM, DIM))


def Ad(X):
    """(..., 3, 3) → (..., 3, 3): Ad_R = R. Raises ValueError for non-rotations."""
    if type(X) is _ND and X.shape == _M and X.dtype is _F64:
        out = _empty(_J)
        if _Ad_one(X, out):
            return out
    return _jit.apply(_Ad, _rotations(X), 2, (DIM, DIM))


def dexp(x):
    """(..., 3) → (..., 3, 3): left Jacobian D_exp(ω) (Eade, Eqs. 35, 46, 53)."""
    if type(x) is _ND and x.shape == _V and x.dtype is _F64:
        out = _empty(_J)
        if _dexp_one(x, out):
            return out
    return _jit.apply(_dexp, _validate.tangent(x, DIM), 1, (DIM, DIM))


def dlog(x):
    """(..., 3) → (..., 3, 3): D_exp(ω)⁻¹ (Eade, Eqs. 55–57), |ω| < 2π."""
    if type(x) is _ND and x.shape == _V and x.dtype is _F64:
        out = _empty(_J)
        if _dlog_one(x, out):
            return out
    return _jit.apply(_dlog, _validate.tangent(x, DIM), 1, (DIM, DIM))


def compose(X, Y):
    """(..., 3, 3) × (..., 3, 3) → (..., 3, 3): X·Y, batch axes broadcast."""
    if (type(X) is _ND and type(Y) is _ND and X.shape == _M and Y.shape == _M
            and X.dtype is _F64 and Y.dtype is _F64):
        out = _empty(_M)
        if _compose_one(X, Y, out):
            return out
    X = _validate.square(X, MAT, "X")
    Y = _validate.square(Y, MAT, "Y")
    return _jit.apply2(_compose, X, Y, (2, 2), (MAT, MAT))


def inverse(X):
    """(..., 3, 3) → (..., 3, 3): Rᵀ. Raises ValueError for non-rotations."""
    if type(X) is _ND and X.shape == _M and X.dtype is _F64:
        out = _empty(_M)
        if _inverse_one(X, out):
            return out
    return _jit.apply(_inverse, _rotations(X), 2, (MAT, MAT))
