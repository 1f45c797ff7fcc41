"""Linear-solver backends for the damped normal equations of :mod:`lie_factors.batch.system`.

* ``"cholmod"`` (default): CHOLMOD's sparse Cholesky
  (:mod:`lie_factors.sparse.cholmod`; cvxopt's wheels bundle CHOLMOD and OpenBLAS).
  The fill-reducing order of the variables (AMD on the block graph) and the
  symbolic analysis — elimination tree, supernodes — are done once per graph;
  every λ and every linearization is a numeric refactorization of the same
  pattern, in place, plus two triangular solves.
* ``"gtsam"``: GTSAM's own multifrontal elimination of the whitened factor
  rows plus GTSAM's λ-priors (``GaussianFactorGraph.optimize``), as GTSAM's LM
  does it: the cross-check, and the fallback where cvxopt is not installed.

Each raises :class:`NotPositiveDefinite` when the system cannot be factored (CHOLMOD's: where a
pivot is refused by :mod:`lie_factors.sparse.pivots`' rule, at the tolerance it is given).

Hard constraints: CHOLMOD and PARDISO factor the system with its pinned variables held
(:meth:`lie_factors.batch.system.LinearSystem.holding`); a constrained factor that pins no
variable (a few of its rows constrained, or rows on several variables) is eliminated by
GTSAM's QR, as GTSAM's optimizers do, so ``"auto"`` chooses ``"gtsam"`` for such a graph
and ``"cholmod"`` or ``"pardiso"`` refuse it.
"""

from __future__ import annotations

import time
import warnings

import gtsam
import numpy as np

from ..util import stack

from ..sparse.cholmod import Cholesky
from ..sparse.cholmod import available as cholmod_available
from ..sparse.pivots import PIVOT_TOLERANCE
from ..errors import InputError, NotPositiveDefinite, first_line

LINEAR_SOLVERS = ("auto", "cholmod", "pardiso", "gtsam")


_fallback_warned = False


def resolve(name: str) -> str:
    """``"auto"`` → ``"cholmod"`` if cvxopt imports, else ``"gtsam"`` (with one warning per process)."""
    global _fallback_warned
    if name not in LINEAR_SOLVERS:
        raise InputError(f"linear_solver must be one of {', '.join(LINEAR_SOLVERS)}, got {name!r}")
    if name == "cholmod" and not cholmod_available():
        raise InputError("linear_solver='cholmod' needs cvxopt (pip install cvxopt)")
    if name == "pardiso":
        _pypardiso()
    if name != "auto":
        return name
    if cholmod_available():
        return "cholmod"
    if not _fallback_warned:
        warnings.warn("lie_factors.batch: cvxopt (CHOLMOD) is not installed; solving with GTSAM's "
                      "elimination, which is slower (pip install cvxopt)", RuntimeWarning, stacklevel=3)
        _fallback_warned = True
    return "gtsam"


def _pypardiso():
    """The optional pypardiso module, or the one-line error naming it."""
    try:
        import pypardiso
    except ImportError:
        raise InputError("linear_solver='pardiso' needs pypardiso (pip install pypardiso, "
                         "or the extra: pip install -e \".[pardiso]\")") from None
    return pypardiso


def make(name: str, system, pivot_tolerance: float = PIVOT_TOLERANCE):
    """The linear solver ``name`` (:data:`LINEAR_SOLVERS`) of ``system``; ``pivot_tolerance``: the
    pivot rule of CHOLMOD's factorizations (:mod:`lie_factors.sparse.pivots`; GTSAM's elimination
    and PARDISO keep their own)."""
    general = system.problem.general_constraints
    if general and name != "gtsam":
        if name != "auto":
            i = general[0]
            f = system.problem.graph.at(i)
            raise InputError(f"linear_solver={name!r}: factor {i} ({type(f).__name__}) is a hard constraint "
                             "(noiseModel.Constrained) on part of a variable or on several, which only "
                             "GTSAM's elimination imposes: use linear_solver='gtsam' (or 'auto')")
        name = "gtsam"
    kind = resolve(name)
    if kind == "cholmod":
        return CholmodSolver(system, pivot_tolerance)
    return {"pardiso": PardisoSolver, "gtsam": GtsamSolver}[kind](system)


