"""SE(2), GTSAM's Pose2: tangent x = [x, y, θ] (TRANSLATION FIRST), elements 3×3 [[R(θ), t], [0, 1]].

Shapes: every function (..., 3) or (..., 3, 3) → (..., 3) or (..., 3, 3): ``hat``,
``exp``, ``ad``, ``dexp``, ``dlog`` take tangents; ``log``, ``Ad``, ``inverse``,
``compose`` elements; ``vee`` an algebra matrix. :mod:`lie_factors.kernels.public`
builds these functions (validation, broadcasting, the single-element fast path)
around the cores below, which the factors call directly.

Closed forms (Eade, "Derivative of the Exponential Map", §5.3), with J = [[0, −1], [1, 0]],
u = (x, y) and the coefficients a = sin θ/θ, b = (1 − cos θ)/θ², c = (1 − a)/θ²
(Eade, Eqs. 50–52)::

    hat(x)  = [[0, −θ, x], [θ, 0, y], [0, 0, 0]];   vee(X) = [X02, X12, X10]
    exp(x)  = [[R(θ), V u], [0, 1]],  V = a I + θ b J                  (Eade, Eq. 83's block)
    log(X)  = [V⁻¹ t, θ],  θ = atan2(X10, X00) ∈ (−π, π],  V⁻¹ = α I − (θ/2) J, α = (θ/2) cot(θ/2)
    ad(x)   = [[θ J, −J u], [0, 0]]                                    (Eade, Eq. 78)
    Ad(X)   = [[R, −J t], [0, 1]]
    dexp(x) = [[a I + θ b J, (θ c x + b y, θ c y − b x)ᵀ], [0, 1]]     (Eade, Eq. 83, corrected:
              Eade drops the factor θ on c; see docs/errata.md)
    dlog(x) = [[A⁻¹, −A⁻¹ w], [0, 1]],  A⁻¹ = α I − (θ/2) J, w the last column of dexp's
              upper block (Eade, Eqs. 84–85); singular at |θ| = 2π
    compose(X, Y) = X Y,   inverse(X) = [[Rᵀ, −Rᵀ t], [0, 1]]

``dexp`` is Eade's D_exp(x) = Σ ad_x^i/(i+1)! (Eq. 35), the LEFT Jacobian:
exp(x + ε) ≈ exp(dexp(x) ε)·exp(x). GTSAM's Pose2.ExpmapDerivative is the right
Jacobian, ``ExpmapDerivative(x) == dexp(-x)`` (likewise Logmap).

a and b have cancellation-free closed forms (b = 2 sin²(θ/2)/θ²) and only need a
Taylor band to avoid 0/0; c cancels catastrophically (relative error ≈ 6ε/θ²), so it
uses its power series up to ``C_TAYLOR``.
"""

from __future__ import annotations

import math

import numpy as np

from . import so3 as _so3
from .kernels import jit as _jit, public as _public, registry as _registry

_info = _registry.SE2
DIM, MAT = _info.dim, _info.mat

#: |θ| below this: a_θ, b_θ from their Taylor polynomials (closed forms are 0/0
#: at θ = 0; the omitted θ⁶/5040 term is < 2e-28 here).
ANGLE_TAYLOR = 1e-4
#: |θ| below this: c_θ = (θ - sin θ)/θ³ from its series (closed form loses
#: ≈ 2ε/θ relative accuracy in the dexp entries; at θ = 1 that is ≤ 4e-16).
C_TAYLOR = 1.0

# c_θ = Σ_k (-1)^k θ^{2k}/(2k+3)!  (Eade, Eq. 81, second sum); 10 terms reach
# θ^18/21! < 2e-20 at |θ| = 1.
C_SERIES = np.array([(-1.0) ** k / math.factorial(2 * k + 3) for k in range(10)])


@_jit.helper_kernel
def _ab(th):
    """(a_θ, b_θ) of Eade, Eqs. (50), (51)."""
    if abs(th) < ANGLE_TAYLOR:
        t = th * th
        return 1.0 - t / 6.0 * (1.0 - t / 20.0), 0.5 - t / 24.0 * (1.0 - t / 30.0)
    s = math.sin(0.5 * th) / th
    # 1 - cos θ = 2 sin²(θ/2) avoids the cancellation of the literal Eq. (51)
    return math.sin(th) / th, 2.0 * s * s


