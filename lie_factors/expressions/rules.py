"""The types of the vocabulary's operations: :func:`output_type` checks an operation's input
types when a residual is written and gives its output type (InputError naming the operation and
the types when they do not fit).  :data:`FAULTS` names what an operation cannot do at some
values, which its compiled form reports when a factor is evaluated there."""

from __future__ import annotations

import numpy as np

from ..errors import CheiralityException, EvaluationError, InputError
from .types import CAMERAS, GROUPS, POINT2, POINT3, STEREO_POINT2, UNIT3, ValueType, matrix, value_type, vector

#: GTSAM's ``Rot3::RQ`` refuses its derivative within this of pitch = +π/2 (gimbal lock).
GIMBAL_BAND = 1e-2

#: What an operation cannot do at some values (its compiled form returns False there): the
#: exception raised when a factor is evaluated there, and what it says.
FAULTS = {
    "pinhole": (CheiralityException, "project: the point is not in front of the camera (depth ≤ 0), "
                                     "GTSAM's CheiralityException"),
    "stereo": (CheiralityException, "project: the point is not in front of the stereo camera (depth ≤ 0), "
                                    "GTSAM's StereoCheiralityException"),
    "div": (EvaluationError, "division by zero"),
    "rpy": (EvaluationError, f"rpy: its derivative is undefined within {GIMBAL_BAND:g} of pitch = π/2 "
                             "(gimbal lock), as GTSAM's Rot3::RQ says"),
}

#: ``select``'s index of a matrix's transpose.
TRANSPOSE = object()

#: The operations whose fault ``ops.catch_cheirality`` catches (GTSAM's projection factors'
#: ``catch (CheiralityException&)``).
CHEIRALITY = ("pinhole", "stereo")


def _number(x) -> float:
    try:
        value = float(x)
    except (TypeError, ValueError, InputError):
        raise InputError(f"expected a constant number, got {type(x).__name__}") from None
    if not np.isfinite(value):
        raise InputError(f"a constant must be finite, got {value}")
    return value


_POSES = ("Pose2", "Pose3", "Similarity2", "Similarity3")
_ROTATIONS = ("Rot2", "Rot3")
_PART = {"Pose2": ("Rot2", POINT2), "Similarity2": ("Rot2", POINT2),
         "Pose3": ("Rot3", POINT3), "Similarity3": ("Rot3", POINT3)}
_PIXELS = ("Cal3_S2", "Cal3Bundler", "Cal3DS2", "Cal3Fisheye")


def _group(t: ValueType, op: str) -> None:
    if not t.is_group:
        raise InputError(f"{op} takes a group element (Rot2, Rot3, Pose2, Pose3, Similarity2, "
                         f"Similarity3), got a {t}")


def _vector(t: ValueType, op: str, dim: int | None = None, matrices: bool = False) -> None:
    if t.is_group:
        raise InputError(f"{op} takes a vector, got a {t} (a group element: compose, between, "
                         "localCoordinates …)")
    if t.kind == "unit":
        raise InputError(f"{op} takes a vector, got a Unit3 (a direction: compare two with "
                         "measured.localCoordinates(predicted))")
    if t.kind == "camera":
        raise InputError(f"{op} takes a vector, got a {t} (a camera: its pose(), calibration(), "
                         "project(point), localCoordinates)")
    if t.is_matrix and not matrices:
        raise InputError(f"{op} takes a vector, got a {t} (a matrix: index it, M[i, j], M[:, j], or "
                         "flatten() it)")
    if dim is not None and t.dim != dim:
        raise InputError(f"{op} takes a vector of dimension {dim}, got a {t}")


def _same(a: ValueType, b: ValueType, op: str) -> None:
    if a.name != b.name:
        raise InputError(f"{op} of a {a} and a {b}: both must be of one group type")


def _like(t: ValueType) -> ValueType:
    """The type of an entry-by-entry result shaped as ``t``: ``t`` itself if its stored array
    is its coordinates, else the plain vector of its coordinates."""
    return t if t.plain else vector(t.dim)


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


