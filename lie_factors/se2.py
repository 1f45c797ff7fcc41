"""SE(2), GTSAM's Pose2: closed-form exp, log, adjoints and D_exp / D_log.

Tangent ordering (translation first, as GTSAM's Pose2)::

    x = [x, y, θ]                      shape (..., 3)
    hat(x) = [[0, -θ, x],
              [θ,  0, y],
              [0,  0, 0]]              shape (..., 3, 3)
    group element [[R(θ), t], [0, 0, 1]]

``dexp`` is the seed's D_exp(x) = Σ ad_x^i/(i+1)! (Eade, Eq. 35), the LEFT
Jacobian: exp(x + ε) ≈ exp(dexp(x) ε)·exp(x). GTSAM's Pose2.ExpmapDerivative is
the right Jacobian, ``ExpmapDerivative(x) == dexp(-x)`` (likewise Logmap).

Every public function broadcasts over leading axes; the ``_name(..., out)``
numba cores work on one element and never allocate.

Coefficients (Eade, Eqs. 50–52) ``a = sinθ/θ``, ``b = (1 - cosθ)/θ²``,
``c = (1 - a)/θ²``: ``a`` and ``b`` have cancellation-free closed forms
(``b = 2 sin²(θ/2)/θ²``) and only need a Taylor band to avoid 0/0;
``c`` cancels catastrophically (relative error ≈ 6ε/θ²), so it uses its
power series up to ``C_TAYLOR``.
"""

from __future__ import annotations

import math

import numpy as np

from .kernels import checks as _check, jit as _jit, validate as _validate

DIM = 3
MAT = 3

#: |θ| below this: a_θ, b_θ from their Taylor polynomials (closed forms are 0/0
#: at θ = 0; the omitted θ⁶/5040 term is < 2e-28 here).
ANGLE_TAYLOR = 1e-4
#: |θ| below this: c_θ = (θ - sin θ)/θ³ from its series (closed form loses
#: ≈ 2ε/θ relative accuracy in the dexp entries; at θ = 1 that is ≤ 4e-16).
C_TAYLOR = 1.0

# c_θ = Σ_k (-1)^k θ^{2k}/(2k+3)!  (Eade, Eq. 81, second sum); 10 terms reach
# θ^18/21! < 2e-20 at |θ| = 1.
_C_SERIES = np.array([(-1.0) ** k / math.factorial(2 * k + 3) for k in range(10)])


@_jit.kernel
def _ab(th):
    """(a_θ, b_θ) of Eade, Eqs. (50), (51)."""
    if abs(th) < ANGLE_TAYLOR:
        t = th * th
        return 1.0 - t / 6.0 * (1.0 - t / 20.0), 0.5 - t / 24.0 * (1.0 - t / 30.0)
    s = math.sin(0.5 * th) / th
    # 1 - cos θ = 2 sin²(θ/2) avoids the cancellation of the literal Eq. (51)
    return math.sin(th) / th, 2.0 * s * s


@_jit.kernel
def _c(th):
    """c_θ = (1 - a_θ)/θ² of Eade, Eq. (52)."""
    if abs(th) < C_TAYLOR:
        t = th * th
        s = 0.0
        for k in range(_C_SERIES.shape[0] - 1, -1, -1):
            s = s * t + _C_SERIES[k]
        return s
    return (th - math.sin(th)) / (th * th * th)


# --- cores -----------------------------------------------------------------------------------


@_jit.kernel
def _hat(x, out):
    out[0, 0] = 0.0
    out[0, 1] = -x[2]
    out[0, 2] = x[0]
    out[1, 0] = x[2]
    out[1, 1] = 0.0
    out[1, 2] = x[1]
    out[2, 0] = 0.0
    out[2, 1] = 0.0
    out[2, 2] = 0.0


@_jit.kernel
def _vee(X, out):
    out[0] = X[0, 2]
    out[1] = X[1, 2]
    out[2] = X[1, 0]


@_jit.kernel
def _exp(x, out):
    th = x[2]
    a, b = _ab(th)
    tb = th * b
    # translation V u with V = a I + θ b J, the same block as D_exp (Eade, Eq. 83)
    out[0, 0] = math.cos(th)
    out[0, 1] = -math.sin(th)
    out[0, 2] = a * x[0] - tb * x[1]
    out[1, 0] = math.sin(th)
    out[1, 1] = math.cos(th)
    out[1, 2] = tb * x[0] + a * x[1]
    out[2, 0] = 0.0
    out[2, 1] = 0.0
    out[2, 2] = 1.0


@_jit.kernel
def _log(X, out):
    th = math.atan2(X[1, 0], X[0, 0])
    a, b = _ab(th)
    # V⁻¹ = (a I - θ b J)/(a² + θ² b²) and a² + θ² b² = 2 b, so V⁻¹ = α I - (θ/2) J
    # with α = a/(2b) = (θ/2) cot(θ/2) (same inverse as Eade, Eq. 85)
    al = a / (2.0 * b)
    h = 0.5 * th
    tx = X[0, 2]
    ty = X[1, 2]
    out[0] = al * tx + h * ty
    out[1] = -h * tx + al * ty
    out[2] = th


