"""SE(3), GTSAM's Pose3: tangent x = [ω, v] (ROTATION FIRST), elements 4×4 [[R, t], [0, 1]].

Shapes: ``hat``, ``exp`` (..., 6) → (..., 4, 4); ``vee``, ``log`` (..., 4, 4) → (..., 6);
``ad``, ``dexp``, ``dlog`` (..., 6) → (..., 6, 6); ``Ad`` (..., 4, 4) → (..., 6, 6);
``inverse`` (..., 4, 4) → (..., 4, 4); ``compose`` (..., 4, 4) × (..., 4, 4) → (..., 4, 4).
:mod:`lie_factors.kernels.public` builds these functions (validation, broadcasting, the
single-element fast path) around the cores below, which the factors call directly.

Eade, "Derivative of the Exponential Map" (§5.2) writes the tangent as [u, ω]
(translation first), so its block matrices appear transposed here: its upper-right
block is our lower-left one. In our ordering, with θ = |ω|, J = D_exp(ω) of SO(3) and
the coefficients a_θ, b_θ, c_θ, e_θ of :mod:`lie_factors.kernels.coeffs`::

    hat(x)  = [[ω×, v], [0, 0]];   vee(X) = [X21, X02, X10, X03, X13, X23]
    exp(x)  = [[R, V v], [0, 1]],  R = I + a_θ ω× + b_θ ω×²,  V = J = I + b_θ ω× + c_θ ω×²
              (Jackson, "Part 6: Computing the Matrix Exponential", boxed SE(3) exp)
    log(X)  = [ω, V⁻¹ t],  ω = Log R (SO(3)),  V⁻¹ = I − ½ ω× + e_θ ω×²  (Jackson's boxed
              SE(3) log; = Eade, Eq. 55), |ω| ≤ π
    ad(x)   = [[ω×, 0], [v×, ω×]]                  (Eade, Eq. 61, blocks swapped)
    Ad(X)   = [[R, 0], [t× R, R]]
    dexp(x) = [[J, 0], [B, J]]                     (Eade, Eqs. 70–71 transposed; B: Eq. 74)
    dlog(x) = [[J⁻¹, 0], [−J⁻¹ B J⁻¹, J⁻¹]]        (Eade, Eqs. 73–75), |ω| < 2π
    compose(X, Y) = X Y,   inverse(X) = [[Rᵀ, −Rᵀ t], [0, 1]]

``dexp(x)`` is the LEFT Jacobian (Eade, Eq. 35): exp(x + ε) ≈ exp(dexp(x) ε) · exp(x);
GTSAM's ``Pose3.ExpmapDerivative(x) == dexp(-x)`` (``LogmapDerivative(x) == dlog(-x)``).
"""

from __future__ import annotations

from lie_factors import so3 as _so3
from lie_factors.kernels import public as _public, registry as _registry
from lie_factors.kernels.coeffs import (a_theta, b_theta, c_theta, dot3, e_omega, ef_omega, norm3, qa_theta, qb_theta)
from lie_factors.kernels.jit import helper_kernel, kernel

_info = _registry.SE3
DIM, MAT = _info.dim, _info.mat


# ---------------------------------------------------------------- 3×3 helpers on 9-tuples
# Row-major 9-tuples stay in registers: the cores allocate nothing.


@helper_kernel
def rod9(w0, w1, w2, p, q):
    """I + p ω× + q ω×² as a 9-tuple (ω×² = ωωᵀ − θ² I, Eade Eq. 47)."""
    return lin9(w0, w1, w2, 1.0, p, q)


@helper_kernel
def lin9(w0, w1, w2, d, p, q):
    """d I + p ω× + q ω×² as a 9-tuple."""
    q01 = q * w0 * w1
    q02 = q * w0 * w2
    q12 = q * w1 * w2
    return (
        d - q * (w1 * w1 + w2 * w2), q01 - p * w2, q02 + p * w1,
        q01 + p * w2, d - q * (w0 * w0 + w2 * w2), q12 - p * w0,
        q02 - p * w1, q12 + p * w0, d - q * (w0 * w0 + w1 * w1),
    )


@helper_kernel
def _B9(w0, w1, w2, u0, u1, u2, th):
    g = w0 * u0 + w1 * u1 + w2 * u2
    return _B9c(w0, w1, w2, u0, u1, u2, g, b_theta(th), c_theta(th), qa_theta(th), qb_theta(th))


