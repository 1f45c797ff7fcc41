"""Unit dual quaternions for SE(3): dq = [q_r (4), q_d (4)], q_d = ½ (0, t) ⊗ q_r.

Tangent xi = [ω, v] exactly as :mod:`lie_factors.se3` (rotation first), and
``to_matrix(exp(xi)) == se3.exp(xi)``: the dual exponential exp(ω + ε v) of
Jackson, "Part 6: Computing the Matrix Exponential" (eq:dual_quat_exp_1 and the
boxed DS³ exp and log, half-angle convention) is the transform [[R, V v], [0, 1]]
of se3.exp with this very ordering — verified against the mpmath definition in the
tests.

Shapes: ``exp`` (..., 6) → (..., 8); ``log`` (..., 8) → (..., 6) with |ω| ≤ π;
``to_matrix`` (..., 8) → (..., 4, 4); ``compose`` (the product p q, transform p
after q) and ``inverse`` (the conjugate [q_r*, q_d*]) on (..., 8). dq and −dq are
the same transform; ``log`` takes the one with q_r0 ≥ 0. Every function taking dual
quaternions rejects those with |‖q_r‖ − 1| or |q_r · q_d| / max(1, ‖q_d‖) above
``UNIT_TOL`` (1e-9). :mod:`lie_factors.kernels.public` builds exp, log, compose and
inverse (validation, broadcasting, the single-element fast path).
"""

from __future__ import annotations

import math

from lie_factors import quaternion as _quat
from lie_factors.kernels import (dispatch as _dispatch, public as _public, registry as _registry, validate as _validate)
from lie_factors.kernels.coeffs import a_theta, b_theta, c_theta, dot3, norm3
from lie_factors.kernels.jit import kernel

_info = _registry.DUAL_QUATERNION

#: Largest accepted |‖q_r‖ − 1| and |q_r · q_d| / max(1, ‖q_d‖) (the unit rule of
#: :mod:`lie_factors.kernels.validate`).
UNIT_TOL = _validate.UNIT_TOL


@kernel
def _exp(x, out):
    # Jackson, boxed dual-quaternion exponential, h = θ/2, γ = ωᵀv:
    #   q_r = [cos h, sin h/θ · ω]
    #   q_d = [−γ sin h/(2θ), γ (½ cos h − sin h/θ)/θ² · ω + sin h/θ · v]
    # sin h/θ = ½ a(h); the cancelling (½ cos h − sin h/θ)/θ² = (c(h) − b(h))/8
    # (cos h − a(h) = h² (c(h) − b(h))), stable at every θ.
    w0, w1, w2 = x[0], x[1], x[2]
    h = 0.5 * norm3(w0, w1, w2)
    s = 0.5 * a_theta(h)
    g = dot3(w0, w1, w2, x[3], x[4], x[5])
    gf = g * 0.125 * (c_theta(h) - b_theta(h))
    out[0] = math.cos(h)
    out[1] = s * w0
    out[2] = s * w1
    out[3] = s * w2
    out[4] = -0.5 * g * s
    out[5] = gf * w0 + s * x[3]
    out[6] = gf * w1 + s * x[4]
    out[7] = gf * w2 + s * x[5]


@kernel
def _log(q, out):
    # Jackson, boxed dual-quaternion logarithm, with φ = atan2(|r|, r0) the half angle:
    #   ω = 2 A r,  v = 2 (A d + (γ G − d0) r),  A = φ/|r|,  G = (r0 − A)/|r|²,  γ = rᵀd.
    # Jackson's small-angle form of G is wrong (it substitutes r0 = cos(|r|/2); in fact
    # |r| = sin φ, r0 = cos φ). Stable: G = (sin φ cos φ − φ)/sin³φ = −4 c(2φ)/a(φ)³.
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    if q[0] < 0.0:
        n = -n
    r0, r1, r2, r3 = q[0] / n, q[1] / n, q[2] / n, q[3] / n
    d0, d1, d2, d3 = q[4] / n, q[5] / n, q[6] / n, q[7] / n
    s = norm3(r1, r2, r3)
    phi = math.atan2(s, r0)
    A = phi / s if s > 0.0 else 1.0
    ap = a_theta(phi)
    G = -4.0 * c_theta(2.0 * phi) / (ap * ap * ap)
    k = dot3(r1, r2, r3, d1, d2, d3) * G - d0
    out[0] = 2.0 * A * r1
    out[1] = 2.0 * A * r2
    out[2] = 2.0 * A * r3
    out[3] = 2.0 * (A * d1 + k * r1)
    out[4] = 2.0 * (A * d2 + k * r2)
    out[5] = 2.0 * (A * d3 + k * r3)


@kernel
def _to_matrix(q, out):
    # t = 2 vec(q_d ⊗ q_r*) = 2 (r0 d − d0 r + r × d)
    _quat._to_rotation(q[:4], out)
    r0, r1, r2, r3 = q[0], q[1], q[2], q[3]
    d0, d1, d2, d3 = q[4], q[5], q[6], q[7]
    out[0, 3] = 2.0 * (r0 * d1 - d0 * r1 + r2 * d3 - r3 * d2)
    out[1, 3] = 2.0 * (r0 * d2 - d0 * r2 + r3 * d1 - r1 * d3)
    out[2, 3] = 2.0 * (r0 * d3 - d0 * r3 + r1 * d2 - r2 * d1)
    out[3, 0] = 0.0
    out[3, 1] = 0.0
    out[3, 2] = 0.0
    out[3, 3] = 1.0


@kernel
def _compose(p, q, out):
    # (p_r + ε p_d)(q_r + ε q_d) = p_r q_r + ε (p_r q_d + p_d q_r)
    _quat._compose(p[:4], q[:4], out[:4])
    _quat._compose(p[:4], q[4:], out[4:])
    w = p[4] * q[0] - p[5] * q[1] - p[6] * q[2] - p[7] * q[3]
    x = p[4] * q[1] + p[5] * q[0] + p[6] * q[3] - p[7] * q[2]
    y = p[4] * q[2] - p[5] * q[3] + p[6] * q[0] + p[7] * q[1]
    z = p[4] * q[3] + p[5] * q[2] - p[6] * q[1] + p[7] * q[0]
    out[4] += w
    out[5] += x
    out[6] += y
    out[7] += z


@kernel
def _inverse(q, out):
    out[0] = q[0]
    out[4] = q[4]
    for i in (1, 2, 3, 5, 6, 7):
        out[i] = -q[i]


# ---------------------------------------------------------------- public functions

exp, log, compose, inverse = _public.functions(_info, globals())


#: The conversion's operation tag (its core: _to_matrix), for the batch loop.
_TO_MATRIX = _dispatch.Op("to_matrix", True)


def to_matrix(dq):
    """(..., 8) → (..., 4, 4): [[R(q_r), t], [0, 1]] with t = 2 vec(q_d ⊗ q_r*) (validated as :func:`log`)."""
    return _public.apply(_info, _TO_MATRIX, _validate.unit(dq, _info, "dq"), 1, (4, 4))
