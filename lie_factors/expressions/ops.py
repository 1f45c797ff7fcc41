"""The vocabulary: each operation's types (checked when a residual is written) and its code (the
call of its compiled form, :mod:`lie_factors.expressions.kernels`, and how its local Jacobians
enter the chain rule).

Functions for a residual, beside the methods of :class:`~lie_factors.expressions.expr.Expr`::

    from lie_factors.expressions import ops
    ops.expmap("Pose3", v)          # Exp(v), a group element of the type named
    ops.project(pose, point, K)     # a pinhole: K's pixels of the point seen by the camera at pose
    ops.stack(a, b, ...)            # the vectors one after the other
    ops.norm(v), ops.dot(a, b), ops.compose(a, b), ... (the methods, as functions)
"""

from __future__ import annotations

from .expr import Expr, _record

# --------------------------------------------------------------------------- #
# The residual's functions (macros expand into the primitive operations)
# --------------------------------------------------------------------------- #


def compose(a: Expr, b: Expr) -> Expr:
    return a.compose(b)


def inverse(a: Expr) -> Expr:
    return a.inverse()


def between(a: Expr, b: Expr) -> Expr:
    return a.between(b)


def localCoordinates(a: Expr, b: Expr) -> Expr:
    return a.localCoordinates(b)


def logmap(a: Expr) -> Expr:
    return a.logmap()


def retract(a: Expr, v: Expr) -> Expr:
    return a.retract(v)


def expmap(group, v: Expr) -> Expr:
    """Exp(v) of the group named ``group`` (``"Pose3"``…): GTSAM's ``Pose3.Expmap(v)``."""
    return _record("expmap", v, group=group)


def rotation(a: Expr) -> Expr:
    return a.rotation()


def translation(a: Expr) -> Expr:
    return a.translation()


def scale(a: Expr) -> Expr:
    return a.scale()


def transformFrom(a: Expr, p: Expr) -> Expr:
    return a.transformFrom(p)


def transformTo(a: Expr, p: Expr) -> Expr:
    return a.transformTo(p)


def rotate(r: Expr, p: Expr) -> Expr:
    return r.rotate(p)


def unrotate(r: Expr, p: Expr) -> Expr:
    return r.unrotate(p)


def dot(a: Expr, b: Expr) -> Expr:
    return a.dot(b)


def norm(a: Expr) -> Expr:
    return a.norm()


def range(a: Expr, b: Expr) -> Expr:  # noqa: A001 - GTSAM's name
    return a.range(b)


def bearing(a: Expr, b: Expr | None = None) -> Expr:
    return a.bearing(b)


def stack(*parts: Expr) -> Expr:
    """The vectors ``parts`` one after the other (a residual of several parts)."""
    return _record("stack", *parts)


def project(pose: Expr, point: Expr, calibration: Expr) -> Expr:
    """The pixel at which a camera at ``pose`` (camera to world, z forward: GTSAM's
    PinholeCamera) sees ``point``: ``calibration`` (a Cal3_S2 [fx, fy, s, u0, v0] or a
    Cal3Bundler [f, k1, k2], constant or variable) applied to the camera-frame point divided by
    its depth."""
    return _record("uncalibrate", calibration, _record("pinhole", pose.transformTo(point)))
