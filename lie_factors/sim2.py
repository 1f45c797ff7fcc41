"""Sim(2), GTSAM's Similarity2: closed-form exp, log, adjoints and D_exp / D_log.

Tangent ordering (as GTSAM's Similarity2)::

    x = [x, y, θ, λ]                   shape (..., 4)
    hat(x) = [[0, -θ,  x],
              [θ,  0,  y],
              [0,  0, -λ]]             shape (..., 3, 3)
    group element [[R(θ), t], [0, 0, s]],  s = e^{-λ} > 0

Relation to GTSAM (checked numerically against gtsam 4.3 in tests/test_sim2.py):
``gtsam.Similarity2.Expmap(v).matrix() == sim2.exp(v)`` and
``gtsam.Similarity2.Logmap(S) == sim2.log(S.matrix())`` with the *same* vector
``v = [x, y, θ, λ]`` and the same scale convention (corner e^{-λ}; GTSAM's
``scale()`` is 1/corner = e^{λ}); ``Similarity2.Hat`` equals ``hat`` and
``Similarity2.AdjointMap(S) == Ad(S.matrix())``. No reordering is needed.
GTSAM's Expmap/Logmap lose accuracy near θ = 0 (errors ~1e-13 at θ = 1e-4).

Everything reduces to complex arithmetic with ``z = λ + iθ``: the rotation-scale
block Q = [[λ, -θ], [θ, λ]] of ad_x (Eade, Eq. 88) acts on (x + iy) as
multiplication by z, so power series in Q are the same series in z:

    φ1(z) = (e^z - 1)/z = p + iq          (Eade, Eqs. 98, 101, 102)
    φ2(z) = (e^z - 1 - z)/z² = g + ih     (Eade, Eqs. 98, 103, 104 corrected)

For |z| < ``PHI_TAYLOR`` both come from their power series (``PHI_TERMS`` terms),
which is the only accurate way as λ² + θ² → 0 along any direction; above it,
the closed forms with e^z - 1 = expm1(λ) cos θ - 2 sin²(θ/2) + i e^λ sin θ.

``dexp`` is the LEFT Jacobian Σ ad^i/(i+1)! (Eade, Eq. 35):
exp(x + ε) ≈ exp(dexp(x) ε)·exp(x); GTSAM's right Jacobian would be dexp(-x).
"""

from __future__ import annotations

import math

import numpy as np

from .kernels import checks as _check, jit as _jit, validate as _validate

DIM = 4
MAT = 3

#: |z| = |λ + iθ| below this: φ1, φ2 from their power series. Above it the closed
#: form of φ2 = (e^z - 1 - z)/z² has absolute error ≲ 3ε/|z|² ≤ 7e-16.
PHI_TAYLOR = 1.0
#: Series terms: the remainder at |z| = 1 is < 1/21! ≈ 2e-20.
PHI_TERMS = 20

_PHI1_SERIES = np.array([1.0 / math.factorial(k + 1) for k in range(PHI_TERMS)])
_PHI2_SERIES = np.array([1.0 / math.factorial(k + 2) for k in range(PHI_TERMS)])


@_jit.kernel
def _phi(lam, th):
    """(p, q, g, h) with φ1(λ + iθ) = p + iq and φ2(λ + iθ) = g + ih."""
    if lam * lam + th * th < PHI_TAYLOR * PHI_TAYLOR:
        # complex Horner, z = λ + iθ; replaces the first-order seed Eqs. (105)-(108)
        pr = _PHI1_SERIES[PHI_TERMS - 1]
        pi = 0.0
        gr = _PHI2_SERIES[PHI_TERMS - 1]
        gi = 0.0
        for k in range(PHI_TERMS - 2, -1, -1):
            pr, pi = pr * lam - pi * th + _PHI1_SERIES[k], pr * th + pi * lam
            gr, gi = gr * lam - gi * th + _PHI2_SERIES[k], gr * th + gi * lam
        return pr, pi, gr, gi
    n2 = lam * lam + th * th
    s = math.sin(0.5 * th)
    # e^z - 1 without cancelling e^λ cos θ against 1 when λ and θ are separately small
    er = math.expm1(lam) * math.cos(th) - 2.0 * s * s
    ei = math.exp(lam) * math.sin(th)
    # Eade, Eqs. (101), (102): φ1 = (e^z - 1) z̄/|z|²
    p = (er * lam + ei * th) / n2
    q = (ei * lam - er * th) / n2
    # φ2 = (e^z - 1 - z) z̄²/|z|⁴ = (φ1 - 1)/z; the literal seed Eqs. (103)-(104) are off
    # by a factor 1/(λ² + θ²) (docs/errata.md)
    nr = er - lam
    ni = ei - th
    n4 = n2 * n2
    g = (nr * (lam * lam - th * th) + 2.0 * ni * lam * th) / n4
    h = (ni * (lam * lam - th * th) - 2.0 * nr * lam * th) / n4
    return p, q, g, h


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
    out[2, 2] = -x[3]


@_jit.kernel
def _vee(X, out):
    out[0] = X[0, 2]
    out[1] = X[1, 2]
    out[2] = X[1, 0]
    out[3] = -X[2, 2]


