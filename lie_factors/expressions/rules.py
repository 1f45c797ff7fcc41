"""The types of the vocabulary's operations: :func:`output_type` checks an operation's input
types when a residual is written and gives its output type (InputError naming the operation and
the types when they do not fit)."""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from .types import GROUPS, POINT2, POINT3, UNIT3, ValueType, value_type, vector


def _number(x) -> float:
    try:
        value = float(x)
    except (TypeError, ValueError):
        raise InputError(f"expected a constant number, got {type(x).__name__}") from None
    if not np.isfinite(value):
        raise InputError(f"a constant must be finite, got {value}")
    return value


_POSES = ("Pose2", "Pose3", "Similarity2", "Similarity3")
_ROTATIONS = ("Rot2", "Rot3")
_PART = {"Pose2": ("Rot2", POINT2), "Similarity2": ("Rot2", POINT2),
         "Pose3": ("Rot3", POINT3), "Similarity3": ("Rot3", POINT3)}


def _group(t: ValueType, op: str) -> None:
    if not t.is_group:
        raise InputError(f"{op} takes a group element (Rot2, Rot3, Pose2, Pose3, Similarity2, "
                         f"Similarity3), got a {t}")


def _vector(t: ValueType, op: str, dim: int | None = None) -> None:
    if t.is_group:
        raise InputError(f"{op} takes a vector, got a {t} (a group element: compose, between, "
                         "localCoordinates …)")
    if t.kind == "unit":
        raise InputError(f"{op} takes a vector, got a Unit3 (a direction: compare two with "
                         "measured.localCoordinates(predicted))")
    if dim is not None and t.dim != dim:
        raise InputError(f"{op} takes a vector of dimension {dim}, got a {t}")


def _same(a: ValueType, b: ValueType, op: str) -> None:
    if a.name != b.name:
        raise InputError(f"{op} of a {a} and a {b}: both must be of one group type")


def output_type(op: str, ins: tuple, attrs: dict) -> tuple[ValueType, dict]:
    """(the output type, the attributes kept) of ``op`` on inputs of types ``ins``; InputError
    naming the operation and the types when they do not fit."""
    rule = _TYPES.get(op)
    if rule is None:
        raise InputError(f"{op} is not an operation of the vocabulary")
    return rule(ins, dict(attrs))


def _t_binary_group(op):
    def rule(ins, attrs):
        a, b = ins
        if op == "localCoordinates" and a.kind == "unit" and b.kind == "unit":
            return vector(2), attrs  # GTSAM's Unit3::localCoordinates, in a's basis
        _group(a, op)
        _same(a, b, op)
        return (vector(a.dim) if op == "localCoordinates" else a), attrs
    return rule


def _t_inverse(ins, attrs):
    _group(ins[0], "inverse")
    return ins[0], attrs


def _t_logmap(ins, attrs):
    _group(ins[0], "logmap")
    return vector(ins[0].dim), attrs


def _t_retract(ins, attrs):
    a, v = ins
    _group(a, "retract")
    _vector(v, "retract's tangent vector", a.dim)
    return a, attrs


def _t_expmap(ins, attrs):
    group = value_type(attrs["group"])
    if not group.is_group:
        raise InputError(f"expmap makes a group element; {group} is not a group")
    _vector(ins[0], "expmap", group.dim)
    attrs["group"] = group.name
    return group, attrs


def _t_rotation(ins, attrs):
    a = ins[0]
    if a.name not in _PART:
        raise InputError(f"rotation of a {a}: takes a Pose2, Pose3, Similarity2 or Similarity3")
    return GROUPS[_PART[a.name][0]], attrs


def _t_translation(ins, attrs):
    a = ins[0]
    if a.name not in _PART:
        raise InputError(f"translation of a {a}: takes a Pose2, Pose3, Similarity2 or Similarity3")
    return _PART[a.name][1], attrs


def _t_scale(ins, attrs):
    if ins[0].name not in ("Similarity2", "Similarity3"):
        raise InputError(f"scale of a {ins[0]}: takes a Similarity2 or Similarity3")
    return vector(1), attrs


def _t_transform(op, allowed):
    def rule(ins, attrs):
        a, p = ins
        if a.name not in allowed:
            raise InputError(f"{op} of a {a}: takes a {' or '.join(allowed)}")
        _vector(p, f"{op}'s point", a.rot)
        return (POINT2 if a.rot == 2 else POINT3), attrs
    return rule