class CholmodSolver:
    """Sparse Cholesky of ``system``'s pattern (:class:`lie_factors.sparse.cholmod.Cholesky`):
    symbolic analysis once, a numeric factorization of ``system.data`` in place per solve.

    ``pivot_tolerance``: a pivot not above this fraction of its diagonal entry is refused
    (:mod:`lie_factors.sparse.pivots`: 1e-13, the one rule for a system that must be
    determined; 0, the sign rule, for Levenberg–Marquardt's damped systems)."""

    name = "cholmod"
    needs_jacobians = False  # it factors H
    solve_seconds = 0.0  # the triangular solves' share of the solve calls

    def __init__(self, system, pivot_tolerance: float = PIVOT_TOLERANCE):
        p = system.pattern
        self.system = system
        self.pivot_tolerance = float(pivot_tolerance)
        self.factor = Cholesky(p.colptr, p.rowind, natural=True)

    def solve(self, scale: np.ndarray | None) -> np.ndarray:
        """δ solving (H + diag(scale)) δ = g."""
        sys_ = self.system
        data, rhs = sys_.damp(scale), sys_.in_matrix_order(sys_.rhs)
        with sys_.holding(data, rhs):
            self.factor.factorize(data, self.pivot_tolerance)  # NotPositiveDefinite: the column
        t = time.perf_counter()
        delta = sys_.from_matrix_order(self.factor.solve(rhs))
        self.solve_seconds += time.perf_counter() - t
        if not np.all(np.isfinite(delta)):
            raise NotPositiveDefinite("the linear system is singular (non-finite step)")
        return delta


class PardisoSolver:
    """MKL PARDISO (pypardiso, optional): symmetric positive definite, analysis once, numeric per solve.

    Not the default: MKL is a large dependency, and it is not faster than CHOLMOD inside
    the loop (docs/benchmarks.md).
    """

    name = "pardiso"
    needs_jacobians = False  # it factors H
    solve_seconds = 0.0  # not told apart: PARDISO's phases run in one call each

    def __init__(self, system):
        import scipy.sparse as sp

        pypardiso = _pypardiso()

        self.system = system
        p = system.pattern
        n = p.n
        # PARDISO wants the upper triangle in CSR: the lower triangle in CSC, transposed.
        lower = sp.csc_matrix((np.arange(p.nnz, dtype=np.float64), p.rowind, p.colptr), shape=(n, n))
        upper = lower.T.tocsr()
        upper.sort_indices()
        self._take = upper.data.astype(np.int64)  # entry k of the CSR is data[take[k]]
        self._U = upper
        self._ps = pypardiso.PyPardisoSolver(mtype=2)
        self._ps._check_A(self._U)
        self._ps.set_phase(11)
        self._ps._call_pardiso(self._U, np.zeros(n))

    def solve(self, scale: np.ndarray | None) -> np.ndarray:
        pypardiso = _pypardiso()
        sys_ = self.system
        data, rhs = sys_.damp(scale), sys_.in_matrix_order(sys_.rhs)
        with sys_.holding(data, rhs):
            self._U.data[:] = data[self._take]
        try:
            self._ps.set_phase(22)
            self._ps._call_pardiso(self._U, rhs)
            self._ps.set_phase(33)
            x = self._ps._call_pardiso(self._U, np.asfortranarray(rhs))
        except pypardiso.pardiso_wrapper.PyPardisoError as exc:
            raise NotPositiveDefinite(f"the linear system is not positive definite (PARDISO: {exc})") from None
        delta = sys_.from_matrix_order(x)
        if not np.all(np.isfinite(delta)):
            raise NotPositiveDefinite("the linear system is singular (non-finite step)")
        return delta