@_jit.kernel
def _exp(x, out):
    th = x[2]
    lam = x[3]
    p, q, g, h = _phi(lam, th)
    s = math.exp(-lam)
    # t = ∫₀¹ e^{(1-τ)iθ} e^{-τλ} dτ (x + iy) = (e^{iθ} - e^{-λ})/(λ + iθ) (x + iy)
    #   = e^{-λ} φ1(z) (x + iy)
    wr = s * p
    wi = s * q
    c = math.cos(th)
    sn = math.sin(th)
    out[0, 0] = c
    out[0, 1] = -sn
    out[0, 2] = wr * x[0] - wi * x[1]
    out[1, 0] = sn
    out[1, 1] = c
    out[1, 2] = wi * x[0] + wr * x[1]
    out[2, 0] = 0.0
    out[2, 1] = 0.0
    out[2, 2] = s


@_jit.kernel
def _log(X, out):
    th = math.atan2(X[1, 0], X[0, 0])
    s = X[2, 2]
    lam = -math.log(s)
    p, q, g, h = _phi(lam, th)
    # invert t = s φ1(z) (x + iy): (x + iy) = t conj(φ1)/(s |φ1|²)
    d = s * (p * p + q * q)
    tx = X[0, 2]
    ty = X[1, 2]
    out[0] = (p * tx + q * ty) / d
    out[1] = (p * ty - q * tx) / d
    out[2] = th
    out[3] = lam


@_jit.kernel
def _ad(x, out):
    # Eade, Eq. (88): [[Q, P], [0, 0]], Q = [[λ, -θ], [θ, λ]], P = [[y, -x], [-x, -y]]
    for i in range(2, 4):
        for j in range(4):
            out[i, j] = 0.0
    out[0, 0] = x[3]
    out[0, 1] = -x[2]
    out[0, 2] = x[1]
    out[0, 3] = -x[0]
    out[1, 0] = x[2]
    out[1, 1] = x[3]
    out[1, 2] = -x[0]
    out[1, 3] = -x[1]


@_jit.kernel
def _Ad(X, out):
    # X = [[R, t], [0, s]]: X hat(v, φ, μ) X⁻¹ = hat((R v - φ J t - μ t)/s, φ, μ)
    si = 1.0 / X[2, 2]
    tx = X[0, 2]
    ty = X[1, 2]
    for i in range(2, 4):
        for j in range(4):
            out[i, j] = 0.0
    out[2, 2] = 1.0
    out[3, 3] = 1.0
    out[0, 0] = X[0, 0] * si
    out[0, 1] = X[0, 1] * si
    out[1, 0] = X[1, 0] * si
    out[1, 1] = X[1, 1] * si
    out[0, 2] = ty * si
    out[1, 2] = -tx * si
    out[0, 3] = -tx * si
    out[1, 3] = -ty * si


@_jit.kernel
def _dexp(x, out):
    p, q, g, h = _phi(x[3], x[2])
    X0 = x[0]
    Y0 = x[1]
    for i in range(2, 4):
        for j in range(4):
            out[i, j] = 0.0
    # Eade, Eq. (100): [[φ1(Q), φ2(Q) P], [0, I]]
    out[2, 2] = 1.0
    out[3, 3] = 1.0
    out[0, 0] = p
    out[0, 1] = -q
    out[1, 0] = q
    out[1, 1] = p
    # [[g, -h], [h, g]] · [[y, -x], [-x, -y]]
    out[0, 2] = g * Y0 + h * X0
    out[0, 3] = h * Y0 - g * X0
    out[1, 2] = h * Y0 - g * X0
    out[1, 3] = -(g * Y0 + h * X0)


@_jit.kernel
def _dlog(x, out):
    p, q, g, h = _phi(x[3], x[2])
    X0 = x[0]
    Y0 = x[1]
    # Eade, Eqs. (109)-(110): D_log = [[A⁻¹, -A⁻¹ B], [0, I]] with the analytic
    # 2×2 inverse A⁻¹ = [[p, q], [-q, p]]/(p² + q²) (i.e. 1/φ1(z))
    d = p * p + q * q
    ar = p / d
    ai = -q / d
    # A⁻¹ B = ψ(Q) P, ψ = φ2/φ1 (rotation-scale blocks commute)
    pr = ar * g - ai * h
    pi = ar * h + ai * g
    for i in range(2, 4):
        for j in range(4):
            out[i, j] = 0.0
    out[2, 2] = 1.0
    out[3, 3] = 1.0
    out[0, 0] = ar
    out[0, 1] = -ai
    out[1, 0] = ai
    out[1, 1] = ar
    out[0, 2] = -(pr * Y0 + pi * X0)
    out[0, 3] = -(pi * Y0 - pr * X0)
    out[1, 2] = -(pi * Y0 - pr * X0)
    out[1, 3] = pr * Y0 + pi * X0


@_jit.kernel
def _compose(X, Y, out):
    for i in range(3):
        for j in range(3):
            out[i, j] = X[i, 0] * Y[0, j] + X[i, 1] * Y[1, j] + X[i, 2] * Y[2, j]