def _t_rpy(ins, attrs):
    if ins[0].name != "Rot3":
        hint = " (of a Pose3: x.rotation().rpy())" if ins[0].name == "Pose3" else ""
        raise InputError(f"rpy of a {ins[0]}: takes a Rot3{hint}")
    return vector(3), attrs


def _t_matrix(ins, attrs):
    _group(ins[0], "matrix")
    m = ins[0].shape[0]
    return matrix(m, m), attrs


def _t_adjoint_map(ins, attrs):
    _group(ins[0], "AdjointMap")
    return matrix(ins[0].dim, ins[0].dim), attrs


def _t_transform(op, allowed):
    def rule(ins, attrs):
        a, p = ins
        if a.name not in allowed:
            raise InputError(f"{op} of a {a}: takes a {' or '.join(allowed)}")
        _vector(p, f"{op}'s point", a.rot)
        return (POINT2 if a.rot == 2 else POINT3), attrs
    return rule


def _t_camera_part(part):
    def rule(ins, attrs):
        a = ins[0]
        if a.kind != "camera":
            raise InputError(f"{part} of a {a}: takes a camera ({', '.join(CAMERAS)})")
        return value_type("Pose3" if part == "pose" else CAMERAS[a.name]), attrs
    return rule


def _t_dot(ins, attrs):
    a, b = ins
    _vector(a, "dot")
    _vector(b, "dot", a.dim)
    return vector(1), attrs


def _t_cross(ins, attrs):
    a, b = ins
    _vector(a, "cross", 3)
    _vector(b, "cross", 3)
    return (POINT3 if a.name == b.name == "Point3" else vector(3)), attrs


def _t_norm(ins, attrs):
    _vector(ins[0], "norm", matrices=True)
    return vector(1), attrs


def _t_elementwise(op):
    def rule(ins, attrs):
        a, b = ins
        _vector(a, op, matrices=True)
        _vector(b, op, matrices=True)
        if a.dim != b.dim or a.is_matrix != b.is_matrix or a.cols != b.cols:
            raise InputError(f"{op} of a {a} and a {b}: both must be of one shape")
        return (_like(a) if a.name == b.name else _like(b) if b.is_matrix else vector(a.dim)), attrs
    return rule


def _t_neg(ins, attrs):
    _vector(ins[0], "-", matrices=True)
    return _like(ins[0]), attrs


def _t_scale_by(ins, attrs):
    _vector(ins[0], "*", matrices=True)
    if "divisor" in attrs:
        divisor = _number(attrs.pop("divisor"))
        if divisor == 0.0:
            raise InputError("division by zero")
        attrs["factor"] = 1.0 / divisor
    else:
        attrs["factor"] = _number(attrs["factor"])
    return _like(ins[0]), attrs


def _scalar(t: ValueType, op: str) -> None:
    _vector(t, op)
    if t.dim != 1:
        raise InputError(f"{op} needs a scalar (an expression of one entry, such as v.norm(), v[0], "
                         f"a.dot(b)), got a {t}")


def _t_smul(ins, attrs):
    s, a = ins
    _scalar(s, "a scalar times a vector")
    _vector(a, "*", matrices=True)
    return _like(a), attrs


def _t_div(ins, attrs):
    a, s = ins
    _vector(a, "/", matrices=True)
    _scalar(s, "division by an expression")
    return _like(a), attrs


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


def _t_mat_mul(ins, attrs):
    A, B = ins
    for t in ins:
        _vector(t, "@", matrices=True)
    r, k = (A.rows, A.cols) if A.is_matrix else (1, A.dim)
    k2, c = (B.rows, B.cols) if B.is_matrix else (B.dim, 1)
    if k != k2:
        raise InputError(f"{A} @ {B}: {k} columns against {k2} rows")
    attrs.update(r=r, k=k, c=c)
    return (matrix(r, c) if A.is_matrix and B.is_matrix else vector(r * c)), attrs


