"""SO(3), GTSAM's Rot3: tangent x = ω = [ω1, ω2, ω3], elements 3×3 rotation matrices R.

Shapes: ``hat``, ``exp``, ``ad``, ``dexp``, ``dlog`` (..., 3) → (..., 3, 3); ``vee``, ``log``
(..., 3, 3) → (..., 3); ``Ad``, ``inverse`` (..., 3, 3) → (..., 3, 3); ``compose``
(..., 3, 3) × (..., 3, 3) → (..., 3, 3). :mod:`lie_factors.kernels.public` builds these
functions (validation, broadcasting, the single-element fast path) around the cores
below (``_exp(x, out)`` ...), which the factors call directly.

Closed forms, θ = |ω|, with the coefficients a_θ, b_θ, c_θ, e_θ of
:mod:`lie_factors.kernels.coeffs` (Eade, "Derivative of the Exponential Map", Eqs. 50–52, 57)::

    hat(ω)  = ω× = [[0, −ω3, ω2], [ω3, 0, −ω1], [−ω2, ω1, 0]];   vee(X) = [X21, X02, X10]
    exp(ω)  = I + a_θ ω× + b_θ ω×²      Rodrigues (Jackson, "Part 6: Computing the Matrix
                                        Exponential", eq:so3_exp)
    log(R)  = θ/sin θ · vee(R − Rᵀ)/2   |ω| ≤ π (Jackson's boxed SO(3) logarithm); near π
                                        from (R + Rᵀ)/2 − cos θ I = (1 − cos θ) n nᵀ
    ad(ω)   = ω×                        (Eade, Eq. 43)
    Ad(R)   = R,   compose(R1, R2) = R1 R2,   inverse(R) = Rᵀ
    dexp(ω) = I + b_θ ω× + c_θ ω×²      D_exp(ω) (Eade, Eqs. 35, 46; = Eq. 53)
    dlog(ω) = I − ½ ω× + e_θ ω×²        D_exp(ω)⁻¹ (Eade, Eqs. 55–57), |ω| < 2π

``dexp(x)`` is the LEFT Jacobian: exp(x + ε) ≈ exp(dexp(x) ε) · exp(x). GTSAM's
``Rot3.ExpmapDerivative(x)`` is the right Jacobian and equals ``dexp(-x)``
(``LogmapDerivative(x) == dlog(-x)``).
"""

from __future__ import annotations

import math

from lie_factors.kernels import public as _public, registry as _registry
from lie_factors.kernels.coeffs import a_theta, b_theta, c_theta, e_omega, norm3
from lie_factors.kernels.jit import helper_kernel, kernel

_info = _registry.SO3
DIM, MAT = _info.dim, _info.mat

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


@helper_kernel
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
    """Rodrigues' formula exp(ω×) = I + a_θ ω× + b_θ ω×² (Jackson, eq:so3_exp), with
    a_θ = sin θ/θ and b_θ = (1 − cos θ)/θ² from their Taylor bands near 0."""
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


# ---------------------------------------------------------------- public functions

hat, vee, exp, log, ad, Ad, dexp, dlog, compose, inverse = _public.functions(_info, globals())
