"""The compiled operations of the vocabulary: each computes its value and, with ``jac``, its local
Jacobians (the derivative of its output with respect to each input, in GTSAM's right
perturbation: a group element X moves as X·Exp(δ), a vector p as p + δ).  The generated kernel
of a factor kind (:mod:`lie_factors.expressions.codegen`) calls them in the order of the
residual's expression and chains their Jacobians (:func:`mm_set`, :func:`mm_add`).

Group-generic operations take the group tag ``g`` (:mod:`lie_factors.kernels.dispatch`) and run
the group's own cores (exp, log, dlog, dexp, Ad, compose, inverse).  The identities they rest on
(Eade, "Derivative of the Exponential Map": Eq. 6, Y·Exp(x) = Exp(Ad_Y x)·Y, and Eq. 12, 35,
with the right Jacobian J_r(x) = D_exp(−x), ``docs/conventions.md``) are derived in
docs/factors.md; every formula is tested against differences of the definition.  Rot2 (SO(2),
tangent [θ], a 2×2 rotation matrix) has its own short forms: Ad = 1, J_r = 1.

Geometry (rotation, translation, scale, points) is written per group type: Pose2
[x, y, θ], Pose3 [ω, v], Similarity2 [x, y, θ, λ], Similarity3 [ω, u, λ] (element
[[R, t], [0, 1/s]], s = e^λ, acting as p ↦ s(R p + t), GTSAM's), Rot2, Rot3.  Matrices (an
element's ``matrix()`` and ``AdjointMap()``) are held row by row in 1-D arrays, their Jacobians'
rows in that order.  The projections are in :mod:`lie_factors.expressions.camera`.  An operation
undefined at some values (a division by zero) returns False there, which the kernel reports.
"""

from __future__ import annotations

import math

import numpy as np

from ..kernels import dispatch as _dispatch
from ..kernels.jit import helper_kernel

# --------------------------------------------------------------------------- #
# Small dense algebra for the chain rule
# --------------------------------------------------------------------------- #


@helper_kernel
def mm_set(A, B, out):
    """out = A·B."""
    for i in range(A.shape[0]):
        for j in range(B.shape[1]):
            acc = 0.0
            for k in range(A.shape[1]):
                acc += A[i, k] * B[k, j]
            out[i, j] = acc


@helper_kernel
def mm_add(A, B, out):
    """out += A·B."""
    for i in range(A.shape[0]):
        for j in range(B.shape[1]):
            acc = 0.0
            for k in range(A.shape[1]):
                acc += A[i, k] * B[k, j]
            out[i, j] += acc


@helper_kernel
def copy2(src, out, sign):
    """out = sign·src (2-D)."""
    for i in range(src.shape[0]):
        for j in range(src.shape[1]):
            out[i, j] = sign * src[i, j]


@helper_kernel
def add2(src, out, sign):
    """out += sign·src (2-D)."""
    for i in range(src.shape[0]):
        for j in range(src.shape[1]):
            out[i, j] += sign * src[i, j]


@helper_kernel
def skew_into(x, out, sign):
    """out = sign·[x]× (3×3)."""
    out[0, 0] = 0.0
    out[0, 1] = -sign * x[2]
    out[0, 2] = sign * x[1]
    out[1, 0] = sign * x[2]
    out[1, 1] = 0.0
    out[1, 2] = -sign * x[0]
    out[2, 0] = -sign * x[1]
    out[2, 1] = sign * x[0]
    out[2, 2] = 0.0


# --------------------------------------------------------------------------- #
# Group operations: any registered matrix group (tag g), and Rot2
# --------------------------------------------------------------------------- #


@helper_kernel
def g_compose(g, A, B, out, DA, jac):
    """out = A·B;  DA = Ad(B⁻¹) (DB = I)."""
    _dispatch.compose(g, A, B, out)
    if jac:
        m = A.shape[0]
        Bi = np.empty((m, m))
        _dispatch.inverse(g, B, Bi)
        _dispatch.Ad(g, Bi, DA)


@helper_kernel
def g_inverse(g, A, out, DA, jac):
    """out = A⁻¹;  DA = −Ad(A)."""
    _dispatch.inverse(g, A, out)
    if jac:
        _dispatch.Ad(g, A, DA)
        copy2(DA, DA, -1.0)