@_jit.kernel
def _inverse(X, out):
    # [[Rᵀ, -Rᵀ t/s], [0, 1/s]]
    si = 1.0 / X[2, 2]
    tx = X[0, 2]
    ty = X[1, 2]
    out[0, 0] = X[0, 0]
    out[0, 1] = X[1, 0]
    out[0, 2] = -(X[0, 0] * tx + X[1, 0] * ty) * si
    out[1, 0] = X[0, 1]
    out[1, 1] = X[1, 1]
    out[1, 2] = -(X[0, 1] * tx + X[1, 1] * ty) * si
    out[2, 0] = 0.0
    out[2, 1] = 0.0
    out[2, 2] = si


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
    if not _check.element_ok(X, 2, _check.POSITIVE):
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
    if not _check.element_ok(X, 2, _check.POSITIVE):
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
    if not (_check.element_ok(X, 2, _check.POSITIVE) and _check.element_ok(Y, 2, _check.POSITIVE)):
        return False
    _compose(X, Y, out)
    return True


@_jit.kernel
def _inverse1(X, out):
    X = np.ascontiguousarray(X)
    if not _check.element_ok(X, 2, _check.POSITIVE):
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

_ROW = "[0, 0, s]"


def _element(X, name):
    arr = _validate.square(X, MAT, name)
    _validate.rotation_block(arr, name, 2)
    _validate.bottom_row(arr, name, _ROW, last_positive=True)
    return arr


def hat(x):
    """(..., 4) → (..., 3, 3): [[0, -θ, x], [θ, 0, y], [0, 0, -λ]]."""
    if type(x) is _ND and x.shape == _V and x.dtype is _F64:
        out = _empty(_M)
        if _hat_one(x, out):
            return out
    return _jit.apply(_hat, _validate.tangent(x, DIM), 1, (MAT, MAT))


def vee(X):
    """(..., 3, 3) → (..., 4): [X[0, 2], X[1, 2], X[1, 0], -X[2, 2]]."""
    if type(X) is _ND and X.shape == _M and X.dtype is _F64:
        out = _empty(_V)
        if _vee_one(X, out):
            return out
    return _jit.apply(_vee, _validate.square(X, MAT, "X"), 2, (DIM,))


def exp(x):
    """(..., 4) → (..., 3, 3): [[R(θ), e^{-λ} φ1(λ + iθ)(x + iy)], [0, e^{-λ}]]."""
    if type(x) is _ND and x.shape == _V and x.dtype is _F64:
        out = _empty(_M)
        if _exp_one(x, out):
            return out
    return _jit.apply(_exp, _validate.tangent(x, DIM), 1, (MAT, MAT))


def log(X):
    """(..., 3, 3) → (..., 4): θ = atan2 ∈ (-π, π], λ = -log s, (x, y) from the 2×2 solve.

    Raises ValueError unless the rotation block is orthonormal and the last row is [0, 0, s], s > 0.
    """
    if type(X) is _ND and X.shape == _M and X.dtype is _F64:
        out = _empty(_V)
        if _log_one(X, out):
            return out
    return _jit.apply(_log, _element(X, "X"), 2, (DIM,))


def ad(x):
    """(..., 4) → (..., 4, 4): ad_x y = vee([hat x, hat y]) (Eade, Eq. 88)."""
    if type(x) is _ND and x.shape == _V and x.dtype is _F64:
        out = _empty(_J)
        if _ad_one(x, out):
            return out
    return _jit.apply(_ad, _validate.tangent(x, DIM), 1, (DIM, DIM))


def Ad(X):
    """(..., 3, 3) → (..., 4, 4): [[R/s, (t_y, -t_x)ᵀ/s, -t/s], [0, I]]; X hat(y) X⁻¹ = hat(Ad(X) y)."""
    if type(X) is _ND and X.shape == _M and X.dtype is _F64:
        out = _empty(_J)
        if _Ad_one(X, out):
            return out
    return _jit.apply(_Ad, _element(X, "X"), 2, (DIM, DIM))


def dexp(x):
    """(..., 4) → (..., 4, 4): left Jacobian [[φ1(Q), φ2(Q) P], [0, I]] (Eade, Eq. 100)."""
    if type(x) is _ND and x.shape == _V and x.dtype is _F64:
        out = _empty(_J)
        if _dexp_one(x, out):
            return out
    return _jit.apply(_dexp, _validate.tangent(x, DIM), 1, (DIM, DIM))


def dlog(x):
    """(..., 4) → (..., 4, 4): D_exp(x)⁻¹ in closed form (Eade, Eqs. 109–110).

    Singular where φ1(λ + iθ) = 0, i.e. λ = 0, θ = ±2π.
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
    """(..., 3, 3) → (..., 3, 3): [[Rᵀ, -Rᵀ t/s], [0, 1/s]]."""
    if type(X) is _ND and X.shape == _M and X.dtype is _F64:
        out = _empty(_M)
        if _inverse_one(X, out):
            return out
    return _jit.apply(_inverse, _element(X, "X"), 2, (MAT, MAT))
