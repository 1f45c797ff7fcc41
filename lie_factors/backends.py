"""The backends of a pose-graph run: where the factor classes come from and which LM runs them.

``native``: GTSAM's own BetweenFactor/PriorFactor in GTSAM's LM (the reference);
``dropin``: :mod:`lie_factors.factors` in the drop-in of GTSAM's LM,
:class:`lie_factors.optimizers.LevenbergMarquardtOptimizer` (GTSAM's algorithm driven
from Python, GTSAM linearizing and eliminating; ``custom``, its former name, is
still accepted); ``batch``: the same factors in the vectorized solver
(:mod:`lie_factors.batch`).  The CLI's ``--backend`` choices come from :data:`BACKENDS`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import gtsam

from .errors import InputError, first_line
from .lm import IterationInfo, OptimizeResult, default_optimize
from .util.stack import large_stack
from .util.timing import Stopwatch, warm_up_factors
from .posegraph.graph import PoseGraph


def _native_factors():
    return gtsam


def _our_factors():
    # Imported here, not at module top, so that `native` works without it.
    from lie_factors import factors

    return factors


@dataclass(frozen=True)
class Backend:
    """``factors()`` returns an object with GTSAM-named constructors
    (BetweenFactorPose2/3, PriorFactorPose2/3); ``optimize`` runs LM on the graph."""

    factors: Callable[[], object]
    optimize: Callable[..., "OptimizeResult"] = None  # type: ignore[assignment]
    description: str = ""


#: Add a backend here (e.g. "batch") — the CLI's --backend choices come from this table.
BACKENDS: dict[str, Backend] = {}

#: Former names of backends, still accepted: name → backend.
ALIASES = {"custom": "dropin"}


def backend_name(name: str) -> str:
    """The backend ``name`` stands for (itself, or what its former name is now); clear error if none."""
    name = ALIASES.get(name, name)
    if name not in BACKENDS:
        raise InputError(f"unknown backend {name!r} (choose from {', '.join(BACKENDS)})")
    return name


def get_backend(name: str) -> Backend:
    return BACKENDS[backend_name(name)]


def load_factors(backend: str):
    """The factor-constructor namespace for ``backend``; clear error if unavailable."""
    b = get_backend(backend)
    try:
        return b.factors()
    except ImportError as exc:
        raise InputError(f"backend {backend!r} is not available: {exc}") from None


def build_graph(ds: PoseGraph, backend: str, robust=None, robust_all: bool = False) -> gtsam.NonlinearFactorGraph:
    """The graph a run optimizes, built with ``backend``'s factor classes: the file's edges, the
    prior on the first pose (:meth:`PoseGraph.with_first_prior`), then the landmark measurements (GTSAM's
    own factors in every backend).

    With ``robust`` (a :class:`lie_factors.robust.losses.RobustLoss`) the loop closures' noise
    models — every edge's with ``robust_all`` — become ``noiseModel.Robust(loss, Gaussian)``
    (:meth:`lie_factors.posegraph.graph.PoseGraph.factor_graph`).  Edge k of the file is factor k.
    """
    return ds.with_first_prior().factor_graph(load_factors(backend), None if robust is None else robust.to_gtsam(),
                                              robust_all)


# --------------------------------------------------------------------------- #
# Optimization, one iteration at a time
# --------------------------------------------------------------------------- #

@large_stack  # GTSAM's elimination recurses once per level: a long chain needs more than 8 MiB
def optimize(
    graph: gtsam.NonlinearFactorGraph,
    initial: gtsam.Values,
    max_iterations: int = 100,
    progress: Callable[[IterationInfo], None] | None = None,
    params: gtsam.LevenbergMarquardtParams | None = None,
    optimizer: type | None = None,
) -> OptimizeResult:
    """Levenberg–Marquardt, stepped from Python exactly like ``optimizer.optimize()``.

    ``optimizer``: ``gtsam.LevenbergMarquardtOptimizer`` (default) or a drop-in
    with its interface (``lie_factors.optimizers.LevenbergMarquardtOptimizer``).

    GTSAM's ``NonlinearOptimizer::defaultOptimize``
    (:func:`lie_factors.lm.default_optimize`), reporting each iteration to
    ``progress``.  ``seconds`` covers building the optimizer (it evaluates the
    initial error) and the iterations, never numba compilation (kernels are
    warmed first; see :mod:`lie_factors.util.timing`).
    """
    if params is None:
        params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(max_iterations)
    warm_up_factors()  # compile before the clock starts
    clock = Stopwatch()
    try:
        opt = (optimizer or gtsam.LevenbergMarquardtOptimizer)(graph, initial, params)
        initial_error = float(opt.error())
        if not math.isfinite(initial_error):
            raise InputError(f"the initial error is {initial_error}: some residual overflows "
                                 f"(coordinates or information values too large?)")
        result = default_optimize(opt, params, progress)
        result.values = opt.values()
    except RuntimeError as exc:
        # e.g. IndeterminantLinearSystemException: report it, don't dump a traceback.
        raise InputError(f"optimization failed: {first_line(exc)}") from None
    result.seconds = clock.seconds()
    return result


def _optimize_dropin(graph, initial, max_iterations=100, progress=None, params=None) -> OptimizeResult:
    # GTSAM's LM run from Python on Values it holds: callbacks get that object, not a copy each.
    from lie_factors.optimizers import LevenbergMarquardtOptimizer

    return optimize(graph, initial, max_iterations, progress, params, optimizer=LevenbergMarquardtOptimizer)


def _optimize_batch(graph, initial, max_iterations=100, progress=None, params=None) -> OptimizeResult:
    # Imported on use: lie_factors.batch compiles its loops, which native/dropin never need.
    from lie_factors.batch import run_batch

    return run_batch(graph, initial, max_iterations, progress, params)


def optimize_batch_robust(graph, initial, max_iterations=100, progress=None, params=None) -> OptimizeResult:
    # Robust noise models vectorized (Σ ρ, rows reweighted by √w) instead of linearized by GTSAM.
    from lie_factors.batch import run_batch
    from lie_factors.robust.weighted import WeightedLevenbergMarquardt

    return run_batch(graph, initial, max_iterations, progress, params,
                     optimizer_class=WeightedLevenbergMarquardt)


BACKENDS.update(
    native=Backend(_native_factors, optimize, "GTSAM's own BetweenFactor/PriorFactor (reference)"),
    dropin=Backend(_our_factors, _optimize_dropin,
                   "lie_factors.factors (closed-form Jacobians) in lie_factors.optimizers' drop-in LM"),
    batch=Backend(_our_factors, _optimize_batch, "lie_factors factors, vectorized LM driven from Python"),
)
