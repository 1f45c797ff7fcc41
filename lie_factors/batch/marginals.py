"""Marginal covariances at a point, from the batch solver's own sparse Cholesky factor.

At the estimate, the Gauss–Newton information matrix of the whitened factors is
H = Σ_f w_f·A_fᵀA_f (:mod:`lie_factors.batch.system`, undamped), and the marginal
covariance of a variable is its diagonal block of H⁻¹, in the variable's tangent
coordinates (GTSAM's order: Pose2 [x, y, θ], Pose3 [ω, v], …) — what
``gtsam.Marginals(graph, values).marginalCovariance(key)`` returns.  Here H is factored
once by CHOLMOD (:class:`lie_factors.sparse.cholmod.Cholesky`, supernodal) and inverted
on the factor's pattern only (:mod:`lie_factors.sparse.selinv`), which holds every
variable's diagonal block: all of them for the cost of one more factorization.
A variable a hard constraint pins (``NonlinearEquality``, a constrained prior) is known
exactly: its covariance is 0 and the others' are conditioned on it, as GTSAM's are.
Where CHOLMOD is not installed, where a hard constraint holds part of a variable or
several, and where the batch solver cannot read the graph, GTSAM's ``Marginals`` answers
instead.
"""

from __future__ import annotations

import numpy as np

from ..errors import IndeterminantLinearSystem, InputError, NotPositiveDefinite
from ..sparse import cholmod
from ..sparse.selinv import diagonal_blocks, invert_in_place
from ..sparse.supernodes import Supernodes
from ..posegraph import gauge
from .graph import Problem, key_name
from .system import LinearSystem

__all__ = ["Marginals"]

#: What a refusal says first: H is singular where the graph does not determine a variable.
SINGULAR = "Marginals: the information matrix is singular"


def _refuse(finding, key_of) -> None:
    """Raise the refusal of a structural finding (:mod:`lie_factors.posegraph.gauge`), if any:
    ``key_of(variable)`` is the key of the variable it names."""
    if finding is not None:
        raise finding.error(SINGULAR, key_name(key_of(finding.variable)))


def _refuse_keys_in_no_factor(values, problem: Problem) -> None:
    """A key of ``values`` that no factor of the graph touches has no marginal: refused (GTSAM's
    Marginals fails when its covariance is asked)."""
    keys = np.asarray(values.keys(), dtype=np.uint64)
    loose = np.setdiff1d(keys, np.asarray(problem.var_keys, dtype=np.uint64))
    if loose.size:
        raise gauge.too_few_rows(None, 0, 1).error(SINGULAR, key_name(int(loose[0])))