def _t_dot(ins, attrs):
    a, b = ins
    _vector(a, "dot")
    _vector(b, "dot", a.dim)
    return vector(1), attrs


def _t_norm(ins, attrs):
    _vector(ins[0], "norm")
    return vector(1), attrs


def _t_add(op):
    def rule(ins, attrs):
        a, b = ins
        _vector(a, op)
        _vector(b, op, a.dim)
        return (a if a.name == b.name else vector(a.dim)), attrs
    return rule


def _t_neg(ins, attrs):
    _vector(ins[0], "-")
    return ins[0], attrs


def _t_scale_by(ins, attrs):
    _vector(ins[0], "*")
    if "divisor" in attrs:
        divisor = _number(attrs.pop("divisor"))
        if divisor == 0.0:
            raise InputError("division by zero")
        attrs["factor"] = 1.0 / divisor
    else:
        attrs["factor"] = _number(attrs["factor"])
    return ins[0], attrs


def _t_matmul(ins, attrs):
    a = ins[0]
    _vector(a, "@")
    try:
        M = np.array(attrs["matrix"], dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"M @ v: M must be a constant matrix, got {type(attrs['matrix']).__name__}") from None
    if M.ndim != 2 or M.shape[1] != a.dim:
        raise InputError(f"M @ v: M must be a matrix of {a.dim} columns, got shape {M.shape}")
    if not np.all(np.isfinite(M)):
        raise InputError("M @ v: M must be finite")
    attrs["matrix"] = M
    return vector(M.shape[0]), attrs


def _t_select(ins, attrs):
    a = ins[0]
    _vector(a, "[]")
    index = attrs.pop("index")
    if isinstance(index, (int, np.integer)) and not isinstance(index, bool):
        i = int(index) + (a.dim if index < 0 else 0)
        if not 0 <= i < a.dim:
            raise InputError(f"index {index} out of a {a}")
        start, stop = i, i + 1
    elif isinstance(index, slice) and index.step in (None, 1):
        start, stop, _ = index.indices(a.dim)
        if stop <= start:
            raise InputError(f"the slice {index} of a {a} is empty")
    else:
        raise InputError(f"a {a} is indexed by an integer or a contiguous slice, got {index!r}")
    attrs["start"], attrs["stop"] = start, stop
    return vector(stop - start), attrs


def _t_stack(ins, attrs):
    if not ins:
        raise InputError("stack of nothing")
    for t in ins:
        _vector(t, "stack")
    return vector(sum(t.dim for t in ins)), attrs


def _t_bearing(ins, attrs):
    if len(ins) != 1:
        raise InputError("bearing takes a point, or a pose and a point")
    p = ins[0]
    _vector(p, "bearing")
    if p.dim not in (2, 3):
        raise InputError(f"bearing of a {p}: the direction of a Point2 (a Rot2) or a Point3 (a Unit3)")
    return (GROUPS["Rot2"] if p.dim == 2 else UNIT3), attrs


def _t_pinhole(ins, attrs):
    _vector(ins[0], "project's camera-frame point", 3)
    return POINT2, attrs


def _t_uncalibrate(ins, attrs):
    K, pn = ins
    if K.name not in ("Cal3_S2", "Cal3Bundler"):
        raise InputError(f"project's calibration must be a Cal3_S2 or a Cal3Bundler, got a {K}")
    _vector(pn, "project's normalized point", 2)
    return POINT2, attrs


_TYPES = {
    "compose": _t_binary_group("compose"), "between": _t_binary_group("between"),
    "localCoordinates": _t_binary_group("localCoordinates"), "inverse": _t_inverse, "logmap": _t_logmap,
    "retract": _t_retract, "expmap": _t_expmap, "rotation": _t_rotation, "translation": _t_translation,
    "scale": _t_scale,
    "transformFrom": _t_transform("transformFrom", _POSES), "transformTo": _t_transform("transformTo", _POSES),
    "rotate": _t_transform("rotate", _ROTATIONS), "unrotate": _t_transform("unrotate", _ROTATIONS),
    "dot": _t_dot, "norm": _t_norm, "add": _t_add("+"), "sub": _t_add("-"), "neg": _t_neg,
    "scale_by": _t_scale_by, "matmul": _t_matmul, "select": _t_select, "stack": _t_stack,
    "bearing": _t_bearing, "pinhole": _t_pinhole, "uncalibrate": _t_uncalibrate,
}
