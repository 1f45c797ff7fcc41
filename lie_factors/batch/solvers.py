"""Linear-solver backends for the damped normal equations of :mod:`lie_factors.batch.system`.

* ``"cholmod"`` (default): CHOLMOD's sparse Cholesky through cvxopt
  (its wheels bundle CHOLMOD and OpenBLAS).  The symbolic analysis —
  fill-reducing ordering (AMD), elimination tree, supernodes — is done once
  per graph; every λ and every linearization is a numeric refactorization of
  the same pattern plus two triangular solves.
* ``"gtsam"``: GTSAM's own multifrontal elimination of the whitened factor
  rows plus GTSAM's λ-priors (``GaussianFactorGraph.optimize``), as GTSAM's LM
  does it: the cross-check, and the fallback where cvxopt is not installed.

Both raise :class:`NotPositiveDefinite` when the system cannot be factored.
"""

from __future__ import annotations

import warnings

import gtsam
import numpy as np

from .. import stack
from .cholmod import available as cholmod_available
from .graph import BatchError

LINEAR_SOLVERS = ("auto", "cholmod", "pardiso", "gtsam")


class NotPositiveDefinite(BatchError):
    """The (damped) normal equations are not positive definite (GTSAM: IndeterminantLinearSystem)."""


_fallback_warned = False


def resolve(name: str) -> str:
    """``"auto"`` → ``"cholmod"`` if cvxopt imports, else ``"gtsam"`` (with one warning per process)."""
    global _fallback_warned
    if name not in LINEAR_SOLVERS:
        raise ValueError(f"linear_solver must be one of {', '.join(LINEAR_SOLVERS)}, got {name!r}")
    if name == "cholmod" and not cholmod_available():
        raise BatchError("linear_solver='cholmod' needs cvxopt (pip install cvxopt)")
    if name == "pardiso":
        try:
            import pypardiso  # noqa: F401
        except ImportError:
            raise BatchError("linear_solver='pardiso' needs pypardiso (pip install pypardiso)") from None
    if name != "auto":
        return name
    if cholmod_available():
        return "cholmod"
    if not _fallback_warned:
        warnings.warn("lie_factors.batch: cvxopt (CHOLMOD) is not installed; solving with GTSAM's "
                      "elimination, which is slower (pip install cvxopt)", RuntimeWarning, stacklevel=3)
        _fallback_warned = True
    return "gtsam"


def make(name: str, system):
    return {"cholmod": CholmodSolver, "pardiso": PardisoSolver, "gtsam": GtsamSolver}[resolve(name)](system)


class CholmodSolver:
    """Sparse Cholesky of ``system``'s pattern; symbolic analysis once, numeric per solve."""

    name = "cholmod"

    def __init__(self, system):
        from cvxopt import cholmod, matrix, spmatrix

        self._cholmod = cholmod
        self.system = system
        p = system.pattern
        n = p.n
        cols = p.colind()
        # cvxopt stores the values in (column, row) order: ours already is, checked below.
        self._V = matrix(np.ones(p.nnz))
        self._S = spmatrix(self._V, matrix(p.rowind), matrix(cols), (n, n))
        I, J, _ = self._S.CCS
        if not (np.array_equal(np.asarray(I).ravel(), p.colptr)
                and np.array_equal(np.asarray(J).ravel(), p.rowind)):
            raise AssertionError("cvxopt reordered the sparsity pattern")
        self.values = np.asarray(self._V).reshape(-1)  # numba writes the damped H here
        self._B = matrix(np.zeros(n))
        self._b = np.asarray(self._B).reshape(-1)
        self._Dinv = matrix(np.zeros(n))
        self._dinv = np.asarray(self._Dinv).reshape(-1)
        self._F = _symbolic(cholmod, self._S)

    def solve(self, scale: np.ndarray | None) -> np.ndarray:
        """δ solving (H + diag(scale)) δ = g."""
        sys_ = self.system
        sys_.damped(scale, self.values)
        self._S.V = self._V
        try:
            self._cholmod.numeric(self._S, self._F)
        except ArithmeticError as exc:
            raise NotPositiveDefinite(f"the linear system is not positive definite "
                                      f"(CHOLMOD stopped at pivot {first_arg(exc)})") from None
        # A simplicial factor is LDLᵀ, and CHOLMOD stops there only at a zero pivot:
        # H is positive definite iff every d > 0 (for a supernodal LLᵀ, D = I).
        self._dinv[:] = 1.0
        self._cholmod.solve(self._F, self._Dinv, sys=6)
        if not np.all(self._dinv > 0.0) or not np.all(np.isfinite(self._dinv)):
            bad = int(np.nonzero(~(self._dinv > 0.0) | ~np.isfinite(self._dinv))[0][0])
            raise NotPositiveDefinite(f"the linear system is not positive definite "
                                      f"(CHOLMOD's LDLᵀ has a non-positive pivot at {bad})")
        self._b[:] = sys_.rhs
        self._cholmod.solve(self._F, self._B)
        delta = self._b.copy()
        if not np.all(np.isfinite(delta)):
            raise NotPositiveDefinite("the linear system is singular (non-finite step)")
        return delta