@helper_kernel
def g_between(g, A, B, out, DA, jac):
    """out = A⁻¹·B;  DA = −Ad(out⁻¹) (DB = I)."""
    m = A.shape[0]
    Ai = np.empty((m, m))
    _dispatch.inverse(g, A, Ai)
    _dispatch.compose(g, Ai, B, out)
    if jac:
        oi = np.empty((m, m))
        _dispatch.inverse(g, out, oi)
        _dispatch.Ad(g, oi, DA)
        copy2(DA, DA, -1.0)


@helper_kernel
def g_logmap(g, A, out, DA, jac):
    """out = Log(A);  DA = J_r⁻¹(out) = dlog(−out)."""
    _dispatch.log(g, A, out)
    if jac:
        neg = -out
        _dispatch.dlog(g, neg, DA)


@helper_kernel
def g_local(g, A, B, out, DA, DB, jac):
    """out = Log(A⁻¹·B) (GTSAM's localCoordinates);  DB = J_r⁻¹(out), DA = −DB·Ad((A⁻¹B)⁻¹)."""
    m = A.shape[0]
    n = out.shape[0]
    Ai = np.empty((m, m))
    E = np.empty((m, m))
    _dispatch.inverse(g, A, Ai)
    _dispatch.compose(g, Ai, B, E)
    _dispatch.log(g, E, out)
    if jac:
        neg = -out
        _dispatch.dlog(g, neg, DB)
        Ei = np.empty((m, m))
        Ad = np.empty((n, n))
        _dispatch.inverse(g, E, Ei)
        _dispatch.Ad(g, Ei, Ad)
        mm_set(DB, Ad, DA)
        copy2(DA, DA, -1.0)


@helper_kernel
def g_expmap(g, v, out, Dv, jac):
    """out = Exp(v);  Dv = J_r(v) = D_exp(−v)."""
    _dispatch.exp(g, v, out)
    if jac:
        neg = -v
        _dispatch.dexp(g, neg, Dv)


@helper_kernel
def g_retract(g, A, v, out, DA, Dv, jac):
    """out = A·Exp(v) (GTSAM's retract and expmap);  DA = Ad(Exp(v)⁻¹), Dv = J_r(v)."""
    m = A.shape[0]
    E = np.empty((m, m))
    _dispatch.exp(g, v, E)
    _dispatch.compose(g, A, E, out)
    if jac:
        Ei = np.empty((m, m))
        _dispatch.inverse(g, E, Ei)
        _dispatch.Ad(g, Ei, DA)
        neg = -v
        _dispatch.dexp(g, neg, Dv)


@helper_kernel
def rot2(c, s, out):
    out[0, 0] = c
    out[0, 1] = -s
    out[1, 0] = s
    out[1, 1] = c


# Rot2's Jacobians are constants (Ad = 1, J_r = 1): ±1, which the chain rule applies as
# identities (:mod:`lie_factors.expressions.codegen`); these compute values only.

@helper_kernel
def r2_compose(A, B, out):
    """Rot2: out = A·B (D = 1, 1)."""
    c = A[0, 0] * B[0, 0] - A[1, 0] * B[1, 0]
    s = A[1, 0] * B[0, 0] + A[0, 0] * B[1, 0]
    rot2(c, s, out)


@helper_kernel
def r2_inverse(A, out):
    """Rot2: out = A⁻¹ (D = −1)."""
    rot2(A[0, 0], -A[1, 0], out)


@helper_kernel
def r2_between(A, B, out):
    """Rot2: out = A⁻¹·B (D = −1, 1)."""
    c = A[0, 0] * B[0, 0] + A[1, 0] * B[1, 0]
    s = A[0, 0] * B[1, 0] - A[1, 0] * B[0, 0]
    rot2(c, s, out)


@helper_kernel
def r2_logmap(A, out):
    """Rot2: out = [θ] = atan2(s, c) (D = 1)."""
    out[0] = math.atan2(A[1, 0], A[0, 0])


@helper_kernel
def r2_local(A, B, out):
    """Rot2: out = Log(A⁻¹·B) (D = −1, 1)."""
    c = A[0, 0] * B[0, 0] + A[1, 0] * B[1, 0]
    s = A[0, 0] * B[1, 0] - A[1, 0] * B[0, 0]
    out[0] = math.atan2(s, c)


@helper_kernel
def r2_expmap(v, out):
    """Rot2: out = Exp(θ) (D = 1)."""
    rot2(math.cos(v[0]), math.sin(v[0]), out)


