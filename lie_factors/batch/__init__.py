"""Batch Levenberg–Marquardt / Gauss–Newton / dogleg: the whole graph as arrays, normal equations, sparse Cholesky.

Why: GTSAM's Python ``CustomFactor`` converts the whole ``Values`` on every
callback from inside a C++ optimizer (many times slower than native GTSAM), and
GTSAM's elimination redoes its symbolic work every iteration.  Here

* :mod:`~lie_factors.batch.graph` reads the graph into arrays (lie_factors
  factors grouped by kind and group; every other factor is linearized by GTSAM)
  and linearizes/evaluates/retracts them with the numba loops of
  :mod:`~lie_factors.batch.loops` (the factors' own kernels);
* :mod:`~lie_factors.batch.system` assembles ``H = Σ w JᵀJ``, ``g = Σ w Jᵀb``
  into a block-sparse matrix whose pattern and scatter map are computed once;
* :mod:`~lie_factors.batch.solvers` factors ``H + damping`` with CHOLMOD
  (symbolic analysis once per graph; cvxopt) or GTSAM's elimination;
* :mod:`~lie_factors.batch.optimizer` runs GTSAM's LM / Gauss–Newton / dogleg loop;
* :mod:`~lie_factors.batch.marginals` gives the marginal covariances at a point from the
  same factorization (``gtsam.Marginals``' ``marginalCovariance``).

Usage::

    from lie_factors import batch
    result = batch.optimize(graph, initial)   # params=LevenbergMarquardtParams | GaussNewtonParams | DoglegParams
    result.values, result.iterations, result.errors, result.seconds, result.timings
"""

from ..util.lazy import exports

#: Public name → the submodule defining it.  Imported on first use (PEP 562), so that
#: importing one submodule (say ``lie_factors.robust.losses``) does not load every
#: other one, and ``import lie_factors.batch`` alone loads neither numba nor GTSAM.
_EXPORTS = {
    "Problem": "graph",
    "BatchLevenbergMarquardt": "optimizer", "OptimizeResult": "optimizer",
    "TIMING_KEYS": "optimizer", "optimize": "optimizer",
    "LINEAR_SOLVERS": "solvers", "cholmod_available": "solvers",
    "LinearSystem": "system",
    "Marginals": "marginals",
}

__all__ = sorted(_EXPORTS)


__getattr__, __dir__ = exports(__name__, _EXPORTS)