class PardisoSolver:
    """MKL PARDISO (pypardiso, optional): symmetric positive definite, analysis once, numeric per solve.

    Measured against CHOLMOD inside the loop (docs/benchmarks.md); not the default
    (MKL is a ~300 MB dependency and was not faster here).
    """

    name = "pardiso"

    def __init__(self, system):
        import pypardiso
        import scipy.sparse as sp

        self.system = system
        p = system.pattern
        n = p.n
        cols = p.colind()
        # PARDISO wants the upper triangle in CSR = our lower CSC without the diagonal blocks' upper halves.
        self._keep = np.nonzero(p.rowind >= cols)[0]
        indptr = np.zeros(n + 1, dtype=np.int64)
        np.cumsum(np.bincount(cols[self._keep], minlength=n), out=indptr[1:])
        self._U = sp.csr_matrix((np.ones(len(self._keep)), p.rowind[self._keep], indptr), shape=(n, n))
        self.values = np.empty(p.nnz)
        self._ps = pypardiso.PyPardisoSolver(mtype=2)
        self._ps._check_A(self._U)
        self._ps.set_phase(11)
        self._ps._call_pardiso(self._U, np.zeros(n))

    def solve(self, scale: np.ndarray | None) -> np.ndarray:
        import pypardiso

        sys_ = self.system
        sys_.damped(scale, self.values)
        self._U.data[:] = self.values[self._keep]
        try:
            self._ps.set_phase(22)
            self._ps._call_pardiso(self._U, sys_.rhs)
            self._ps.set_phase(33)
            delta = self._ps._call_pardiso(self._U, np.asfortranarray(sys_.rhs))
        except pypardiso.pardiso_wrapper.PyPardisoError as exc:
            raise NotPositiveDefinite(f"the linear system is not positive definite (PARDISO: {exc})") from None
        if not np.all(np.isfinite(delta)):
            raise NotPositiveDefinite("the linear system is singular (non-finite step)")
        return delta


def _symbolic(cholmod, S):
    """CHOLMOD's symbolic analysis with its own simplicial/supernodal choice.

    cvxopt asks for a supernodal factor by default; CHOLMOD's automatic choice
    (by flops per nonzero of L) takes a simplicial LDLᵀ for near-chain graphs,
    which factors 2× faster there (kitti_00: 3.5 ms instead of 7.3 ms per
    numeric factorization) and is the same on 3-D graphs with loop closures.
    (:meth:`CholmodSolver.solve` checks D's signs: CHOLMOD's LDLᵀ does not
    stop at a negative pivot.)  cvxopt's options are a module-level dict:
    restored afterwards.
    """
    saved = dict(cholmod.options)
    cholmod.options["supernodal"] = 1
    try:
        return cholmod.symbolic(S, uplo="L")
    finally:
        cholmod.options.clear()
        cholmod.options.update(saved)


def first_arg(exc) -> str:
    return str(exc.args[0]) if exc.args else "?"


class GtsamSolver:
    """GTSAM elimination of the whitened factors + λ-priors (``GaussianFactorGraph.optimize``)."""

    name = "gtsam"

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

    def _ordering_for(self, gfg):
        if self._ordering is None:
            self._ordering = gtsam.Ordering.Colamd(gtsam.VariableIndex(gfg))
        return self._ordering

    def solve(self, scale: np.ndarray | None) -> np.ndarray:
        P = self.problem
        token = getattr(P, "linearization", None)
        if self._base_for is not token or token is None:
            self._graph = self._base()
            self._base_for = token
        gfg = gtsam.GaussianFactorGraph()
        gfg.push_back(self._graph)
        if scale is not None:
            # GTSAM's damping: a prior √scale·I on every variable (rows, not normal equations).
            for v, k in enumerate(P.var_keys):
                o, d = int(P.var_offsets[v]), int(P.var_dims[v])
                gfg.add(k, np.diag(np.sqrt(scale[o:o + d])), np.zeros(d), self._units[d])
        try:
            vv = stack.call(gfg.optimize, self._ordering_for(gfg))  # recursive elimination
        except RuntimeError as exc:
            raise NotPositiveDefinite(f"the linear system is not positive definite "
                                      f"(GTSAM: {str(exc).strip().splitlines()[0][:120]})") from None
        delta = np.empty(P.total_dim)
        for v, k in enumerate(P.var_keys):
            o, d = int(P.var_offsets[v]), int(P.var_dims[v])
            delta[o:o + d] = vv.at(k)
        if not np.all(np.isfinite(delta)):
            raise NotPositiveDefinite("the linear system is singular (non-finite step)")
        return delta
