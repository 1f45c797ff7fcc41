"""Evaluating a factor kind's kernel on arrays, and Richardson differences of its residual."""

from __future__ import annotations

import numpy as np

from lie_factors import se2, se3, sim2, sim3, so3
from lie_factors.expressions.types import ValueType

_EXP = {"Rot3": so3.exp, "Pose3": se3.exp, "Pose2": se2.exp, "Similarity2": sim2.exp, "Similarity3": sim3.exp}


def group_exp(t: ValueType, x: np.ndarray) -> np.ndarray:
    """Exp(x) of the group ``t`` (Rot2 by its angle)."""
    if t.name == "Rot2":
        c, s = np.cos(x[0]), np.sin(x[0])
        return np.array([[c, -s], [s, c]])
    return _EXP[t.name](x)


def perturbed(t: ValueType, value: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """X·Exp(δ) of a group element, p + δ of a vector (on its first dim entries: a Cal3Bundler's
    principal point stays): GTSAM's retract."""
    if t.is_group:
        return value @ group_exp(t, delta)
    out = np.array(value, dtype=np.float64)
    out[:t.dim] += delta
    return out


def evaluate(kind, values: list, constants: list, jacobians: bool = True, status: bool = False):
    """(e (m,), [H_j (m, d_j)]) of one factor of ``kind`` at ``values`` (one array per variable);
    with ``status``, (e, H, the kernel's status of the factor)."""
    m = kind.dim
    args = list(kind.tags)
    index = np.zeros(1, dtype=np.int64)
    for t, v in zip(kind.variables, values):
        args += [np.ascontiguousarray(np.asarray(v, dtype=np.float64).reshape((1,) + t.shape)), index]
    for t, c in zip(kind.constants, constants):
        args.append(np.ascontiguousarray(np.asarray(c, dtype=np.float64).reshape((1,) + t.shape)))
    e, A, code = np.zeros((1, m)), np.zeros((1, m, kind.columns)), np.zeros(1, dtype=np.int64)
    args += [np.eye(m)[None], index, e, A, np.zeros((1, m)), np.zeros(1), code, 0, 1]
    kind.module.evaluate(*args, jacobians)
    H = [A[0, :, o:o + t.dim].copy() for o, t in zip(kind.offsets, kind.variables)]
    if status:
        return e[0].copy(), H, int(code[0])
    assert code[0] == 0, (kind.name, int(code[0]))
    return e[0].copy(), H


def richardson(kind, values: list, constants: list, h: float = 1e-3) -> list:
    """The Jacobians of ``kind``'s residual by Richardson-extrapolated central differences of
    retracted variables (error O(h⁴))."""
    out = []
    for j, t in enumerate(kind.variables):
        cols = []
        for i in range(t.dim):
            def f(step):
                d = np.zeros(t.dim)
                d[i] = step
                vs = list(values)
                vs[j] = perturbed(t, values[j], d)
                return evaluate(kind, vs, constants, jacobians=False)[0]

            d1 = (f(h) - f(-h)) / (2 * h)
            d2 = (f(h / 2) - f(-h / 2)) / h
            cols.append((4 * d2 - d1) / 3)
        out.append(np.stack(cols, axis=1))
    return out


def relative_error(A: np.ndarray, B: np.ndarray) -> float:
    """max|A − B| / max(1, max|B|), the project's accuracy measure."""
    return float(np.max(np.abs(A - B)) / max(1.0, float(np.max(np.abs(B)))))