@_jit.helper_kernel
def _c(th):
    """c_θ = (1 - a_θ)/θ² of Eade, Eq. (52)."""
    if abs(th) < C_TAYLOR:
        t = th * th
        s = 0.0
        for k in range(C_SERIES.shape[0] - 1, -1, -1):
            s = s * t + C_SERIES[k]
        return s
    return (th - math.sin(th)) / (th * th * th)


@_jit.helper_kernel
def _write(out, m00, m01, m02, m10, m11, m12, m22):
    """out = [[m00, m01, m02], [m10, m11, m12], [0, 0, m22]]: the form of every 3×3 matrix of
    SE(2) and Sim(2) (elements, algebra matrices, ad, Ad, D_exp, D_log)."""
    out[0, 0] = m00
    out[0, 1] = m01
    out[0, 2] = m02
    out[1, 0] = m10
    out[1, 1] = m11
    out[1, 2] = m12
    out[2, 0] = 0.0
    out[2, 1] = 0.0
    out[2, 2] = m22


# --- cores -----------------------------------------------------------------------------------


@_jit.kernel
def _hat(x, out):
    _write(out, 0.0, -x[2], x[0], x[2], 0.0, x[1], 0.0)


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
    c = math.cos(th)
    s = math.sin(th)
    _write(out, c, -s, a * x[0] - tb * x[1], s, c, tb * x[0] + a * x[1], 1.0)


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
    # Eade, Eq. (78): [[θ J, −J u], [0, 0]]
    _write(out, 0.0, -x[2], x[1], x[2], 0.0, -x[0], 0.0)


@_jit.kernel
def _Ad(X, out):
    # X hat(v, φ) X⁻¹ = hat(R v - φ J t, φ): Ad = [[R, -J t], [0, 1]], -J t = (t_y, -t_x)
    _write(out, X[0, 0], X[0, 1], X[1, 2], X[1, 0], X[1, 1], -X[0, 2], 1.0)


@_jit.kernel
def _dexp(x, out):
    th = x[2]
    a, b = _ab(th)
    tc = th * _c(th)
    tb = th * b
    # Eade, Eq. (83) corrected: third column (θ c x + b y, θ c y - b x); Eade
    # drops the factor θ on c (see docs/errata.md)
    _write(out, a, -tb, tc * x[0] + b * x[1], tb, a, tc * x[1] - b * x[0], 1.0)


@_jit.kernel
def _dlog(x, out):
    th = x[2]
    a, b = _ab(th)
    # Eade, Eqs. (84)-(85): D_log = [[A⁻¹, -A⁻¹ v], [0, 1]], with the 2×2 inverse
    # A⁻¹ = (a I - θ b J)/(a² + θ² b²) = α I - (θ/2) J since a² + θ² b² = 2 b
    al = a / (2.0 * b)
    h = 0.5 * th
    tc = th * _c(th)
    v0 = tc * x[0] + b * x[1]
    v1 = tc * x[1] - b * x[0]
    _write(out, al, h, -(al * v0 + h * v1), -h, al, h * v0 - al * v1, 1.0)


#: X·Y: the 3×3 matrix product.
_compose = _so3._compose


@_jit.kernel
def _inverse(X, out):
    # [[Rᵀ, −Rᵀ t/s], [0, 1/s]] for X = [[R, t], [0, s]]: Sim(2)'s inverse too; for SE(2)
    # s = 1 and the products with 1/s = 1 are exact
    si = 1.0 / X[2, 2]
    tx = X[0, 2]
    ty = X[1, 2]
    _write(out, X[0, 0], X[1, 0], -(X[0, 0] * tx + X[1, 0] * ty) * si,
           X[0, 1], X[1, 1], -(X[0, 1] * tx + X[1, 1] * ty) * si, si)


# ---------------------------------------------------------------- public functions

hat, vee, exp, log, ad, Ad, dexp, dlog, compose, inverse = _public.functions(_info, globals())
