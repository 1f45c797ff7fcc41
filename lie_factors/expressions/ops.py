"""The vocabulary: each operation's types (checked when a residual is written) and its code (the
call of its compiled form, :mod:`lie_factors.expressions.kernels`, and how its local Jacobians
enter the chain rule).

Functions for a residual, beside the methods of :class:`~lie_factors.expressions.expr.Expr`::

    from lie_factors.expressions import ops
    ops.expmap("Pose3", v)          # Exp(v), a group element of the type named
    ops.project(pose, point, K)     # a pinhole: K's pixels of the point seen by the camera at pose
                                    # (a Cal3_S2Stereo K: GTSAM's StereoCamera, [uL, uR, v])
    ops.catch_cheirality(r, c)      # r, or the constant c (zero Jacobians) where a projection in r
                                    # finds its point behind the camera: GTSAM's projection factors
    ops.stack(a, b, ...)            # the vectors one after the other
    ops.norm(v), ops.dot(a, b), ops.cross(a, b), ops.compose(a, b), ... (the methods, as functions)
"""

from __future__ import annotations

from .expr import Expr, _record, constant_only, fail
from .expr import project as _project

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


def cross(a: Expr, b: Expr) -> Expr:
    return a.cross(b)


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
    PinholeCamera) sees ``point``: ``calibration`` (constant or variable: a Cal3_S2, Cal3Bundler,
    Cal3DS2 or Cal3Fisheye) applied to the camera-frame point divided by its depth; with a
    Cal3_S2Stereo, GTSAM's StereoCamera's [uL, uR, v].  A point not in front of the camera
    (depth ≤ 0) raises :class:`~lie_factors.errors.CheiralityException` when the factor is
    evaluated there, as GTSAM's ``project`` does (:func:`catch_cheirality` gives GTSAM's
    projection factors' constant instead)."""
    return _project(pose, point, calibration)


def catch_cheirality(residual: Expr, fallback) -> Expr:
    """``residual``, or, where a projection in it finds its point not in front of the camera,
    ``fallback`` (an expression of constants, or a constant array) with zero Jacobians: what
    GTSAM's GenericProjectionFactor, GenericStereoFactor and GeneralSFMFactor return when they
    catch a ``CheiralityException``."""
    if isinstance(fallback, Expr) and not constant_only(fallback.node):
        raise fail("catch_cheirality's fallback must depend on constants only (its Jacobians are zero)")
    return _record("catch_cheirality", residual, fallback)
