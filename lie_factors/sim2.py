"""Sim(2), GTSAM's Similarity2: tangent x = [x, y, θ, λ], elements 3×3 [[R(θ), t], [0, 1/s]], s = e^λ.

Shapes: ``hat``, ``exp`` (..., 4) → (..., 3, 3); ``vee``, ``log`` (..., 3, 3) → (..., 4);
``ad``, ``dexp``, ``dlog`` (..., 4) → (..., 4, 4); ``Ad`` (..., 3, 3) → (..., 4, 4);
``inverse`` (..., 3, 3) → (..., 3, 3); ``compose`` (..., 3, 3) × (..., 3, 3) → (..., 3, 3).
:mod:`lie_factors.kernels.public` builds these functions (validation, broadcasting, the
single-element fast path) around the cores below, which the factors call directly.

The same vector, matrices and scale convention as GTSAM 4.3 (checked in tests/kernels/test_sim2.py):
``gtsam.Similarity2.Expmap(v).matrix() == sim2.exp(v)``, ``Similarity2.Logmap(S) ==
sim2.log(S.matrix())``, ``Similarity2.Hat == hat``, ``S.AdjointMap() == Ad(S.matrix())``;
GTSAM's ``scale()`` is s = 1/X[2, 2] = e^λ. GTSAM's Expmap/Logmap lose accuracy near
θ = 0 (errors ~1e-13 at θ = 1e-4).

Everything reduces to complex arithmetic with z = λ + iθ: the rotation-scale block
Q = [[λ, −θ], [θ, λ]] of ad_x (Eade, "Derivative of the Exponential Map", Eq. 88) acts
on (x + iy) as multiplication by z, so power series in Q are the same series in z::

    φ1(z) = (e^z − 1)/z = p + iq          (Eade, Eqs. 98, 101, 102)
    φ2(z) = (e^z − 1 − z)/z² = g + ih     (Eade, Eqs. 98, 103, 104 corrected)

and, with P = [[y, −x], [−x, −y]] and u = x + iy (Eade, §5.4)::

    hat(x)  = [[0, −θ, x], [θ, 0, y], [0, 0, −λ]];   vee(X) = [X02, X12, X10, −X22]
    exp(x)  = [[R(θ), e^{−λ} φ1(z) u], [0, e^{−λ}]]
    log(X)  = [t / (X22 φ1(z)), θ, λ],  θ = atan2(X10, X00) ∈ (−π, π],  λ = −ln X22
    ad(x)   = [[Q, P], [0, 0]]                                (Eade, Eq. 88)
    Ad(X)   = [[R, (t_y, −t_x), −t] / X22, [0, I]]
    dexp(x) = [[φ1(Q), φ2(Q) P], [0, I]]                      (Eade, Eq. 100)
    dlog(x) = [[φ1(Q)⁻¹, −φ1(Q)⁻¹ φ2(Q) P], [0, I]]           (Eade, Eqs. 109–110)
    compose(X, Y) = X Y,   inverse(X) = [[Rᵀ, −Rᵀ t/X22], [0, 1/X22]]

For |z| < ``PHI_TAYLOR`` φ1 and φ2 come from their power series (``PHI_TERMS`` terms),
which is the only accurate way as λ² + θ² → 0 along any direction; above it, the
closed forms with e^z − 1 = expm1(λ) cos θ − 2 sin²(θ/2) + i e^λ sin θ.

``dexp`` is the LEFT Jacobian Σ ad^i/(i+1)! (Eade, Eq. 35):
exp(x + ε) ≈ exp(dexp(x) ε)·exp(x); a GTSAM-style right Jacobian is dexp(−x).
"""

from __future__ import annotations

import math

import numpy as np

from . import se2 as _se2
from .kernels import jit as _jit, public as _public, registry as _registry

_info = _registry.SIM2
DIM, MAT = _info.dim, _info.mat

#: |z| = |λ + iθ| below this: φ1, φ2 from their power series. Above it the closed
#: form of φ2 = (e^z - 1 - z)/z² has absolute error ≲ 3ε/|z|² ≤ 7e-16.
PHI_TAYLOR = 1.0
#: Series terms: the remainder at |z| = 1 is < 1/21! ≈ 2e-20.
PHI_TERMS = 20