class GtsamSolver:
    """GTSAM elimination of the whitened factors + λ-priors (``GaussianFactorGraph.optimize``)."""

    name = "gtsam"
    needs_jacobians = True  # it eliminates the whitened factors
    solve_seconds = 0.0  # elimination and back-substitution are one call

    def __init__(self, system):
        self.system = system
        P = system.problem
        self.problem = P
        self._units = {d: gtsam.noiseModel.Unit.Create(int(d)) for d in set(P.var_dims.tolist())}
        self._ordering = None
        self._base_for = None

    def _base(self):
        """Undamped GaussianFactorGraph of the current linearization (built once per linearization)."""
        P = self.problem
        w = self.system.weights
        gfg = gtsam.GaussianFactorGraph()
        add = gfg.add
        keys = P.var_keys
        for g in P.groups:
            unit = self._units[g.spec.dim]
            sw = np.sqrt(w[g.fidx])
            k1 = [keys[v] for v in g.v1]
            if g.kind == "between":
                k2 = [keys[v] for v in g.v2]
                for f in range(g.E):
                    if sw[f] > 0:
                        add(k1[f], sw[f] * g.A1[f], k2[f], sw[f] * g.A2[f], sw[f] * g.b[f], unit)
            else:
                for f in range(g.E):
                    if sw[f] > 0:
                        add(k1[f], sw[f] * g.A1[f], sw[f] * g.b[f], unit)
        for kg in P.kinds:
            self._add_kind(gfg, kg, np.sqrt(w[kg.fidx]))
        if P.native_linear is not None:
            wn = w[P.native_arrays.fidx]
            for j in range(P.native_linear.size()):
                lf = P.native_linear.at(j)
                if wn[j] == 1.0:
                    gfg.push_back(lf)
                elif wn[j] > 0:
                    A, b = lf.jacobian()
                    s = np.sqrt(wn[j])
                    ks = [int(k) for k in lf.keys()]
                    blocks, c = [], 0
                    for k in ks:
                        d = int(P.var_dims[P.var_index[k]])
                        blocks.append((k, s * A[:, c:c + d]))
                        c += d
                    gfg.push_back(gtsam.JacobianFactor(blocks[0][0], blocks[0][1], *[x for kb in blocks[1:] for x in kb],
                                                       s * b, gtsam.noiseModel.Unit.Create(len(b))))
        return gfg

    def _add_kind(self, gfg, kg, sw: np.ndarray) -> None:
        """The rows of a kind's factors (:class:`~lie_factors.batch.kinds.KindGroup`), each
        weighted by ``sw``: one JacobianFactor on its variables' keys."""
        keys = self.problem.var_keys
        m = kg.kind.dim
        if len(kg.kind.variables) > 3:  # GTSAM's Python JacobianFactor takes at most three blocks
            raise InputError(f"the GTSAM linear solver takes factors of at most 3 variables; the kind "
                             f"{kg.kind.name} has {len(kg.kind.variables)}: use linear_solver='cholmod'")
        unit = gtsam.noiseModel.Unit.Create(m)
        var_keys = [[keys[v] for v in var] for var in kg.var]
        for f in range(kg.E):
            if sw[f] > 0:
                A = sw[f] * kg.A[f]
                blocks = [x for j, (o, end) in enumerate(kg.kind.blocks) for x in (var_keys[j][f], A[:, o:end])]
                gfg.push_back(gtsam.JacobianFactor(*blocks, sw[f] * kg.b[f], unit))

    def _ordering_for(self, gfg):
        if self._ordering is None:
            self._ordering = gtsam.Ordering.Colamd(gtsam.VariableIndex(gfg))
        return self._ordering

    def _linearization(self) -> gtsam.GaussianFactorGraph:
        """:meth:`_base` of the problem's current linearization (built once for it)."""
        token = getattr(self.problem, "linearization", None)
        if self._base_for is not token or token is None:
            self._graph = self._base()
            self._base_for = token
        return self._graph

    def dogleg_points(self):
        """GTSAM's ``DoglegOptimizer::iterate`` on the current linearization: its Bayes tree
        (multifrontal elimination of the undamped system), the steepest-descent point
        (``optimizeGradientSearch``) and the Gauss–Newton point (``optimize``) as δ vectors, and the
        Bayes tree, whose ``error`` is the dogleg's model (:meth:`model_error`)."""
        base = self._linearization()
        try:
            tree = stack.call(base.eliminateMultifrontal, self._ordering_for(base))
            dx_u, dx_n = tree.optimizeGradientSearch(), tree.optimize()
        except RuntimeError as exc:
            raise NotPositiveDefinite(f"the linear system is not positive definite "
                                      f"(GTSAM: {first_line(exc, 120)})") from None
        return self._vector(dx_u), self._vector(dx_n), tree

    def model_error(self, tree, delta: np.ndarray) -> float:
        """The error of ``tree`` (:meth:`dogleg_points`) at the step ``delta``."""
        P = self.problem
        vv = gtsam.VectorValues()
        for v, k in enumerate(P.var_keys):
            o, d = int(P.var_offsets[v]), int(P.var_dims[v])
            vv.insert(k, delta[o:o + d])
        return float(tree.error(vv))

    def _vector(self, vv) -> np.ndarray:
        P = self.problem
        delta = np.empty(P.total_dim)
        for v, k in enumerate(P.var_keys):
            o, d = int(P.var_offsets[v]), int(P.var_dims[v])
            delta[o:o + d] = vv.at(k)
        return delta

    def solve(self, scale: np.ndarray | None) -> np.ndarray:
        P = self.problem
        gfg = gtsam.GaussianFactorGraph()
        gfg.push_back(self._linearization())
        if scale is not None:
            # GTSAM's damping: a prior √scale·I on every variable (rows, not normal equations).
            for v, k in enumerate(P.var_keys):
                o, d = int(P.var_offsets[v]), int(P.var_dims[v])
                gfg.add(k, np.diag(np.sqrt(scale[o:o + d])), np.zeros(d), self._units[d])
        try:
            vv = stack.call(gfg.optimize, self._ordering_for(gfg))  # recursive elimination
        except RuntimeError as exc:
            raise NotPositiveDefinite(f"the linear system is not positive definite "
                                      f"(GTSAM: {first_line(exc, 120)})") from None
        delta = self._vector(vv)
        if not np.all(np.isfinite(delta)):
            raise NotPositiveDefinite("the linear system is singular (non-finite step)")
        return delta
