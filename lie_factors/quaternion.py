"""Unit quaternions q = [w, x, y, z] (Hamilton product) for SO(3), tangent ω = [ω1, ω2, ω3].

Half-angle convention (Jackson, "Part 6: Computing the Matrix Exponential", eq:quat_exp
and the boxed S³ exp and log)::

    exp(ω)        = [cos(θ/2), sin(θ/2) ω/θ],  θ = |ω|     (..., 3) → (..., 4)
    log(q)        = 2 atan2(|q⃗|, w) q⃗/|q⃗|  with w ≥ 0     (..., 4) → (..., 3), |ω| ≤ π
    compose(p, q) = p ⊗ q (rotation p after q)               (..., 4) × (..., 4) → (..., 4)
    inverse(q)    = [w, −x, −y, −z]                          (..., 4) → (..., 4)
    to_rotation(q) (..., 4) → (..., 3, 3),  from_rotation(R) (..., 3, 3) → (..., 4)

so that ``to_rotation(exp(ω)) == so3.exp(ω)``. q and −q are the same rotation;
``log`` returns the shorter of the two logarithms (it flips q to w ≥ 0 first).
Every function taking quaternions rejects those with |‖q‖ − 1| > ``UNIT_TOL`` (1e-9);
``log`` normalises the rest. :mod:`lie_factors.kernels.public` builds exp, log,
compose and inverse (validation, broadcasting, the single-element fast path).
"""

from __future__ import annotations

import math

from lie_factors.kernels import (dispatch as _dispatch, public as _public, registry as _registry, validate as _validate)
from lie_factors.kernels.coeffs import a_theta, norm3
from lie_factors.kernels.jit import kernel

_info = _registry.QUATERNION

#: Largest accepted |‖q‖ − 1| (the unit rule of :mod:`lie_factors.kernels.validate`).
UNIT_TOL = _validate.UNIT_TOL


@kernel
def _exp(x, out):
    # Jackson: exp(ω) = cos(θ/2) + sin(θ/2) ω/θ, with sin(θ/2)/θ = ½ a(θ/2)
    # (no 0/0 at θ = 0, no θ² underflow at θ = 1e-200).
    th = norm3(x[0], x[1], x[2])
    h = 0.5 * th
    s = 0.5 * a_theta(h)
    out[0] = math.cos(h)
    out[1] = s * x[0]
    out[2] = s * x[1]
    out[3] = s * x[2]


@kernel
def _log(q, out):
    # Jackson: log q = 2 atan2(|q⃗|, q0) q⃗/|q⃗| after q → −q if q0 < 0 (shortest
    # rotation, |ω| ≤ π). atan2(r, w)/r has no cancellation for any r > 0.
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    w = q[0] / n
    if w < 0.0:
        n = -n
        w = -w
    x = q[1] / n
    y = q[2] / n
    z = q[3] / n
    r = norm3(x, y, z)
    k = 2.0 * math.atan2(r, w) / r if r > 0.0 else 2.0
    out[0] = k * x
    out[1] = k * y
    out[2] = k * z


@kernel
def _compose(p, q, out):
    w1, x1, y1, z1 = p[0], p[1], p[2], p[3]
    w2, x2, y2, z2 = q[0], q[1], q[2], q[3]
    out[0] = w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2
    out[1] = w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2
    out[2] = w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2
    out[3] = w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2


@kernel
def _inverse(q, out):
    out[0] = q[0]
    out[1] = -q[1]
    out[2] = -q[2]
    out[3] = -q[3]


@kernel
def _to_rotation(q, out):
    w, x, y, z = q[0], q[1], q[2], q[3]
    out[0, 0] = 1.0 - 2.0 * (y * y + z * z)
    out[0, 1] = 2.0 * (x * y - w * z)
    out[0, 2] = 2.0 * (x * z + w * y)
    out[1, 0] = 2.0 * (x * y + w * z)
    out[1, 1] = 1.0 - 2.0 * (x * x + z * z)
    out[1, 2] = 2.0 * (y * z - w * x)
    out[2, 0] = 2.0 * (x * z - w * y)
    out[2, 1] = 2.0 * (y * z + w * x)
    out[2, 2] = 1.0 - 2.0 * (x * x + y * y)


@kernel
def _from_rotation(R, out):
    # Shepperd: divide by the largest of 4w², 4x², 4y², 4z² (never small).
    tr = R[0, 0] + R[1, 1] + R[2, 2]
    if tr >= R[0, 0] and tr >= R[1, 1] and tr >= R[2, 2]:
        s = 2.0 * math.sqrt(1.0 + tr)
        out[0] = 0.25 * s
        out[1] = (R[2, 1] - R[1, 2]) / s
        out[2] = (R[0, 2] - R[2, 0]) / s
        out[3] = (R[1, 0] - R[0, 1]) / s
    elif R[0, 0] >= R[1, 1] and R[0, 0] >= R[2, 2]:
        s = 2.0 * math.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2])
        out[0] = (R[2, 1] - R[1, 2]) / s
        out[1] = 0.25 * s
        out[2] = (R[0, 1] + R[1, 0]) / s
        out[3] = (R[0, 2] + R[2, 0]) / s
    elif R[1, 1] >= R[2, 2]:
        s = 2.0 * math.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2])
        out[0] = (R[0, 2] - R[2, 0]) / s
        out[1] = (R[0, 1] + R[1, 0]) / s
        out[2] = 0.25 * s
        out[3] = (R[1, 2] + R[2, 1]) / s
    else:
        s = 2.0 * math.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1])
        out[0] = (R[1, 0] - R[0, 1]) / s
        out[1] = (R[0, 2] + R[2, 0]) / s
        out[2] = (R[1, 2] + R[2, 1]) / s
        out[3] = 0.25 * s
    if out[0] < 0.0:
        for i in range(4):
            out[i] = -out[i]


# ---------------------------------------------------------------- public functions

exp, log, compose, inverse = _public.functions(_info, globals())


#: The conversions' operation tags (their cores: _to_rotation, _from_rotation), for the batch loop.
_TO_ROTATION, _FROM_ROTATION = _dispatch.Op("to_rotation", True), _dispatch.Op("from_rotation", False)


def to_rotation(q):
    """(..., 4) → (..., 3, 3): the rotation matrix of a unit quaternion (validated as :func:`log`)."""
    return _public.apply(_info, _TO_ROTATION, _validate.unit(q, _info, "q"), 1, (3, 3))


def from_rotation(R):
    """(..., 3, 3) → (..., 4): the unit quaternion with w ≥ 0 (Shepperd's method) of rotations R."""
    return _public.apply(_info, _FROM_ROTATION, _public.elements(R, _registry.SO3, "R"), 2, (4,))
