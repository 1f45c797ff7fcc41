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
import numpy as np

from .errors import InputError, gtsam_failure, nonfinite_error
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


def gtsam_optimizer(backend: str, params=None) -> type:
    """The optimizer class ``native`` and ``dropin`` step for ``params`` (Levenberg–Marquardt's,
    Gauss–Newton's or dogleg's): GTSAM's own, or its drop-in."""
    name = ("GaussNewtonOptimizer" if isinstance(params, gtsam.GaussNewtonParams) else
            "DoglegOptimizer" if isinstance(params, gtsam.DoglegParams) else "LevenbergMarquardtOptimizer")
    if backend == "native":
        return getattr(gtsam, name)
    from . import optimizers

    return getattr(optimizers, name)


@large_stack  # GTSAM's elimination recurses once per level: a long chain needs more than 8 MiB
def step_optimizer(graph: gtsam.NonlinearFactorGraph, initial: gtsam.Values, params, optimizer: type,
                   progress: Callable[[IterationInfo], None] | None = None) -> OptimizeResult:
    """``optimizer(graph, initial, params)`` stepped from Python exactly as its ``optimize()``
    (GTSAM's ``defaultOptimize``, :func:`lie_factors.lm.default_optimize`), each iteration reported
    to ``progress``. ``seconds``: building the optimizer (it evaluates the initial error) and the
    iterations, never numba compilation.  An error that is not a finite number, at the start or
    after an iteration, raises :class:`InputError` naming the factor."""
    warm_up_factors()  # compile before the clock starts
    clock = Stopwatch()
    try:
        opt = optimizer(graph, initial, params)
        if not math.isfinite(float(opt.error())):
            raise _nonfinite(graph, initial, "at the initial values")

        def checked(info: IterationInfo) -> None:
            if not math.isfinite(info.error):  # GTSAM's Gauss-Newton steps to it and goes on
                raise _nonfinite(graph, opt.values(), f"after iteration {info.iteration}")
            if progress is not None:
                progress(info)

        result = default_optimize(opt, params, checked)
        result.values = opt.values()
    except RuntimeError as exc:
        raise gtsam_failure(exc) from None
    result.seconds = clock.seconds()
    return result


def _nonfinite(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, when: str) -> InputError:
    """The refusal of a graph error that is not a finite number, naming the factor (GTSAM's errors)."""
    from .batch.graph import describe_factor

    errors = np.array([0.0 if graph.at(k) is None else float(graph.at(k).error(values)) for k in range(graph.size())])
    return nonfinite_error(when, errors, lambda k: describe_factor(graph, k))


def optimize_with(backend: str, graph: gtsam.NonlinearFactorGraph, initial: gtsam.Values, params,
                  progress: Callable[[IterationInfo], None] | None = None, robust: bool = False) -> OptimizeResult:
    """``backend``'s optimizer on ``graph`` (built with :func:`build_graph`) from ``initial``.

    ``batch`` runs the vectorized solver (with ``robust``, the robust noise models evaluated and
    reweighted in its loops: :class:`lie_factors.robust.weighted.WeightedLevenbergMarquardt`);
    ``seconds``: its construction and iterations, numba compilation excluded.
    """
    if backend != "batch":
        return step_optimizer(graph, initial, params, gtsam_optimizer(backend, params), progress)
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
