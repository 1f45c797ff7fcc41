"""What a residual cannot be written with is refused when its kind is defined: every comparison,
branching, abs, **, max/min, math functions, numpy's ufuncs and functions, with InputError naming
the operation, the residual's function and its line; and what numpy arithmetic stays in the
vocabulary (M @ v, np.ones(3) + v, a numpy scalar times v) is kept.  Definition only: nothing
here compiles a kernel but the last test."""

from __future__ import annotations

import inspect
import math

import gtsam
import numpy as np
import pytest

import lie_factors as lf
from lie_factors.errors import InputError, LieFactorsError
from lie_factors.expressions import ops


def _refused(fn, *types, **constants) -> str:
    """The message of defining a kind of ``fn``, checked to name the function and the line that
    carries the marker comment ``# refused``."""
    with pytest.raises(InputError) as err:
        lf.factor(*types, **constants)(fn)
    lines, start = inspect.getsourcelines(fn)
    line = start + next(i for i, text in enumerate(lines) if "# refused" in text)
    text = str(err.value)
    assert text.startswith(f"{fn.__qualname__}, line {line}: "), text
    return text


def test_equality_is_refused_not_frozen_into_a_branch():
    def residual(x, z):
        if x.translation()[0] == z[0]:  # refused
            return z - z
        return x.translation() - z

    assert "`==` compares two values" in _refused(residual, "Pose3", measured="Point3")


@pytest.mark.parametrize("symbol", ["==", "!=", "<", "<=", ">", ">="])
def test_every_comparison_is_refused(symbol):
    compare = {"==": lambda a, b: a == b, "!=": lambda a, b: a != b, "<": lambda a, b: a < b,
               "<=": lambda a, b: a <= b, ">": lambda a, b: a > b, ">=": lambda a, b: a >= b}[symbol]

    def residual(p):
        compare(p[0], 1.0)  # refused
        return p

    # the comparison runs in the lambda, called from the marked line of the residual
    assert f"`{symbol}` compares two values" in _refused(residual, "Point3")


def test_max_min_and_sorted_say_that_they_compare():
    def with_max(p):
        return max(p[0], p[1])  # refused

    def with_min(p):
        return min(p[0], p[1])  # refused

    def with_sorted(p):
        return sorted([p[0], p[1]])[0]  # refused

    for fn in (with_max, with_min, with_sorted):
        text = _refused(fn, "Point3")
        assert "compares two values (as max(), min() and sorted() do" in text


def test_branching_and_truth_are_refused():
    def with_if(p):
        if p.norm():  # refused
            return p
        return -p

    def with_and(p):
        return p[0] and p  # refused

    def with_not(p):
        return p if not p[0] else -p  # refused

    for fn in (with_if, with_and, with_not):
        assert "cannot branch on a value" in _refused(fn, "Point3")


def test_abs_pow_and_other_operators_are_refused():
    def with_abs(p):
        return abs(p)  # refused

    def with_pow(p):
        return p ** 2  # refused

    def with_rpow(p):
        return 2.0 ** p  # refused

    def with_floordiv(p):
        return p // 2.0  # refused

    def with_mod(p):
        return p % 2.0  # refused

    assert "abs() is not in the vocabulary" in _refused(with_abs, "Point3")
    assert "`**` is not in the vocabulary" in _refused(with_pow, "Point3")
    assert "`**` is not in the vocabulary" in _refused(with_rpow, "Point3")
    assert "is not in the vocabulary" in _refused(with_floordiv, "Point3")
    assert "is not in the vocabulary" in _refused(with_mod, "Point3")


def test_math_functions_and_float_are_refused():
    def with_math(p):
        return math.sin(p[0]) * p  # refused

    def with_float(p):
        return float(p.norm()) * p  # refused

    for fn in (with_math, with_float):
        assert "is not a number" in _refused(fn, "Point3")


@pytest.mark.parametrize("name,call,expected", [
    ("np.sin", lambda p, q: np.sin(p), "np.sin of an expression is not in the vocabulary"),
    ("np.exp", lambda p, q: np.exp(p), "np.exp of an expression"),
    ("np.sqrt", lambda p, q: np.sqrt(p), "np.sqrt of an expression"),
    ("np.abs", lambda p, q: np.abs(p), "np.absolute of an expression is not in the vocabulary: it compares"),
    ("np.maximum", lambda p, q: np.maximum(p, q), "np.maximum of an expression is not in the vocabulary: it compares"),
    ("np.greater", lambda p, q: np.greater(p, q), "np.greater of an expression"),
    ("np.add out", lambda p, q: np.add(p, q, out=np.zeros(3)), "np.add of an expression"),
    ("np.cross", lambda p, q: np.cross(p, q), "np.cross of an expression is not in the vocabulary: write a.cross(b)"),
    ("np.dot", lambda p, q: np.dot(p, q), "np.dot of an expression is not in the vocabulary: write a.dot(b)"),
    ("np.linalg.norm", lambda p, q: np.linalg.norm(p), "np.linalg.norm of an expression is not in the "
                                                        "vocabulary: write a.norm()"),
    ("np.concatenate", lambda p, q: np.concatenate([p, q]), "np.concatenate of an expression is not in the "
                                                             "vocabulary: write ops.stack"),
    ("np.sum", lambda p, q: np.sum(p), "np.sum of an expression"),
    ("np.where", lambda p, q: np.where(p, p, q), "np.where of an expression is not in the vocabulary: it compares"),
])
def test_numpy_ufuncs_and_functions_are_refused_naming_them(name, call, expected):
    def residual(p, q):
        return call(p, q)  # refused

    assert expected in _refused(residual, "Point3", "Point3")