def _axis(index, n: int, t: ValueType) -> tuple[list, bool]:
    """The positions ``index`` (an integer or a slice) picks among ``n``, and whether it keeps
    the axis (a slice)."""
    if isinstance(index, (int, np.integer)) and not isinstance(index, (bool, np.bool_)):
        i = int(index) + (n if index < 0 else 0)
        if not 0 <= i < n:
            raise InputError(f"index {index} out of a {t}")
        return [i], False
    if isinstance(index, slice):
        picked = list(range(*index.indices(n)))
        if not picked:
            raise InputError(f"the slice {index} of a {t} is empty")
        return picked, True
    raise InputError(f"a {t} is indexed by integers and slices, got {index!r}")


def _t_select(ins, attrs):
    a = ins[0]
    _vector(a, "[]", matrices=True)
    index = attrs.pop("index")
    if index is TRANSPOSE:
        rows, cols = a.rows, a.cols
        attrs["indices"] = tuple(i * cols + j for j in range(cols) for i in range(rows))
        return matrix(cols, rows), attrs
    if a.is_matrix:
        parts = index if isinstance(index, tuple) else (index, slice(None))
        if len(parts) != 2:
            raise InputError(f"a {a} is indexed by a row, or a row and a column, got {index!r}")
        rows, keep_rows = _axis(parts[0], a.rows, a)
        cols, keep_cols = _axis(parts[1], a.cols, a)
        attrs["indices"] = tuple(i * a.cols + j for i in rows for j in cols)
        t = matrix(len(rows), len(cols)) if keep_rows and keep_cols else vector(len(rows) * len(cols))
        return t, attrs
    if isinstance(index, tuple) and len(index) == 1:
        index = index[0]
    picked, _ = _axis(index, a.dim, a)
    attrs["indices"] = tuple(picked)
    return vector(len(picked)), attrs


def _t_flatten(ins, attrs):
    return vector(ins[0].dim), attrs


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
    if K.name not in _PIXELS:
        raise InputError(f"project's calibration must be one of {', '.join(_PIXELS)} or Cal3_S2Stereo, got a {K}")
    _vector(pn, "project's normalized point", 2)
    return POINT2, attrs


def _t_stereo(ins, attrs):
    K, q = ins
    if K.name != "Cal3_S2Stereo":
        raise InputError(f"a stereo projection's calibration must be a Cal3_S2Stereo, got a {K}")
    _vector(q, "project's camera-frame point", 3)
    return STEREO_POINT2, attrs


def _t_catch(ins, attrs):
    r, fallback = ins
    _vector(r, "catch_cheirality")
    _vector(fallback, "catch_cheirality's fallback", r.dim)
    return r, attrs


_TYPES = {
    "compose": _t_binary_group("compose"), "between": _t_binary_group("between"),
    "localCoordinates": _t_binary_group("localCoordinates"), "inverse": _t_inverse, "logmap": _t_logmap,
    "retract": _t_retract, "expmap": _t_expmap, "rotation": _t_rotation, "translation": _t_translation,
    "scale": _t_scale, "rpy": _t_rpy, "camera_pose": _t_camera_part("pose"),
    "camera_calibration": _t_camera_part("calibration"), "matrix": _t_matrix, "adjoint_map": _t_adjoint_map,
    "transformFrom": _t_transform("transformFrom", _POSES), "transformTo": _t_transform("transformTo", _POSES),
    "rotate": _t_transform("rotate", _ROTATIONS), "unrotate": _t_transform("unrotate", _ROTATIONS),
    "dot": _t_dot, "cross": _t_cross, "norm": _t_norm, "add": _t_elementwise("+"),
    "sub": _t_elementwise("-"), "emul": _t_elementwise("*"), "neg": _t_neg, "scale_by": _t_scale_by,
    "smul": _t_smul, "div": _t_div, "matmul": _t_matmul, "mat_mul": _t_mat_mul, "select": _t_select,
    "flatten": _t_flatten, "stack": _t_stack, "bearing": _t_bearing, "pinhole": _t_pinhole,
    "uncalibrate": _t_uncalibrate, "stereo": _t_stereo, "catch_cheirality": _t_catch,
}
