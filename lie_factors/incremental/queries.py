"""What the smoother answers without changing: its estimate, θ, δ, factors, marginals, errors.

:class:`Queries` is the part of :class:`~lie_factors.incremental.smoother.Smoother`
that reads its state, under ``gtsam.ISAM2``'s names: the estimate θ ⊕ δ
(``calculateEstimate``, ``calculateBestEstimate`` with the exact δ), θ and δ
themselves, the factors added, marginal covariances and information of one
variable or jointly of several (from the factor's own columns, no Marginals
object), the error of the factor's conditionals at a ``VectorValues`` (ISAM2's
``error``) and of the factors at a ``Values``, the variable index, the factor's
entries (``treeNnz``).  Variables an update took out are in none of them.
"""

from __future__ import annotations

import gtsam
import numpy as np

from ..batch.graph import key_name
from ..errors import InputError
from ..interop import to_gtsam
from .group_statistic import group_statistic
from .gtsam_objects import make_factor, retracted


class JointMarginal:
    """A joint marginal of several variables, as ``gtsam.JointMarginal`` is read: its blocks in
    the order of the keys asked (``fullMatrix()``, ``at(key1, key2)``, ``keys()``)."""

    def __init__(self, keys: list, dims: list, matrix: np.ndarray):
        self._keys = list(keys)
        self._offsets = dict(zip(self._keys, np.concatenate([[0], np.cumsum(dims)[:-1]]).astype(int).tolist()))
        self._dims = dict(zip(self._keys, dims))
        self._matrix = matrix

    def fullMatrix(self) -> np.ndarray:
        """(Σd, Σd): every block, the keys in the order asked."""
        return self._matrix.copy()

    def at(self, key1, key2) -> np.ndarray:
        """The block of ``key1``, ``key2``."""
        for k in (key1, key2):
            if int(k) not in self._offsets:
                raise InputError(f"key {key_name(int(k))} is not in this joint marginal")
        a, b = self._offsets[int(key1)], self._offsets[int(key2)]
        return self._matrix[a:a + self._dims[int(key1)], b:b + self._dims[int(key2)]].copy()

    def keys(self) -> list:
        return list(self._keys)

    def __repr__(self) -> str:
        return f"<JointMarginal of {', '.join(map(key_name, self._keys))}>"