@helper_kernel
def r2_retract(A, v, out):
    """Rot2: out = A·Exp(θ) (D = 1, 1)."""
    c, s = math.cos(v[0]), math.sin(v[0])
    rot2(A[0, 0] * c - A[1, 0] * s, A[1, 0] * c + A[0, 0] * s, out)


# --------------------------------------------------------------------------- #
# Parts of an element: rotation, translation, scale
# --------------------------------------------------------------------------- #


@helper_kernel
def rotation_of(X, d, out, DX, jac):
    """out = the rotation block R = X[:d, :d];  DX = [0 … I_r … 0], the rotation's rows of the
    tangent (d = 3: ω at columns 0–2; d = 2: θ at column 2), exact: Exp(δ)'s rotation block is
    Exp of δ's rotation part."""
    for i in range(d):
        for j in range(d):
            out[i, j] = X[i, j]
    if jac:
        for i in range(DX.shape[0]):
            for j in range(DX.shape[1]):
                DX[i, j] = 0.0
        if d == 3:
            for i in range(3):
                DX[i, i] = 1.0
        else:
            DX[0, 2] = 1.0


@helper_kernel
def translation_of(X, d, first, similarity, out, DX, jac):
    """out = t = X[:d, d];  DX: the rotation times the tangent's translation part (at column
    ``first``), and for a similarity −t at the scale's column (the last): X·Exp(δ) moves t by
    R·u and, through the corner 1/s, by −λ·t."""
    for i in range(d):
        out[i] = X[i, d]
    if jac:
        for i in range(DX.shape[0]):
            for j in range(DX.shape[1]):
                DX[i, j] = 0.0
        for i in range(d):
            for j in range(d):
                DX[i, first + j] = X[i, j]
        if similarity:
            last = DX.shape[1] - 1
            for i in range(d):
                DX[i, last] = -X[i, d]


@helper_kernel
def scale_of(X, out, DX, jac):
    """out = [s] = [1/X[m−1, m−1]] of a similarity;  DX = [0 … s] (λ last: s' = s·e^λ)."""
    m = X.shape[0]
    s = 1.0 / X[m - 1, m - 1]
    out[0] = s
    if jac:
        for j in range(DX.shape[1]):
            DX[0, j] = 0.0
        DX[0, DX.shape[1] - 1] = s


# --------------------------------------------------------------------------- #
# Points: transformFrom, transformTo, rotate, unrotate (GTSAM's actions)
# --------------------------------------------------------------------------- #


@helper_kernel
def transform_from(X, d, kind, p, out, DX, Dp, jac):
    """out = s·(R p + t) (s = 1 but for a similarity); ``kind``: 0 a rotation (out = R p), 1 a
    pose, 2 a similarity.  DX (tangent columns: d = 3 [ω, v (, λ)], d = 2 [x, y, θ (, λ)]):
    the rotation's column(s) s·R·(−[p]×) (3-D) or s·R·J·p (2-D, J = [[0, −1], [1, 0]]), the
    translation's s·R, the scale's s·R·p;  Dp = s·R."""
    m = X.shape[0]
    s = 1.0 / X[m - 1, m - 1] if kind == 2 else 1.0
    Rp = np.empty(d)
    for i in range(d):
        acc = 0.0
        for j in range(d):
            acc += X[i, j] * p[j]
        Rp[i] = acc
    for i in range(d):
        out[i] = s * (Rp[i] + (X[i, d] if kind > 0 else 0.0))
    if not jac:
        return
    for i in range(d):
        for j in range(d):
            Dp[i, j] = s * X[i, j]
    for i in range(DX.shape[0]):
        for j in range(DX.shape[1]):
            DX[i, j] = 0.0
    if d == 3:
        # rotation part: −s R [p]×, columns 0..2
        for i in range(3):
            DX[i, 0] = -s * (X[i, 1] * p[2] - X[i, 2] * p[1])
            DX[i, 1] = -s * (X[i, 2] * p[0] - X[i, 0] * p[2])
            DX[i, 2] = -s * (X[i, 0] * p[1] - X[i, 1] * p[0])
        if kind > 0:
            for i in range(3):
                for j in range(3):
                    DX[i, 3 + j] = s * X[i, j]
        if kind == 2:
            for i in range(3):
                DX[i, 6] = s * Rp[i]
    else:
        col = 0 if kind == 0 else 2
        # s R J p, J p = (−p1, p0)
        for i in range(2):
            DX[i, col] = s * (X[i, 0] * -p[1] + X[i, 1] * p[0])
        if kind > 0:
            for i in range(2):
                for j in range(2):
                    DX[i, j] = s * X[i, j]
        if kind == 2:
            for i in range(2):
                DX[i, 3] = s * Rp[i]


