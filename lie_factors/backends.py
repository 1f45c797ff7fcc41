"""The backends: where the factor classes come from and which optimizer runs them.

``batch``: :mod:`lie_factors.factors` in the vectorized solver (:mod:`lie_factors.batch`);
``dropin``: the same factors in the drop-in of GTSAM's Levenberg–Marquardt,
:class:`lie_factors.optimizers.LevenbergMarquardtOptimizer` (GTSAM's algorithm driven from
Python, GTSAM linearizing and eliminating); ``native``: GTSAM's own BetweenFactor and
PriorFactor in GTSAM's optimizer, the reference.
"""

from __future__ import annotations

import math
from typing import Callable

import gtsam

from .errors import InputError, gtsam_failure
from .lm import IterationInfo, OptimizeResult, default_optimize
from .posegraph.graph import PoseGraph
from .util.stack import large_stack
from .util.timing import Stopwatch, warm_up_factors

__all__ = ["BACKENDS", "DEFAULT_BACKEND", "factor_namespace", "build_graph", "gtsam_optimizer",
           "step_optimizer", "optimize_with"]

#: The backends, the default first.
BACKENDS = ("batch", "dropin", "native")
DEFAULT_BACKEND = BACKENDS[0]


def factor_namespace(backend: str):
    """The module whose ``BetweenFactorPose3``, ``PriorFactorPose2``, … ``backend`` builds graphs
    with: ``gtsam`` for native, :mod:`lie_factors.factors` otherwise."""
    if backend not in BACKENDS:
        raise InputError(f"unknown backend {backend!r} (choose from {', '.join(BACKENDS)})")
    if backend == "native":
        return gtsam
    try:
        from . import factors
    except ImportError as exc:
        raise InputError(f"backend {backend!r} is not available: {exc}") from None
    return factors


def build_graph(pg: PoseGraph, backend: str, robust=None, robust_all: bool = False) -> gtsam.NonlinearFactorGraph:
    """The graph a run optimizes, built with ``backend``'s factor classes: the edges, the priors
    (the first pose's where there is none: :meth:`PoseGraph.with_first_prior`), then the landmark
    measurements (GTSAM's own factors in every backend). Edge k is factor k.

    With ``robust`` (a :class:`lie_factors.robust.losses.RobustLoss`) the loop closures' noise
    models, every edge's with ``robust_all``, become ``noiseModel.Robust(loss, Gaussian)``.
    """
    return pg.with_first_prior().factor_graph(factor_namespace(backend), None if robust is None else robust.to_gtsam(),
                                              robust_all)


def gtsam_optimizer(backend: str, gauss_newton: bool = False) -> type:
    """The optimizer class ``native`` and ``dropin`` step: GTSAM's own, or its drop-in."""
    if backend == "native":
        return gtsam.GaussNewtonOptimizer if gauss_newton else gtsam.LevenbergMarquardtOptimizer
    from .optimizers import GaussNewtonOptimizer, LevenbergMarquardtOptimizer

    return GaussNewtonOptimizer if gauss_newton else LevenbergMarquardtOptimizer


@large_stack  # GTSAM's elimination recurses once per level: a long chain needs more than 8 MiB
def step_optimizer(graph: gtsam.NonlinearFactorGraph, initial: gtsam.Values, params, optimizer: type,
                   progress: Callable[[IterationInfo], None] | None = None) -> OptimizeResult:
    """``optimizer(graph, initial, params)`` stepped from Python exactly as its ``optimize()``
    (GTSAM's ``defaultOptimize``, :func:`lie_factors.lm.default_optimize`), each iteration reported
    to ``progress``. ``seconds``: building the optimizer (it evaluates the initial error) and the
    iterations, never numba compilation."""
    warm_up_factors()  # compile before the clock starts
    clock = Stopwatch()
    try:
        opt = optimizer(graph, initial, params)
        initial_error = float(opt.error())
        if not math.isfinite(initial_error):
            raise InputError(f"the initial error is {initial_error}: some residual overflows "
                             "(coordinates or information values too large?)")
        result = default_optimize(opt, params, progress)
        result.values = opt.values()
    except RuntimeError as exc:
        raise gtsam_failure(exc) from None
    result.seconds = clock.seconds()
    return result


def optimize_with(backend: str, graph: gtsam.NonlinearFactorGraph, initial: gtsam.Values, params,
                  progress: Callable[[IterationInfo], None] | None = None, robust: bool = False) -> OptimizeResult:
    """``backend``'s optimizer on ``graph`` (built with :func:`build_graph`) from ``initial``.

    ``batch`` runs the vectorized solver (with ``robust``, the robust noise models evaluated and
    reweighted in its loops: :class:`lie_factors.robust.weighted.WeightedLevenbergMarquardt`);
    ``seconds``: its construction and iterations, numba compilation excluded.
    """
    gauss_newton = isinstance(params, gtsam.GaussNewtonParams)
    if backend != "batch":
        return step_optimizer(graph, initial, params, gtsam_optimizer(backend, gauss_newton), progress)
    if robust:
        from .robust.weighted import WeightedLevenbergMarquardt as Optimizer
    else:
        from .batch.optimizer import BatchLevenbergMarquardt as Optimizer
    clock = Stopwatch()
    try:
        result = Optimizer(graph, initial, params).optimize(progress)
    except RuntimeError as exc:
        raise gtsam_failure(exc) from None
    result.seconds = clock.seconds()
    return result
