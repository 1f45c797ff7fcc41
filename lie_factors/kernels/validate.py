"""Input validation in numpy: one rule per kind of argument, one message per defect.

The public functions (:mod:`lie_factors.kernels.public`) convert their input
with :func:`tangent` (a tangent vector), :func:`square` (a Lie-algebra matrix,
for ``vee``) or, for a group element, :func:`square` followed by the numba test
:func:`lie_factors.kernels.checks.element_code` worded by :func:`defect` (unit
quaternions: :func:`unit`), so wrong shapes, non-finite values and non-members
raise :class:`~lie_factors.errors.InputError` (a ``ValueError``) naming the
expected shape or the defect instead of returning garbage. The factors word their messages with :func:`defect` too.

This module imports no numba: :func:`rotation_block` and :func:`bottom_row` are
the element test in numpy, with the same wording, for the numba-free callers
(the initializers on the ``--backend native`` path).
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from .registry import NO_CORNER, ONE, POSITIVE, UNIT, GroupInfo

#: Largest accepted max|RᵀR − I| for a rotation block.
ORTHONORMAL_TOL = 1e-9
#: Largest accepted |‖q‖ − 1| of a unit quaternion (q_r of a dual quaternion), and
#: |q_r · q_d| / max(1, ‖q_d‖) of a unit dual quaternion.
UNIT_TOL = 1e-9

#: Defects of a matrix element, in the order they are tested: the codes of
#: :func:`lie_factors.kernels.checks.element_code`, worded by :func:`defect`.
OK, NOT_FINITE, NOT_ORTHONORMAL, REFLECTION, BAD_LAST_ROW, BAD_SCALE = range(6)


def _as_float(a, name: str) -> np.ndarray:
    try:
        arr = np.asarray(a, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name}: cannot convert {type(a).__name__} to a float64 array") from exc
    return arr


def _check_finite(arr: np.ndarray, name: str) -> None:
    if not np.all(np.isfinite(arr)):
        raise InputError(f"{name}: {defect(NOT_FINITE)}")


def tangent(x, n: int, name: str = "x") -> np.ndarray:
    """Return ``x`` as a finite float64 array of shape ``(..., n)``."""
    arr = _as_float(x, name)
    if arr.ndim < 1 or arr.shape[-1] != n:
        raise InputError(f"{name}: expected shape (..., {n}), got {arr.shape}")
    _check_finite(arr, name)
    return arr


def square(X, m: int, name: str = "X") -> np.ndarray:
    """Return ``X`` as a finite float64 array of shape ``(..., m, m)``."""
    arr = _as_float(X, name)
    if arr.ndim < 2 or arr.shape[-2:] != (m, m):
        raise InputError(f"{name}: expected shape (..., {m}, {m}), got {arr.shape}")
    _check_finite(arr, name)
    return arr


def last_row(info: GroupInfo) -> str:
    """The last row of an element of ``info``, as the messages write it: ``[0, 0, 0, 1]``,
    ``[0, 0, 1/s]``."""
    return "[" + "0, " * (info.mat - 1) + ("1]" if info.corner == ONE else "1/s]")


def _orthonormality(X: np.ndarray, d: int) -> float:
    """max|RᵀR − I| over the rotation blocks R = X[..., :d, :d] (0 for no element)."""
    B = X[..., :d, :d]
    gram = np.einsum("...ki,...kj->...ij", B, B) - np.eye(d)
    return float(np.max(np.abs(gram))) if gram.size else 0.0


def _not_orthonormal(X: np.ndarray, d: int) -> str:
    return f"rotation block is not orthonormal (max|RᵀR - I| = {_orthonormality(X, d):.3g})"


def _bad_last_row(row: str, scale: bool) -> str:
    return f"non-positive scale: expected last row {row} with s > 0" if scale else f"expected last row {row}"


_REFLECTION = "rotation block has determinant -1 (a reflection)"


def defect(code: int, info: GroupInfo | None = None, X: np.ndarray | None = None) -> str:
    """What a failed :func:`lie_factors.kernels.checks.element_code` ``code`` means for the
    element(s) ``X`` of ``info``: the message of the public functions and of the factors
    (which prefix their own context)."""
    if code == NOT_FINITE:
        return "contains NaN or inf"
    if code == NOT_ORTHONORMAL:
        return _not_orthonormal(X, info.rot_dim)
    if code == REFLECTION:
        return _REFLECTION
    return _bad_last_row(last_row(info), code == BAD_SCALE)


def rotation_block(R: np.ndarray, name: str, d: int) -> None:
    """Raise :class:`~lie_factors.errors.InputError` unless every ``R[..., :d, :d]`` of the finite ``R``
    is a rotation."""
    if _orthonormality(R, d) > ORTHONORMAL_TOL:
        raise InputError(f"{name}: {_not_orthonormal(R, d)}")
    B = R[..., :d, :d]
    if B.size and np.any(np.linalg.det(B) < 0):
        raise InputError(f"{name}: {_REFLECTION}")


def bottom_row(X: np.ndarray, name: str, expected: str, last_positive: bool = False) -> None:
    """Check the last row of homogeneous matrices: zeros, then 1 (or any s > 0); ``expected``
    is how the message writes the row (:func:`last_row`)."""
    if X[..., -1, :-1].size and np.any(X[..., -1, :-1] != 0.0):
        raise InputError(f"{name}: {_bad_last_row(expected, False)}")
    corner = X[..., -1, -1]
    if np.any(corner <= 0.0) if last_positive else np.any(corner != 1.0):
        raise InputError(f"{name}: {_bad_last_row(expected, last_positive)}")


def unit(q, info: GroupInfo, name: str = "q") -> np.ndarray:
    """Return ``q`` as float64 unit quaternions (..., 4), |‖q‖ − 1| ≤ UNIT_TOL, or unit dual
    quaternions (..., 8): that for q_r, and |q_r · q_d| / max(1, ‖q_d‖) ≤ UNIT_TOL."""
    n = info.element[0]
    q = tangent(q, n, name)
    if not q.size:
        return q
    dev = float(np.max(np.abs(np.linalg.norm(q[..., :4], axis=-1) - 1.0)))
    if n == 4:
        if dev > UNIT_TOL:
            raise InputError(f"{name}: expected {info.label} of shape (..., 4) (max | |q| - 1 | = {dev:.3g})")
        return q
    qr, qd = q[..., :4], q[..., 4:]
    # |q_r·q_d| / max(1, ‖q_d‖), computed on u = q_d / max(1, max|q_d|): the same ratio,
    # but ‖q_d‖² cannot overflow (translations up to ~1e308).
    u = qd / np.maximum(1.0, np.max(np.abs(qd), axis=-1, keepdims=True))
    orth = float(np.max(np.abs(np.sum(qr * u, axis=-1)) / np.maximum(1.0, np.linalg.norm(u, axis=-1))))
    if max(dev, orth) > UNIT_TOL:
        raise InputError(f"{name}: expected {info.label} of shape (..., 8) "
                         f"(| |q_r| - 1 | = {dev:.3g}, |q_r . q_d| = {orth:.3g})")
    return q


def rule(info: GroupInfo) -> str:
    """What an element of ``info`` is, in words: "every X is ..." (the public functions' docstrings)."""
    if info.corner == UNIT:
        if info.element[0] == 4:
            return f"a unit quaternion (|‖q‖ − 1| ≤ {UNIT_TOL:g})"
        return (f"a unit dual quaternion (|‖q_r‖ − 1| ≤ {UNIT_TOL:g} and "
                f"|q_r · q_d| ≤ {UNIT_TOL:g} max(1, ‖q_d‖))")
    block = "a rotation" if info.corner == NO_CORNER else f"its block X[:{info.rot_dim}, :{info.rot_dim}] a rotation"
    text = f"an element of {info.label}: {block} (max|RᵀR − I| ≤ {ORTHONORMAL_TOL:g}, det > 0)"
    if info.corner == NO_CORNER:
        return text
    return f"{text}, last row {last_row(info)}" + (" with s > 0" if info.corner == POSITIVE else "")