@helper_kernel
def transform_to(X, d, kind, p, out, DX, Dp, jac):
    """out = q = Rᵀ(p/s − t) (the inverse of :func:`transform_from`; s = 1 but for a similarity,
    t = 0 for a rotation).  DX: the rotation's column(s) [q]× (3-D) or −J·q (2-D), the
    translation's −I, the scale's −q;  Dp = Rᵀ/s."""
    m = X.shape[0]
    s = 1.0 / X[m - 1, m - 1] if kind == 2 else 1.0
    w = np.empty(d)
    for i in range(d):
        w[i] = p[i] / s - (X[i, d] if kind > 0 else 0.0)
    for i in range(d):
        acc = 0.0
        for j in range(d):
            acc += X[j, i] * w[j]
        out[i] = acc
    if not jac:
        return
    for i in range(d):
        for j in range(d):
            Dp[i, j] = X[j, i] / s
    for i in range(DX.shape[0]):
        for j in range(DX.shape[1]):
            DX[i, j] = 0.0
    if d == 3:
        DX[0, 1] = -out[2]
        DX[0, 2] = out[1]
        DX[1, 0] = out[2]
        DX[1, 2] = -out[0]
        DX[2, 0] = -out[1]
        DX[2, 1] = out[0]
        if kind > 0:
            for i in range(3):
                DX[i, 3 + i] = -1.0
        if kind == 2:
            for i in range(3):
                DX[i, 6] = -out[i]
    else:
        col = 0 if kind == 0 else 2
        # −J q = (q1, −q0)
        DX[0, col] = out[1]
        DX[1, col] = -out[0]
        if kind > 0:
            DX[0, 0] = -1.0
            DX[1, 1] = -1.0
        if kind == 2:
            DX[0, 3] = -out[0]
            DX[1, 3] = -out[1]


# --------------------------------------------------------------------------- #
# Vectors
# --------------------------------------------------------------------------- #


#: GTSAM's norm2/norm3 give the Jacobian [1, …, 1] of a norm at or below this (its value 0).
NORM_ZERO = 1e-10


@helper_kernel
def v_norm(a, out, Da, jac):
    """out = [‖a‖];  Da = aᵀ/‖a‖, and [1, …, 1] where ‖a‖ ≤ :data:`NORM_ZERO` (GTSAM's norm2 and
    norm3: the norm has no derivative at 0, and GTSAM's choice is this one)."""
    n = 0.0
    for i in range(a.shape[0]):
        n += a[i] * a[i]
    n = math.sqrt(n)
    out[0] = n
    if jac:
        for i in range(a.shape[0]):
            Da[0, i] = a[i] / n if n > NORM_ZERO else 1.0


@helper_kernel
def v_dot(a, b, out, Da, Db, jac):
    """out = [a·b];  Da = bᵀ, Db = aᵀ."""
    acc = 0.0
    for i in range(a.shape[0]):
        acc += a[i] * b[i]
    out[0] = acc
    if jac:
        for i in range(a.shape[0]):
            Da[0, i] = b[i]
            Db[0, i] = a[i]


#: GTSAM's Rot2::relativeBearing gives the identity, with Jacobian 0, for a point at or within
#: this of the origin.
BEARING_ZERO = 1e-5


@helper_kernel
def bearing2(p, out, Dp, jac):
    """out = the Rot2 of direction p = (x, y) (GTSAM's Rot2::relativeBearing: c = x/r, s = y/r);
    Dp = [−y, x]/r²; the identity and 0 where r ≤ :data:`BEARING_ZERO` (GTSAM's)."""
    x, y = p[0], p[1]
    r2 = x * x + y * y
    r = math.sqrt(r2)
    near = r <= BEARING_ZERO
    if near:
        rot2(1.0, 0.0, out)
    else:
        rot2(x / r, y / r, out)
    if jac:
        Dp[0, 0] = 0.0 if near else -y / r2
        Dp[0, 1] = 0.0 if near else x / r2