@helper_kernel
def _B9c(w0, w1, w2, u0, u1, u2, g, b, c, qa, qb):
    """Eade Eq. (74) (= the off-diagonal block of Eq. 71), with u = v:

        B = b u× + c (ω uᵀ + u ωᵀ) + (ωᵀu) W,
        W = (c − b) I + qa ω× + qb ω ωᵀ              (Eq. 70)
    """
    gd = g * (c - b)
    ga = g * qa
    gb = g * qb
    return (
        gd + 2.0 * c * w0 * u0 + gb * w0 * w0,
        -b * u2 + c * (w0 * u1 + u0 * w1) - ga * w2 + gb * w0 * w1,
        b * u1 + c * (w0 * u2 + u0 * w2) + ga * w1 + gb * w0 * w2,
        b * u2 + c * (w1 * u0 + u1 * w0) + ga * w2 + gb * w1 * w0,
        gd + 2.0 * c * w1 * u1 + gb * w1 * w1,
        -b * u0 + c * (w1 * u2 + u1 * w2) - ga * w0 + gb * w1 * w2,
        -b * u1 + c * (w2 * u0 + u2 * w0) - ga * w1 + gb * w2 * w0,
        b * u0 + c * (w2 * u1 + u2 * w1) + ga * w0 + gb * w2 * w1,
        gd + 2.0 * c * w2 * u2 + gb * w2 * w2,
    )


@helper_kernel
def _write_block_lower(D, L, out):
    """out = [[D, 0], [L, D]] for 9-tuples D, L."""
    for i in range(3):
        for j in range(3):
            d = D[3 * i + j]
            out[i, j] = d
            out[i + 3, j + 3] = d
            out[i, j + 3] = 0.0
            out[i + 3, j] = L[3 * i + j]


# ---------------------------------------------------------------- cores


@kernel
def _hat(x, out):
    # [[ω×, v], [0, 0]]
    _so3._hat(x, out)
    for i in range(3):
        out[i, 3] = x[i + 3]
        out[3, i] = 0.0
    out[3, 3] = 0.0


@kernel
def _vee(X, out):
    _so3._vee(X, out)
    for i in range(3):
        out[i + 3] = X[i, 3]


@kernel
def _exp(x, out):
    # exp = [[R, J v], [0, 1]] with R = I + a ω× + b ω×² and J = V = I + b ω× + c ω×²
    # (Jackson, SE(3) boxed formula; V there is Eade's D_exp(ω), Eq. 46).
    w0, w1, w2 = x[0], x[1], x[2]
    th = norm3(w0, w1, w2)
    a = a_theta(th)
    b = b_theta(th)
    c = c_theta(th)
    R = rod9(w0, w1, w2, a, b)
    V = rod9(w0, w1, w2, b, c)
    for i in range(3):
        out[i, 0] = R[3 * i]
        out[i, 1] = R[3 * i + 1]
        out[i, 2] = R[3 * i + 2]
        out[i, 3] = V[3 * i] * x[3] + V[3 * i + 1] * x[4] + V[3 * i + 2] * x[5]
        out[3, i] = 0.0
    out[3, 3] = 1.0


@kernel
def _log(X, out):
    # ω = log R (so3 core); v = V⁻¹ t with V⁻¹ = D_exp⁻¹(ω) = I − ½ω× + e_θ ω×²
    # (Jackson's V⁻¹ expression = Eade, Eq. 55).
    _so3._log(X, out)
    w0, w1, w2 = out[0], out[1], out[2]
    Vi = rod9(w0, w1, w2, -0.5, e_omega(w0, w1, w2))
    t0, t1, t2 = X[0, 3], X[1, 3], X[2, 3]
    out[3] = Vi[0] * t0 + Vi[1] * t1 + Vi[2] * t2
    out[4] = Vi[3] * t0 + Vi[4] * t1 + Vi[5] * t2
    out[5] = Vi[6] * t0 + Vi[7] * t1 + Vi[8] * t2


@kernel
def _ad(x, out):
    # ad_x = [[ω×, 0], [v×, ω×]] (Eade Eq. 61 with blocks swapped to [ω, v]).
    W = rod9(x[0], x[1], x[2], 1.0, 0.0)
    U = rod9(x[3], x[4], x[5], 1.0, 0.0)
    W = (0.0, W[1], W[2], W[3], 0.0, W[5], W[6], W[7], 0.0)
    U = (0.0, U[1], U[2], U[3], 0.0, U[5], U[6], U[7], 0.0)
    _write_block_lower(W, U, out)