class Marginals:
    """``gtsam.Marginals``' covariances, from the batch solver's factorization (module docstring).

    ``Marginals(graph, values)``: a ``gtsam.NonlinearFactorGraph`` linearized at ``values``
    (robust noise models reweighted at ``values``, as GTSAM's linearization does);
    :meth:`of_pose_graph`: a pose graph's arrays, with no factor object.  Raises
    :class:`~lie_factors.errors.IndeterminantLinearSystem` where H is singular (a variable
    the factors do not determine: no prior, say).
    """

    def __init__(self, graph, values):
        self._gtsam = None
        try:
            problem = Problem(graph, values)
        except InputError:
            # what the batch solver cannot read (a factor on a key the values lack, as GTSAM's
            # LinearContainerFactor of a linear graph): GTSAM's Marginals, where it can
            if not self._gtsam_can(graph, values):
                raise
            return
        _refuse_keys_in_no_factor(values, problem)
        _refuse(problem.undetermined(), lambda v: problem.var_keys[v])
        if cholmod.available() and not problem.general_constraints:
            self._compute(problem)
        else:  # GTSAM's elimination imposes hard constraints on part of a variable
            self._use_gtsam(graph, values)

    @classmethod
    def of_pose_graph(cls, pose_graph, poses: np.ndarray) -> "Marginals":
        """The marginals of a :class:`~lie_factors.posegraph.graph.PoseGraph` (its edges and priors;
        give it its prior first: :meth:`~lie_factors.posegraph.graph.PoseGraph.with_first_prior`)
        at ``poses`` (P, m, m) in its keys' order, straight from its arrays."""
        self = cls.__new__(cls)
        self._gtsam = None
        _refuse(gauge.of_pose_graph(pose_graph), lambda v: pose_graph.keys[v])
        if cholmod.available():
            self._compute(Problem.from_pose_graph(pose_graph, poses))
        else:
            from ..interop import values_from_matrices

            self._use_gtsam(pose_graph.factor_graph(), values_from_matrices(pose_graph.group, pose_graph.keys, poses))
        return self

    def _use_gtsam(self, graph, values) -> None:
        import gtsam

        self._gtsam = gtsam.Marginals(graph, values)
        self._keys = {int(k) for k in values.keys()} | {int(k) for k in graph.keyVector()}

    def _gtsam_can(self, graph, values) -> bool:
        try:
            self._use_gtsam(graph, values)
        except (RuntimeError, ValueError, TypeError):
            return False
        return True

    def _compute(self, problem: Problem) -> None:
        system = LinearSystem(problem)
        system.linearize_assemble()
        p = system.pattern
        factor = cholmod.Cholesky(p.colptr, p.rowind, natural=True, supernodal=True)
        try:
            with system.holding(system.data, np.zeros(p.n)):  # a pinned variable: H's row the identity's
                factor.factorize(system.data)
        except NotPositiveDefinite as exc:
            variable = system.variable_at(exc.column)
            where = "" if variable is None else f" near variable {key_name(problem.var_keys[variable])}"
            raise IndeterminantLinearSystem(f"{SINGULAR}{where}: {exc}", variable) from None
        del system
        inverse = invert_in_place(factor.supernodes() if factor.supernodal and cholmod.direct_available()
                                  else Supernodes.from_lower(*factor.lower()))
        row_of = np.empty(p.n, dtype=np.int64)  # δ index → matrix row
        row_of[p.scalar_order] = np.arange(p.n)
        dims = problem.var_dims
        #: variable index → (its dimension's block array, its place there)
        self._blocks: dict[int, np.ndarray] = {}
        self._place = np.empty(len(dims), dtype=np.int64)
        for d in np.unique(dims).tolist():
            idx = np.flatnonzero(dims == d)
            rows = row_of[problem.var_offsets[idx][:, None] + np.arange(d)]
            self._blocks[d] = diagonal_blocks(inverse, rows)
            self._place[idx] = np.arange(len(idx))
        for _, v in problem.pins:  # held by a hard constraint: known exactly (GTSAM's covariance is 0)
            self._blocks[int(dims[v])][self._place[v]] = 0.0
        self._index = problem.var_index
        self._dims = dims
        factor.free()

    def _variable(self, key) -> int:
        try:
            k = int(key)
        except (TypeError, ValueError):
            raise InputError(f"marginalCovariance: expected an integer key, got {key!r}") from None
        v = self._index.get(k)
        if v is None:
            raise InputError(f"marginalCovariance: {key_name(k)} is not a variable of the graph")
        return v

    def marginalCovariance(self, key) -> np.ndarray:
        """(d, d): the covariance of ``key``'s variable in its tangent coordinates."""
        if self._gtsam is not None:
            if int(key) not in self._keys:
                raise InputError(f"marginalCovariance: {key_name(int(key))} is not a variable of the graph")
            return np.asarray(self._gtsam.marginalCovariance(int(key)))
        v = self._variable(key)
        return self._blocks[int(self._dims[v])][self._place[v]].copy()

    def marginalInformation(self, key) -> np.ndarray:
        """(d, d): the inverse of :meth:`marginalCovariance`."""
        return np.linalg.inv(self.marginalCovariance(key))

    def covariances(self, keys) -> np.ndarray:
        """(n, d, d): :meth:`marginalCovariance` of each of ``keys`` (all of one dimension d)."""
        keys = np.asarray(keys, dtype=np.int64).reshape(-1)
        if self._gtsam is not None:
            covs = [self.marginalCovariance(k) for k in keys.tolist()]
            if len({c.shape for c in covs}) > 1:
                raise InputError("covariances: the keys' variables have different dimensions; ask for one "
                                 "dimension at a time (or use marginalCovariance)")
            return np.array(covs) if covs else np.zeros((0, 0, 0))
        vs = np.array([self._variable(k) for k in keys.tolist()], dtype=np.int64)
        dims = np.unique(self._dims[vs])
        if len(dims) > 1:
            raise InputError(f"covariances: the keys' variables have dimensions {dims.tolist()}; ask for "
                             "one dimension at a time (or use marginalCovariance)")
        if not len(vs):
            return np.zeros((0, 0, 0))
        return self._blocks[int(dims[0])][self._place[vs]]