def test_constants_that_are_not_numbers_or_arrays_are_refused():
    def group_literal(x):
        return x.compose(gtsam.Pose3()).logmap()  # refused

    def list_of_expressions(p):
        return p - [p[0], p[1], p[2]]  # refused

    def array_of_expressions(p):
        return np.array([p[0], p[1], p[2]]) + p  # refused

    def bool_constant(p):
        return p + True  # refused

    def non_finite(p):
        return p - np.inf  # refused

    assert "declare it, lf.factor(..., name='Pose3')" in _refused(group_literal, "Pose3")
    assert "ops.stack" in _refused(list_of_expressions, "Point3")
    assert "ops.stack" in _refused(array_of_expressions, "Point3")
    assert "a bool is not a value" in _refused(bool_constant, "Point3")
    assert "must be finite" in _refused(non_finite, "Point3")


def test_shapes_that_do_not_fit_are_refused():
    def by_vector(p, q):
        return p / q  # refused

    def by_array(p):
        return p / np.ones(3)  # refused

    def matrix_residual(x):
        return x.matrix()  # refused

    def matrix_and_vector(x, p):
        return x.matrix() + p  # refused

    def wrong_columns(x, p):
        return x.matrix() @ p  # refused

    def theta_of_pose3(x):
        return x.theta()  # refused

    def rpy_of_pose3(x):
        return x.rpy()  # refused

    def pose_from_pose2(x, y):
        return x.transformPoseFrom(y).logmap()  # refused

    def cross_of_2d(a, b):
        return ops.cross(a, b)  # refused

    def catch_of_variable(x, p, z, K):
        return ops.catch_cheirality(ops.project(x, p, K) - z, p[0:2])  # refused

    assert "needs a scalar" in _refused(by_vector, "Point3", "Point3")
    assert "division by an array" in _refused(by_array, "Point3")
    assert "the residual is a Matrix4x4: return a vector, e.g. the matrix's flatten()" in _refused(
        matrix_residual, "Pose3")
    assert "both must be of one shape" in _refused(matrix_and_vector, "Rot3", "Point3")
    assert "Matrix4x4 @ Point3: 4 columns against 3 rows" in _refused(wrong_columns, "Pose3", "Point3")
    assert "theta of a Pose3: takes a Rot2 or a Pose2" in _refused(theta_of_pose3, "Pose3")
    assert "rpy of a Pose3: takes a Rot3 (of a Pose3: x.rotation().rpy())" in _refused(rpy_of_pose3, "Pose3")
    assert "transformPoseFrom of a Pose2: takes a Pose3" in _refused(pose_from_pose2, "Pose2", "Pose2")
    assert "cross takes a vector of dimension 3, got a Point2" in _refused(cross_of_2d, "Point2", "Point2")
    assert "fallback must depend on constants only" in _refused(catch_of_variable, "Pose3", "Point3",
                                                                 measured="Point2", K="Cal3_S2")


def test_refusals_are_lie_factors_errors():
    with pytest.raises(LieFactorsError):
        lf.factor("Point3")(lambda p: abs(p))
    with pytest.raises(ValueError):  # InputError is a ValueError
        lf.factor("Point3")(lambda p: np.sin(p))


def test_numpy_arithmetic_in_the_vocabulary_is_kept():
    """numpy's ufuncs that are the vocabulary's arithmetic defer to the expression: M @ v with a
    numpy M, np.ones(3) + v, a numpy scalar times v, np.negative(v): values against numpy's."""
    from support.kinds import evaluate

    M = np.arange(6.0).reshape(2, 3)
    kind = lf.factor("Point3")(lambda p: ops.stack(M @ p, np.ones(3) + p, np.array([1.0, 2.0, 3.0]) - p,
                                                   np.float64(2.5) * p, p * np.float64(0.5), np.negative(p),
                                                   np.add(p, p), np.multiply(2.0, p))).kind
    p = np.array([0.3, -1.2, 2.0])
    e, _ = evaluate(kind, [p], [])
    expected = np.concatenate([M @ p, np.ones(3) + p, np.array([1.0, 2.0, 3.0]) - p, 2.5 * p, 0.5 * p, -p, 2 * p,
                               2 * p])
    np.testing.assert_allclose(e, expected, rtol=0, atol=1e-15)