@kernel
def _Ad(X, out):
    # Ad_X = [[R, 0], [t× R, R]]: X hat(ω, v) X⁻¹ = hat(Rω, t × Rω + R v).
    t0, t1, t2 = X[0, 3], X[1, 3], X[2, 3]
    for j in range(3):
        r0, r1, r2 = X[0, j], X[1, j], X[2, j]
        out[0, j] = r0
        out[1, j] = r1
        out[2, j] = r2
        out[3, j + 3] = r0
        out[4, j + 3] = r1
        out[5, j + 3] = r2
        out[0, j + 3] = 0.0
        out[1, j + 3] = 0.0
        out[2, j + 3] = 0.0
        out[3, j] = t1 * r2 - t2 * r1
        out[4, j] = t2 * r0 - t0 * r2
        out[5, j] = t0 * r1 - t1 * r0


@kernel
def _dexp(x, out):
    # D_exp(x) = [[J, 0], [B, J]]: Eade Eq. (71) transposed to [ω, v].
    w0, w1, w2 = x[0], x[1], x[2]
    th = norm3(w0, w1, w2)
    J = rod9(w0, w1, w2, b_theta(th), c_theta(th))
    B = _B9(w0, w1, w2, x[3], x[4], x[5], th)
    _write_block_lower(J, B, out)


@kernel
def _dlog(x, out):
    # D_exp⁻¹(x) = [[J⁻¹, 0], [L, J⁻¹]] with L = −J⁻¹ B J⁻¹: Eade Eqs. (73)–(75),
    # J⁻¹ = I − ½ω× + e_θ ω×² from Eq. (55). The product is not formed: L is the
    # derivative of J⁻¹(ω) along u = v (verified symbolically and in the tests),
    #   L = −½ u× + e_θ (ω×u× + u×ω×) + (ωᵀu) f_θ ω×²,   f_θ = e_θ'/θ,
    # with ω×u× + u×ω× = ωuᵀ + uωᵀ − 2(ωᵀu) I (Eq. 67). Besides being cheaper,
    # the product form amplifies the rounding of B by (e_θ θ²)² ~ (2π/(2π − θ))²
    # as θ → 2π, this form does not. ωᵀu is compensated: it multiplies f_θ ~ 1/(2π − θ)².
    w0, w1, w2 = x[0], x[1], x[2]
    u0, u1, u2 = x[3], x[4], x[5]
    th, e, f = ef_omega(w0, w1, w2)
    g = dot3(w0, w1, w2, u0, u1, u2)
    gf = g * f
    gd = -2.0 * e * g
    L = lin9(w0, w1, w2, gd, 0.0, gf)
    e01 = e * (w0 * u1 + u0 * w1)
    e02 = e * (w0 * u2 + u0 * w2)
    e12 = e * (w1 * u2 + u1 * w2)
    L = (
        L[0] + 2.0 * e * w0 * u0, L[1] + e01 + 0.5 * u2, L[2] + e02 - 0.5 * u1,
        L[3] + e01 - 0.5 * u2, L[4] + 2.0 * e * w1 * u1, L[5] + e12 + 0.5 * u0,
        L[6] + e02 + 0.5 * u1, L[7] + e12 - 0.5 * u0, L[8] + 2.0 * e * w2 * u2,
    )
    _write_block_lower(rod9(w0, w1, w2, -0.5, e), L, out)


@kernel
def _compose(X, Y, out):
    for i in range(3):
        for j in range(4):
            out[i, j] = X[i, 0] * Y[0, j] + X[i, 1] * Y[1, j] + X[i, 2] * Y[2, j]
        out[i, 3] += X[i, 3]
        out[3, i] = 0.0
    out[3, 3] = 1.0


@kernel
def _inverse(X, out):
    for i in range(3):
        for j in range(3):
            out[i, j] = X[j, i]
        out[i, 3] = -(X[0, i] * X[0, 3] + X[1, i] * X[1, 3] + X[2, i] * X[2, 3])
        out[3, i] = 0.0
    out[3, 3] = 1.0


# ---------------------------------------------------------------- public functions

hat, vee, exp, log, ad, Ad, dexp, dlog, compose, inverse = _public.functions(_info, globals())