@helper_kernel
def unit3_of(w, out, Dw, jac):
    """out = w/‖w‖, the Unit3 of a Point3 (GTSAM's ``Unit3(point)``, ``Pose3.bearing``);
    Dw = (I − out·outᵀ)/‖w‖."""
    n = math.sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2])
    for i in range(3):
        out[i] = w[i] / n
    if jac:
        for i in range(3):
            for j in range(3):
                Dw[i, j] = ((1.0 if i == j else 0.0) - out[i] * out[j]) / n


#: θ/sin θ and (sin θ − θ cos θ)/sin³ θ below this θ: their series (relative error < 1e-16 there)
UNIT3_SERIES = 1e-3


@helper_kernel
def unit3_basis(p, B):
    """B (3, 2): GTSAM's basis of the tangent plane of the Unit3 p: b1 = p × a/‖p × a‖, with a the
    coordinate axis of p's smallest |component| (x, then y, then z on ties), and b2 = p × b1.
    Returns a (3,)."""
    mx, my, mz = abs(p[0]), abs(p[1]), abs(p[2])
    a0, a1, a2 = 0.0, 0.0, 1.0
    if mx <= my and mx <= mz:
        a0, a2 = 1.0, 0.0
    elif my <= mx and my <= mz:
        a1, a2 = 1.0, 0.0
    c0 = p[1] * a2 - p[2] * a1
    c1 = p[2] * a0 - p[0] * a2
    c2 = p[0] * a1 - p[1] * a0
    n = math.sqrt(c0 * c0 + c1 * c1 + c2 * c2)
    B[0, 0], B[1, 0], B[2, 0] = c0 / n, c1 / n, c2 / n
    B[0, 1] = p[1] * B[2, 0] - p[2] * B[1, 0]
    B[1, 1] = p[2] * B[0, 0] - p[0] * B[2, 0]
    B[2, 1] = p[0] * B[1, 0] - p[1] * B[0, 0]
    a = np.empty(3)
    a[0], a[1], a[2] = a0, a1, a2
    return a


@helper_kernel
def unit3_local(p, q, out, Dp, Dq, jac):
    """out = g(θ)·B(p)ᵀq, GTSAM's ``Unit3::localCoordinates`` of q in p's basis B (Bᵀp = 0, θ the
    angle between them, g = θ/sin θ);  Dq = g·Bᵀ − h·(Bᵀq)·pᵀ and Dp = g·[qᵀ·∂b1/∂p; qᵀ·∂b2/∂p]
    − h·(Bᵀq)·qᵀ, h = (sin θ − θ cos θ)/sin³ θ (dθ = −(qᵀdp + pᵀdq)/sin θ), with the basis's
    derivative: b1 = w/‖w‖, w = p × a, ∂b1/∂p = (I − b1b1ᵀ)/‖w‖·(−[a]×); b2 = p × b1,
    ∂b2/∂p = −[b1]× + [p]×·∂b1/∂p."""
    B = np.empty((3, 2))
    a = unit3_basis(p, B)
    c = p[0] * q[0] + p[1] * q[1] + p[2] * q[2]
    x0 = p[1] * q[2] - p[2] * q[1]
    x1 = p[2] * q[0] - p[0] * q[2]
    x2 = p[0] * q[1] - p[1] * q[0]
    s = math.sqrt(x0 * x0 + x1 * x1 + x2 * x2)
    th = math.atan2(s, c)
    if th < UNIT3_SERIES:
        t2 = th * th
        g = 1.0 + t2 / 6.0 + 7.0 * t2 * t2 / 360.0
        h = 1.0 / 3.0 + 2.0 * t2 / 15.0
    else:
        g = th / s
        h = (s - th * c) / (s * s * s)
    u0 = B[0, 0] * q[0] + B[1, 0] * q[1] + B[2, 0] * q[2]
    u1 = B[0, 1] * q[0] + B[1, 1] * q[1] + B[2, 1] * q[2]
    out[0] = g * u0
    out[1] = g * u1
    if not jac:
        return
    for j in range(3):
        Dq[0, j] = g * B[j, 0] - h * u0 * p[j]
        Dq[1, j] = g * B[j, 1] - h * u1 * p[j]
    # ∂b1/∂p = P1·(−[a]×), P1 = (I − b1b1ᵀ)/‖w‖
    w = np.empty(3)
    w[0] = p[1] * a[2] - p[2] * a[1]
    w[1] = p[2] * a[0] - p[0] * a[2]
    w[2] = p[0] * a[1] - p[1] * a[0]
    nw = math.sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2])
    Ma = np.empty((3, 3))
    skew_into(a, Ma, -1.0)
    db1 = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            acc = 0.0
            for k in range(3):
                acc += ((1.0 if i == k else 0.0) - B[i, 0] * B[k, 0]) * Ma[k, j]
            db1[i, j] = acc / nw
    # ∂b2/∂p = −[b1]× + [p]×·∂b1/∂p
    b1 = np.empty(3)
    for i in range(3):
        b1[i] = B[i, 0]
    Mb = np.empty((3, 3))
    skew_into(b1, Mb, -1.0)
    Mp = np.empty((3, 3))
    skew_into(p, Mp, 1.0)
    db2 = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            acc = Mb[i, j]
            for k in range(3):
                acc += Mp[i, k] * db1[k, j]
            db2[i, j] = acc
    for j in range(3):
        r0 = 0.0
        r1 = 0.0
        for i in range(3):
            r0 += q[i] * db1[i, j]
            r1 += q[i] * db2[i, j]
        Dp[0, j] = g * r0 - h * u0 * q[j]
        Dp[1, j] = g * r1 - h * u1 * q[j]