class Queries:
    """The reading half of the smoother (module docstring)."""

    def getDelta(self) -> gtsam.VectorValues:
        """δ (the step from θ to the estimate) as a ``gtsam.VectorValues``."""
        self._solve()
        vv = gtsam.VectorValues()
        for k, v in self.var.items():
            vv.insert(k, self._variable_step(v).copy())
        return vv

    def between_statistic(self, group: str, ends, where, C, R, sign: float) -> float:
        """T = bᵀ (I + sign·A Σ Aᵀ)⁻¹ b of between factors of group ``group`` at the estimate, NaN at
        leverage 1 (:func:`~lie_factors.incremental.group_statistic.group_statistic`): ``ends``
        their distinct keys, ``where`` (g, 2) int64 each factor's ends as places in ``ends``, ``C``
        (g, m, m) the measurements' inverses, ``R`` (g, n, n) their whitening."""
        vs = np.array([self._var_of(k) for k in ends], dtype=np.int64)
        return group_statistic(self, self.elements[group], vs, where, C, R, sign)

    def _var_of(self, key) -> int:
        try:
            v = self.var.get(int(key))
        except (TypeError, ValueError):
            raise InputError(f"expected a key (an integer), got {type(key).__name__}") from None
        if v is None:
            raise InputError(f"key {key_name(int(key))} is not a variable of the smoother")
        return v

    def _estimate_matrix(self, v: int) -> np.ndarray:
        el = self.elements[self.vgroup[v]]
        out = np.empty((1, el.spec.mat, el.spec.mat))
        e = self.velem[v:v + 1]
        el.loops.retract(np.ascontiguousarray(el.X[e]), self.step, self.bf.tree.voff[v:v + 1], out)
        return out[0]

    def calculateEstimate(self, key=None):
        """θ ⊕ δ: a ``gtsam.Values`` of every variable, or the value of ``key``."""
        self._solve()
        if key is not None:
            v = self._var_of(key)
            name = self.vgroup[v]
            if name is not None:
                return to_gtsam(name, self._estimate_matrix(v))
            return self._other_estimate(v)
        return self._estimate(self.step)

    def _estimate(self, delta: np.ndarray) -> gtsam.Values:
        """θ ⊕ ``delta`` of every variable, a ``gtsam.Values``."""
        out = gtsam.Values()
        bf = self.bf
        for name, el in self.elements.items():
            idx = np.arange(el.n)
            if bf.ndead:
                idx = idx[bf.vdead[el.var[idx]] == 0]
            X = np.empty((len(idx), el.spec.mat, el.spec.mat))
            el.loops.retract(np.ascontiguousarray(el.X[idx]), delta, bf.tree.voff[el.var[idx]], X)
            spec = el.spec
            for v, M in zip(el.var[idx].tolist(), X):
                out.insert(self.keys[v], to_gtsam(spec.name, M))
        if self.other.size():
            vv = gtsam.VectorValues()
            for k, v in self.var.items():
                if self.vgroup[v] is None:
                    o, d = int(bf.tree.voff[v]), int(bf.tree.dim[v])
                    vv.insert(k, delta[o:o + d].copy())
            out.insert(self.other.retract(vv))
        return out

    def calculateBestEstimate(self) -> gtsam.Values:
        """θ ⊕ δ with δ from a full back-substitution (every node solved, no wildfire
        threshold); the smoother's own δ is left as it was (ISAM2's ``calculateBestEstimate``)."""
        self._solve()
        bf = self.bf
        saved_delta = bf.delta.copy()
        saved_replaced = bf.wildfire.replaced.copy()
        try:
            bf.replace_all()
            bf.solve(0.0)
            return self._estimate(bf.delta)
        finally:
            bf.delta[:] = saved_delta
            bf.wildfire.replaced[:] = saved_replaced

    def _other_estimate(self, v: int):
        k = self.keys[v]
        return retracted(self.other, k, self.other_types[k], self._variable_step(v))

    def getLinearizationPoint(self) -> gtsam.Values:
        """θ as a ``gtsam.Values`` (a copy)."""
        out = gtsam.Values()
        bf = self.bf
        for name, el in self.elements.items():
            idx = np.arange(el.n)
            if bf.ndead:
                idx = idx[bf.vdead[el.var[idx]] == 0]
            for v, M in zip(el.var[idx].tolist(), el.X[idx]):
                out.insert(self.keys[v], to_gtsam(el.spec.name, M))
        if self.other.size():
            out.insert(self.other)
        return out

    def getFactorsUnsafe(self) -> gtsam.NonlinearFactorGraph:
        """Every factor added, at its index (``None`` where a factor was removed, as in ISAM2's
        graph); factors given as arrays are made as GTSAM's ``BetweenFactor``/``PriorFactor``
        with ``noiseModel.Gaussian.Information``."""
        graph = gtsam.NonlinearFactorGraph()
        removed = self.bf.fremoved
        for f, (code, local) in enumerate(zip(self.fkind[:self.bf.nf].tolist(), self.flocal[:self.bf.nf].tolist())):
            if removed[f]:
                graph.push_back(None)
            elif code == -1:
                graph.push_back(self.native[local][0])
            else:
                store = self.kind_list[code]
                factor = store.source[local]
                graph.push_back(factor if factor is not None else make_factor(store, local, self.keys))
        return graph

    def getVariableIndex(self) -> gtsam.VariableIndex:
        """The factors of every variable (``gtsam.VariableIndex`` of :meth:`getFactorsUnsafe`)."""
        return gtsam.VariableIndex(self.getFactorsUnsafe())

    def getFixedVariables(self) -> gtsam.KeySet:
        """The variables of marginal factors, never relinearized (ISAM2's fixed variables)."""
        return gtsam.KeySet([self.keys[v] for v in np.flatnonzero(self.vfixed[:len(self.keys)]).tolist()])

    def marginalCovariance(self, key) -> np.ndarray:
        """The marginal covariance of ``key`` at θ, (d, d): its block of Λ⁻¹, from the path of
        its column to the root of the factor (cheapest for the newest variables)."""
        return self.bf.marginal_covariance(self._var_of(key))

    def marginalInformation(self, key) -> np.ndarray:
        """The marginal information of ``key`` at θ, (d, d): the inverse of its marginal covariance."""
        return _inverse(self.marginalCovariance(key))

    def _joint(self, keys) -> tuple[list, list, np.ndarray]:
        keys = [int(k) for k in keys]
        if not keys:
            raise InputError("a joint marginal needs one key at least")
        if len(set(keys)) != len(keys):
            raise InputError("a joint marginal's keys must be distinct")
        vs = [self._var_of(k) for k in keys]
        return keys, [int(self.bf.tree.dim[v]) for v in vs], self.bf.joint_covariance(vs)

    def jointMarginalCovariance(self, keys) -> JointMarginal:
        """The joint marginal covariance of ``keys`` at θ, its blocks in the order of ``keys``."""
        keys, dims, cov = self._joint(keys)
        return JointMarginal(keys, dims, cov)

    def jointMarginalInformation(self, keys) -> JointMarginal:
        """The joint marginal information of ``keys`` at θ: the inverse of their joint covariance."""
        keys, dims, cov = self._joint(keys)
        return JointMarginal(keys, dims, _inverse(cov))

    def error(self, x=None) -> float:
        """ISAM2's ``error(VectorValues x)``: ½ Σ ‖R_j x_j + T_j x_S − d_j‖² over the factor's
        conditionals (its Bayes tree as a Gaussian factor graph).  Given a ``gtsam.Values``
        (or nothing: the estimate), the factors' error there (:meth:`error_at`)."""
        if not isinstance(x, gtsam.VectorValues):
            return self.error_at(x)
        bf = self.bf
        flat = np.zeros(bf.nscalar)
        found = 0
        for k, v in self.var.items():  # (a VectorValues cannot list its keys from Python)
            if not x.exists(k):
                continue
            found += 1
            vk = np.asarray(x.at(k), dtype=np.float64).reshape(-1)
            d = int(bf.tree.dim[v])
            if vk.shape[0] != d:
                raise InputError(f"error: key {key_name(int(k))} has {d} dimensions, got {vk.shape[0]}")
            o = int(bf.tree.voff[v])
            flat[o:o + d] = vk
        if found < x.size():
            raise InputError("error: the VectorValues holds a key that is not a variable of the smoother")
        return bf.conditional_error(flat)

    def error_at(self, values: gtsam.Values | None = None) -> float:
        """The factors' error ½Σ‖whitened residual‖² at ``values`` (default: the estimate)."""
        values = self.calculateEstimate() if values is None else values
        return float(self.getFactorsUnsafe().error(values))

    def treeNnz(self) -> int:
        """The entries of the factor's conditionals (ISAM2's ``treeNnz``: Σ d(d + 1)/2 + d·s)."""
        return self.bf.nnz()

    def size(self) -> int:
        """The nodes of the factor's tree (one per variable)."""
        return self.bf.live

    def empty(self) -> bool:
        return self.bf.live == 0

    def valueExists(self, key) -> bool:
        """Whether ``key`` is a variable of the smoother."""
        return int(key) in self.var


def _inverse(matrix: np.ndarray) -> np.ndarray:
    """The inverse of a symmetric positive definite matrix, by its Cholesky factor."""
    L = np.linalg.cholesky(matrix)
    Linv = np.linalg.solve(L, np.eye(len(L)))
    return Linv.T @ Linv