_PHI1_SERIES = np.array([1.0 / math.factorial(k + 1) for k in range(PHI_TERMS)])
_PHI2_SERIES = np.array([1.0 / math.factorial(k + 2) for k in range(PHI_TERMS)])


@_jit.helper_kernel
def _phi(lam, th):
    """(p, q, g, h) with φ1(λ + iθ) = p + iq and φ2(λ + iθ) = g + ih."""
    if lam * lam + th * th < PHI_TAYLOR * PHI_TAYLOR:
        # complex Horner, z = λ + iθ; replaces the first-order Eade, Eqs. (105)-(108)
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
    # φ2 = (e^z - 1 - z) z̄²/|z|⁴ = (φ1 - 1)/z; the literal Eade, Eqs. (103)-(104) are off
    # by a factor 1/(λ² + θ²) (docs/errata.md)
    nr = er - lam
    ni = ei - th
    n4 = n2 * n2
    g = (nr * (lam * lam - th * th) + 2.0 * ni * lam * th) / n4
    h = (ni * (lam * lam - th * th) - 2.0 * nr * lam * th) / n4
    return p, q, g, h


# --- cores -----------------------------------------------------------------------------------


@_jit.helper_kernel
def _write4(out, upper, d):
    """out = [[upper[0] … upper[3]], [upper[4] … upper[7]], [0, 0, d, 0], [0, 0, 0, d]]: the form of
    ad (d = 0), Ad, D_exp and D_log (d = 1) (Eade, Eqs. 88, 100, 110)."""
    for j in range(4):
        out[0, j] = upper[j]
        out[1, j] = upper[4 + j]
        out[2, j] = 0.0
        out[3, j] = 0.0
    out[2, 2] = d
    out[3, 3] = d


@_jit.kernel
def _hat(x, out):
    _se2._write(out, 0.0, -x[2], x[0], x[2], 0.0, x[1], -x[3])


@_jit.kernel
def _vee(X, out):
    _se2._vee(X, out)
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
    _se2._write(out, c, -sn, wr * x[0] - wi * x[1], sn, c, wi * x[0] + wr * x[1], s)


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
    _write4(out, (x[3], -x[2], x[1], -x[0], x[2], x[3], -x[0], -x[1]), 0.0)


@_jit.kernel
def _Ad(X, out):
    # X = [[R, t], [0, s]]: X hat(v, φ, μ) X⁻¹ = hat((R v - φ J t - μ t)/s, φ, μ)
    si = 1.0 / X[2, 2]
    tx = X[0, 2]
    ty = X[1, 2]
    _write4(out, (X[0, 0] * si, X[0, 1] * si, ty * si, -tx * si,
                  X[1, 0] * si, X[1, 1] * si, -tx * si, -ty * si), 1.0)


@_jit.kernel
def _dexp(x, out):
    p, q, g, h = _phi(x[3], x[2])
    X0 = x[0]
    Y0 = x[1]
    # Eade, Eq. (100): [[φ1(Q), φ2(Q) P], [0, I]], with
    # [[g, -h], [h, g]] · [[y, -x], [-x, -y]] the upper right block
    _write4(out, (p, -q, g * Y0 + h * X0, h * Y0 - g * X0,
                  q, p, h * Y0 - g * X0, -(g * Y0 + h * X0)), 1.0)


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
    _write4(out, (ar, -ai, -(pr * Y0 + pi * X0), -(pi * Y0 - pr * X0),
                  ai, ar, -(pi * Y0 - pr * X0), pr * Y0 + pi * X0), 1.0)


#: X·Y: the 3×3 matrix product; X⁻¹ = [[Rᵀ, −Rᵀ t/s], [0, 1/s]] (the kernel SE(2) uses too).
_compose = _se2._compose
_inverse = _se2._inverse


# ---------------------------------------------------------------- public functions

hat, vee, exp, log, ad, Ad, dexp, dlog, compose, inverse = _public.functions(_info, globals())