@helper_kernel
def v_cross(a, b, out, Da, Db, jac):
    """out = a × b;  Da = −[b]×, Db = [a]× (GTSAM's ``cross``)."""
    out[0] = a[1] * b[2] - a[2] * b[1]
    out[1] = a[2] * b[0] - a[0] * b[2]
    out[2] = a[0] * b[1] - a[1] * b[0]
    if jac:
        skew_into(b, Da, -1.0)
        skew_into(a, Db, 1.0)


@helper_kernel
def v_smul(s, a, out, Ds, jac):
    """out = s·a (s one entry, a any length);  Ds = a (a column); Da = s·I (the chain rule
    scales)."""
    for i in range(out.shape[0]):
        out[i] = s[0] * a[i]
    if jac:
        for i in range(out.shape[0]):
            Ds[i, 0] = a[i]


@helper_kernel
def v_div(a, s, out, Ds, jac):
    """out = a/s (s one entry);  Ds = −a/s² = −out/s (a column); Da = I/s (the chain rule
    scales).  False at s = 0."""
    d = s[0]
    for i in range(out.shape[0]):
        out[i] = a[i] / d
    if jac:
        for i in range(out.shape[0]):
            Ds[i, 0] = -out[i] / d
    return d != 0.0


#: GTSAM's Rot3::RQ refuses the derivative of rpy within this of pitch = +π/2 (gimbal lock).
GIMBAL_BAND = 1e-2


@helper_kernel
def rot3_rpy(R, out, DR, jac):
    """out = [x, y, z] = [roll, pitch, yaw], R = Rz(z)·Ry(y)·Rx(x): GTSAM's Rot3::RQ step for
    step (x = −atan2(−R21, R22), B = R·Rx(−x), y = −atan2(B20, B22), C = B·Ry(−y),
    z = −atan2(−C10, C11)).  DR (right perturbation R·Exp(ω)) = E⁻¹, the inverse of the map
    from Euler rates to ω: [[1, sin x tan y, cos x tan y], [0, cos x, −sin x],
    [0, sin x/cos y, cos x/cos y]].  False, with the Jacobian asked, within :data:`GIMBAL_BAND`
    of y = π/2 (GTSAM's refusal; toward y = −π/2 both grow as 1/cos y)."""
    x = -math.atan2(-R[2, 1], R[2, 2])
    cx, sx = math.cos(-x), math.sin(-x)  # Rx(−x) = [[1, 0, 0], [0, cx, −sx], [0, sx, cx]]
    b20 = R[2, 0]
    b22 = R[2, 1] * -sx + R[2, 2] * cx
    y = -math.atan2(b20, b22)
    cy, sy = math.cos(-y), math.sin(-y)  # Ry(−y) = [[cy, 0, sy], [0, 1, 0], [−sy, 0, cy]]
    b10 = R[1, 0]
    b11 = R[1, 1] * cx + R[1, 2] * sx
    b12 = R[1, 1] * -sx + R[1, 2] * cx
    c10 = b10 * cy + b12 * -sy
    c11 = b11
    z = -math.atan2(-c10, c11)
    out[0] = x
    out[1] = y
    out[2] = z
    if not jac:
        return True
    cr, sr = math.cos(x), math.sin(x)
    cp, tp = math.cos(y), math.tan(y)
    DR[0, 0], DR[0, 1], DR[0, 2] = 1.0, sr * tp, cr * tp
    DR[1, 0], DR[1, 1], DR[1, 2] = 0.0, cr, -sr
    DR[2, 0], DR[2, 1], DR[2, 2] = 0.0, sr / cp, cr / cp
    return abs(y - math.pi / 2.0) >= GIMBAL_BAND