@_jit.kernel
def _ad(x, out):
    # Eade, Eq. (78)
    out[0, 0] = 0.0
    out[0, 1] = -x[2]
    out[0, 2] = x[1]
    out[1, 0] = x[2]
    out[1, 1] = 0.0
    out[1, 2] = -x[0]
    out[2, 0] = 0.0
    out[2, 1] = 0.0
    out[2, 2] = 0.0


@_jit.kernel
def _Ad(X, out):
    # X hat(v, φ) X⁻¹ = hat(R v - φ J t, φ): Ad = [[R, -J t], [0, 1]], -J t = (t_y, -t_x)
    out[0, 0] = X[0, 0]
    out[0, 1] = X[0, 1]
    out[0, 2] = X[1, 2]
    out[1, 0] = X[1, 0]
    out[1, 1] = X[1, 1]
    out[1, 2] = -X[0, 2]
    out[2, 0] = 0.0
    out[2, 1] = 0.0
    out[2, 2] = 1.0


@_jit.kernel
def _dexp(x, out):
    th = x[2]
    a, b = _ab(th)
    tc = th * _c(th)
    tb = th * b
    # Eade, Eq. (83) corrected: third column (θ c x + b y, θ c y - b x); the seed
    # drops the factor θ on c (see docs/errata.md)
    out[0, 0] = a
    out[0, 1] = -tb
    out[0, 2] = tc * x[0] + b * x[1]
    out[1, 0] = tb
    out[1, 1] = a
    out[1, 2] = tc * x[1] - b * x[0]
    out[2, 0] = 0.0
    out[2, 1] = 0.0
    out[2, 2] = 1.0


@_jit.kernel
def _dlog(x, out):
    th = x[2]
    a, b = _ab(th)
    tc = th * _c(th)
    # Eade, Eqs. (84)-(85): D_log = [[A⁻¹, -A⁻¹ v], [0, 1]], with the 2×2 inverse
    # A⁻¹ = (a I - θ b J)/(a² + θ² b²) = α I - (θ/2) J since a² + θ² b² = 2 b
    al = a / (2.0 * b)
    h = 0.5 * th
    v0 = tc * x[0] + b * x[1]
    v1 = tc * x[1] - b * x[0]
    out[0, 0] = al
    out[0, 1] = h
    out[0, 2] = -(al * v0 + h * v1)
    out[1, 0] = -h
    out[1, 1] = al
    out[1, 2] = h * v0 - al * v1
    out[2, 0] = 0.0
    out[2, 1] = 0.0
    out[2, 2] = 1.0


@_jit.kernel
def _compose(X, Y, out):
    for i in range(3):
        for j in range(3):
            out[i, j] = X[i, 0] * Y[0, j] + X[i, 1] * Y[1, j] + X[i, 2] * Y[2, j]


@_jit.kernel
def _inverse(X, out):
    # [[Rᵀ, -Rᵀ t], [0, 1]]
    tx = X[0, 2]
    ty = X[1, 2]
    out[0, 0] = X[0, 0]
    out[0, 1] = X[1, 0]
    out[0, 2] = -(X[0, 0] * tx + X[1, 0] * ty)
    out[1, 0] = X[0, 1]
    out[1, 1] = X[1, 1]
    out[1, 2] = -(X[0, 1] * tx + X[1, 1] * ty)
    out[2, 0] = 0.0
    out[2, 1] = 0.0
    out[2, 2] = 1.0


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


@_jit.kernel
def _hat1(x, out):
    x = np.ascontiguousarray(x)
    if not _check.finite(x):
        return False
    _hat(x, out)
    return True


@_jit.kernel
def _vee1(X, out):
    X = np.ascontiguousarray(X)
    if not _check.finite(X):
        return False
    _vee(X, out)
    return True


@_jit.kernel
def _exp1(x, out):
    x = np.ascontiguousarray(x)
    if not _check.finite(x):
        return False
    _exp(x, out)
    return True


@_jit.kernel
def _log1(X, out):
    X = np.ascontiguousarray(X)
    if not _check.element_ok(X, 2, _check.ONE):
        return False
    _log(X, out)
    return True


@_jit.kernel
def _ad1(x, out):
    x = np.ascontiguousarray(x)
    if not _check.finite(x):
        return False
    _ad(x, out)
    return True


@_jit.kernel
def _Ad1(X, out):
    X = np.ascontiguousarray(X)
    if not _check.element_ok(X, 2, _check.ONE):
        return False
    _Ad(X, out)
    return True


@_jit.kernel
def _dexp1(x, out):
    x = np.ascontiguousarray(x)
    if not _check.finite(x):
        return False
    _dexp(x, out)
    return True


@_jit.kernel
def _dlog1(x, out):
    x = np.ascontiguousarray(x)
    if not _check.finite(x):
        return False
    _dlog(x, out)
    return True