# --------------------------------------------------------------------------- #
# Matrices (held row by row): an element's matrix and adjoint, products
# --------------------------------------------------------------------------- #


@helper_kernel
def product_column(A, B, D, c):
    """D[:, c] = A·B row by row (A, B square): one column of a matrix's Jacobian."""
    m = A.shape[0]
    for i in range(m):
        for j in range(m):
            acc = 0.0
            for k in range(m):
                acc += A[i, k] * B[k, j]
            D[i * m + j, c] = acc


@helper_kernel
def unit_vector(e, c):
    """e = the c-th unit vector."""
    for q in range(e.shape[0]):
        e[q] = 0.0
    e[c] = 1.0


@helper_kernel
def g_matrix(g, X, out, DX, jac):
    """out = X, row by row (m²);  DX column c = X·hat(e_c), row by row: X·Exp(δ) = X + X·hat(δ)
    + O(δ²)."""
    m = X.shape[0]
    n = DX.shape[1]
    for i in range(m):
        for j in range(m):
            out[i * m + j] = X[i, j]
    if jac:
        e = np.empty(n)
        H = np.empty((m, m))
        for c in range(n):
            unit_vector(e, c)
            _dispatch.hat(g, e, H)
            product_column(X, H, DX, c)


@helper_kernel
def r2_matrix(X, out, DX, jac):
    """Rot2: out = X, row by row;  DX = X·[[0, −1], [1, 0]], row by row (tangent [θ])."""
    for i in range(2):
        for j in range(2):
            out[i * 2 + j] = X[i, j]
    if jac:
        for i in range(2):
            DX[i * 2, 0] = X[i, 1]
            DX[i * 2 + 1, 0] = -X[i, 0]


@helper_kernel
def g_adjoint_map(g, X, out, DX, jac):
    """out = Ad(X), row by row (n²);  DX column c = Ad(X)·ad(e_c), row by row: Ad(X·Exp(δ)) =
    Ad(X)·Ad(Exp(δ)) = Ad(X)·e^{ad δ} (Eade, Eq. 9) = Ad(X) + Ad(X)·ad(δ) + O(δ²)."""
    n = DX.shape[1]
    A = np.empty((n, n))
    _dispatch.Ad(g, X, A)
    for i in range(n):
        for j in range(n):
            out[i * n + j] = A[i, j]
    if jac:
        e = np.empty(n)
        a = np.empty((n, n))
        for c in range(n):
            unit_vector(e, c)
            _dispatch.ad(g, e, a)
            product_column(A, a, DX, c)


@helper_kernel
def mat_product(A, B, r, k, c, out):
    """out (r·c) = A (r·k) · B (k·c), all row by row."""
    for i in range(r):
        for j in range(c):
            acc = 0.0
            for q in range(k):
                acc += A[i * k + q] * B[q * c + j]
            out[i * c + j] = acc


@helper_kernel
def mat_chain_left(JA, B, r, k, c, out, first):
    """out (r·c, d) (=, or += if not ``first``) dA·B column by column: the term of A's Jacobian
    JA (r·k, d) in the Jacobian of A·B."""
    for col in range(out.shape[1]):
        for i in range(r):
            for j in range(c):
                acc = 0.0
                for q in range(k):
                    acc += JA[i * k + q, col] * B[q * c + j]
                if first:
                    out[i * c + j, col] = acc
                else:
                    out[i * c + j, col] += acc


@helper_kernel
def mat_chain_right(A, JB, r, k, c, out, first):
    """out (r·c, d) (=, or +=) A·dB column by column: the term of B's Jacobian JB (k·c, d)."""
    for col in range(out.shape[1]):
        for i in range(r):
            for j in range(c):
                acc = 0.0
                for q in range(k):
                    acc += A[i * k + q] * JB[q * c + j, col]
                if first:
                    out[i * c + j, col] = acc
                else:
                    out[i * c + j, col] += acc