@_jit.kernel
def _compose1(X, Y, out):
    X = np.ascontiguousarray(X)
    Y = np.ascontiguousarray(Y)
    if not (_check.element_ok(X, 2, _check.ONE) and _check.element_ok(Y, 2, _check.ONE)):
        return False
    _compose(X, Y, out)
    return True


@_jit.kernel
def _inverse1(X, out):
    X = np.ascontiguousarray(X)
    if not _check.element_ok(X, 2, _check.ONE):
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


# --- public, broadcasting ----------------------------------------------------------------------
# Each public function first tries its one-element fast path (``_exp_one`` …): taken when
# the input is an ndarray of exactly the element's shape and dtype float64 (any memory
# order); batches, lists, other dtypes and refused inputs take the general path.
# Both run the same cores.

_ND, _F64, _empty = _check.NDARRAY, _check.F64, np.empty
_V, _M, _J = (DIM,), (MAT, MAT), (DIM, DIM)

_ROW = "[0, 0, 1]"


def _element(X, name):
    arr = _validate.square(X, MAT, name)
    _validate.rotation_block(arr, name, 2)
    _validate.bottom_row(arr, name, _ROW)
    return arr


def hat(x):
    """(..., 3) → (..., 3, 3): [[0, -θ, x], [θ, 0, y], [0, 0, 0]]."""
    if type(x) is _ND and x.shape == _V and x.dtype is _F64:
        out = _empty(_M)
        if _hat_one(x, out):
            return out
    return _jit.apply(_hat, _validate.tangent(x, DIM), 1, (MAT, MAT))


def vee(X):
    """(..., 3, 3) → (..., 3): [X[0, 2], X[1, 2], X[1, 0]]."""
    if type(X) is _ND and X.shape == _M and X.dtype is _F64:
        out = _empty(_V)
        if _vee_one(X, out):
            return out
    return _jit.apply(_vee, _validate.square(X, MAT, "X"), 2, (DIM,))


def exp(x):
    """(..., 3) → (..., 3, 3): [[R(θ), V u], [0, 1]], V = a_θ I + θ b_θ J (Eade, Eqs. 50–51)."""
    if type(x) is _ND and x.shape == _V and x.dtype is _F64:
        out = _empty(_M)
        if _exp_one(x, out):
            return out
    return _jit.apply(_exp, _validate.tangent(x, DIM), 1, (MAT, MAT))


def log(X):
    """(..., 3, 3) → (..., 3): principal logarithm, θ = atan2 ∈ (-π, π].

    Raises ValueError unless the rotation block is orthonormal and the last row is [0, 0, 1].
    """
    if type(X) is _ND and X.shape == _M and X.dtype is _F64:
        out = _empty(_V)
        if _log_one(X, out):
            return out
    return _jit.apply(_log, _element(X, "X"), 2, (DIM,))


def ad(x):
    """(..., 3) → (..., 3, 3): ad_x y = vee([hat x, hat y]) (Eade, Eq. 78)."""
    if type(x) is _ND and x.shape == _V and x.dtype is _F64:
        out = _empty(_J)
        if _ad_one(x, out):
            return out
    return _jit.apply(_ad, _validate.tangent(x, DIM), 1, (DIM, DIM))


def Ad(X):
    """(..., 3, 3) → (..., 3, 3): [[R, (t_y, -t_x)ᵀ], [0, 1]], X hat(y) X⁻¹ = hat(Ad(X) y)."""
    if type(X) is _ND and X.shape == _M and X.dtype is _F64:
        out = _empty(_J)
        if _Ad_one(X, out):
            return out
    return _jit.apply(_Ad, _element(X, "X"), 2, (DIM, DIM))


def dexp(x):
    """(..., 3) → (..., 3, 3): left Jacobian D_exp(x) (Eade, Eq. 83, corrected).

    GTSAM's Pose2.ExpmapDerivative(x) equals dexp(-x).
    """
    if type(x) is _ND and x.shape == _V and x.dtype is _F64:
        out = _empty(_J)
        if _dexp_one(x, out):
            return out
    return _jit.apply(_dexp, _validate.tangent(x, DIM), 1, (DIM, DIM))


def dlog(x):
    """(..., 3) → (..., 3, 3): D_exp(x)⁻¹ in closed form (Eade, Eqs. 84–85); singular at |θ| = 2π.

    GTSAM's Pose2.LogmapDerivative(x) equals dlog(-x).
    """
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
    return _jit.apply2(_compose, _element(X, "X"), _element(Y, "Y"), (2, 2), (MAT, MAT))


def inverse(X):
    """(..., 3, 3) → (..., 3, 3): [[Rᵀ, -Rᵀ t], [0, 1]]."""
    if type(X) is _ND and X.shape == _M and X.dtype is _F64:
        out = _empty(_M)
        if _inverse_one(X, out):
            return out
    return _jit.apply(_inverse, _element(X, "X"), 2, (MAT, MAT))
