"""Pose-graph optimization of g2o files with GTSAM, native or lie_factors factors.

Pipeline (each step a function, the CLI and the benchmark just chain them):

1. :func:`lie_factors.g2o.resolve_dataset` — a path, or the name of a file shipped with GTSAM
   (``sphere2500.txt``) found with ``gtsam.findExampleDataFile``.
2. :func:`lie_factors.g2o.check_g2o` — our own line-by-line check, so a bad file gives
   ``file:line: what was expected`` instead of GTSAM silently skipping lines
   (``readG2o`` drops every edge after a ``#`` comment, for instance).
3. :func:`load` — ``gtsam.readG2o(path, is3D)``; poses without a vertex line
   are initialized by composing measurements along a BFS spanning tree.
4. :func:`build_graph` — the between factors re-created with the chosen
   backend's constructors, plus a prior on the first pose.
5. :func:`lie_factors.initialize.initialize` — where LM starts: GTSAM's chordal
   relaxation (3-D) or LAGO (2-D) by default, the file's vertices on request.
6. :func:`optimize` — Levenberg–Marquardt driven one ``iterate()`` at a time
   from Python, with GTSAM's own stopping rule, reporting each iteration.

g2o formats (checking, reading, writing) live in :mod:`lie_factors.g2o`; result
types in :mod:`lie_factors.results`.
"""

from __future__ import annotations

import dataclasses
import math
import os
from dataclasses import dataclass
from typing import Callable

import numpy as np

import gtsam

from .errors import PoseGraphError
from .g2o import check_g2o, read_g2o, resolve_dataset
from .initialize import METHODS as INIT_METHODS
from .initialize import Initialization, InitializationError, initialize, spanning_tree_initial
from .results import IterationInfo, OptimizeResult
from .timing import Stopwatch, warm_up_factors


# --------------------------------------------------------------------------- #
# Loading
# --------------------------------------------------------------------------- #

@dataclass
class PoseGraph:
    """A checked g2o file read by GTSAM.

    ``between``: native GTSAM graph of BetweenFactorPose2/3 exactly as
    ``readG2o`` built it (no prior) — also what :func:`write_g2o` writes;
    ``initial``: Values with every pose; ``first_key``: smallest id, gets the prior;
    ``group``: GTSAM type of the poses, Pose2, Pose3 or Similarity3 (the latter
    read by :func:`lie_factors.g2o.read_sim3_g2o`; ``is3d`` is true for it).
    """

    path: str
    name: str
    is3d: bool
    between: gtsam.NonlinearFactorGraph
    initial: gtsam.Values
    first_key: int
    initialized_from_edges: bool
    group: str = ""

    def __post_init__(self):
        if not self.group:
            self.group = "Pose3" if self.is3d else "Pose2"

    @property
    def poses(self) -> int:
        return int(self.initial.size())

    @property
    def edges(self) -> int:
        return int(self.between.size())


def load(dataset: str) -> PoseGraph:
    """Resolve, check and read ``dataset``; raise :class:`PoseGraphError` if unusable."""
    path = resolve_dataset(dataset)
    summary = check_g2o(path)
    graph, initial = read_g2o(path, summary)
    if graph.size() != len(summary.edges):
        # Our checker and GTSAM's reader disagree: refuse rather than optimize half a file.
        raise PoseGraphError(
            f"{os.path.basename(path)}: gtsam.readG2o read {graph.size()} edges, "
            f"the file has {len(summary.edges)}"
        )
    from_edges = not summary.vertices
    if from_edges:
        # readG2o leaves 3-D edge-only files (sphere2500.txt) without Values; for
        # 2-D it chains odometry itself.  Do the same thing for both: a spanning tree.
        initial = spanning_tree_initial(graph, summary.is3d, summary.pose_ids[0],
                                        getattr(gtsam, summary.group)())
    return PoseGraph(
        path=path,
        name=os.path.basename(path),
        is3d=summary.is3d,
        between=graph,
        initial=initial,
        first_key=summary.pose_ids[0],
        initialized_from_edges=from_edges,
        group=summary.group,
    )


# --------------------------------------------------------------------------- #
# Backends: name → where the factor constructors come from
# --------------------------------------------------------------------------- #

def _native_factors():
    return gtsam


def _custom_factors():
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


def get_backend(name: str) -> Backend:
    try:
        return BACKENDS[name]
    except KeyError:
        raise PoseGraphError(
            f"unknown backend {name!r} (choose from {', '.join(BACKENDS)})"
        ) from None


def load_factors(backend: str):
    """The factor-constructor namespace for ``backend``; clear error if unavailable."""
    b = get_backend(backend)
    try:
        return b.factors()
    except ImportError as exc:
        raise PoseGraphError(f"backend {backend!r} is not available: {exc}") from None


def prior_noise(is3d: bool, group: str | None = None) -> gtsam.noiseModel.Base:
    """The prior GTSAM's Pose2/Pose3SLAMExample_g2o.py put on the first pose
    (Similarity3: Pose3's, and the log-scale as tight as the rotation)."""
    if group == "Similarity3":
        return gtsam.noiseModel.Diagonal.Variances(np.array([1e-6, 1e-6, 1e-6, 1e-4, 1e-4, 1e-4, 1e-6]))
    if is3d:
        return gtsam.noiseModel.Diagonal.Variances(np.array([1e-6, 1e-6, 1e-6, 1e-4, 1e-4, 1e-4]))
    return gtsam.noiseModel.Diagonal.Variances(np.array([1e-6, 1e-6, 1e-8]))


def build_graph(pg: PoseGraph, backend: str, robust=None,
                robust_all: bool = False) -> gtsam.NonlinearFactorGraph:
    """Graph of ``pg.edges`` between factors + 1 prior, built with ``backend``'s constructors.

    The prior pins the first pose at its initial value (identity for edge-only
    files), fixing the gauge.  With ``robust`` (a
    :class:`lie_factors.batch.robust.RobustLoss`) the loop closures' noise models —
    every edge's with ``robust_all`` — become ``noiseModel.Robust(loss,
    Gaussian)``.  Edge k of the file is factor k; the prior is the last factor.
    """
    F = load_factors(backend)
    Between = getattr(F, f"BetweenFactor{pg.group}")
    Prior = getattr(F, f"PriorFactor{pg.group}")
    mestimator = robust.to_gtsam() if robust is not None else None
    graph = gtsam.NonlinearFactorGraph()
    for k in range(pg.between.size()):
        f = pg.between.at(k)
        i, j = f.keys()
        noise = f.noiseModel()
        if mestimator is not None and (robust_all or abs(int(i) - int(j)) != 1):
            noise = gtsam.noiseModel.Robust.Create(mestimator, noise)
        graph.add(Between(i, j, f.measured(), noise))
    first = getattr(pg.initial, f"at{pg.group}")(pg.first_key)
    graph.add(Prior(pg.first_key, first, prior_noise(pg.is3d, pg.group)))
    return graph
# --------------------------------------------------------------------------- #
# Optimization, one iteration at a time
# --------------------------------------------------------------------------- #

def optimize(
    graph: gtsam.NonlinearFactorGraph,
    initial: gtsam.Values,
    max_iterations: int = 100,
    progress: Callable[[IterationInfo], None] | None = None,
    params: gtsam.LevenbergMarquardtParams | None = None,
) -> OptimizeResult:
    """Levenberg–Marquardt, stepped from Python exactly like ``optimizer.optimize()``.

    GTSAM's ``NonlinearOptimizer::defaultOptimize``: stop at once if the error
    is already ≤ errorTol; otherwise ``iterate()`` while iterations <
    maxIterations, ``checkConvergence(relTol, absTol, errorTol, current, new)``
    is false and the error is finite.  (``max_iterations=0`` runs none; GTSAM
    would still run one.)  ``seconds`` covers building the optimizer (it
    evaluates the initial error) and the iterations, never numba compilation
    (kernels are warmed first; see :mod:`lie_factors.timing`).
    """
    if params is None:
        params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(max_iterations)
    warm_up_factors()  # compile before the clock starts
    clock = Stopwatch()
    try:
        opt = gtsam.LevenbergMarquardtOptimizer(graph, initial, params)
        initial_error = new_error = float(opt.error())
        converged = new_error <= params.getErrorTol()
        history = []
        while not converged and opt.iterations() < max_iterations:
            current_error = new_error
            step = Stopwatch()
            opt.iterate()
            new_error = float(opt.error())
            info = IterationInfo(int(opt.iterations()), new_error, float(opt.lambda_()),
                                 step.seconds())
            history.append(info)
            if progress is not None:
                progress(info)
            converged = gtsam.checkConvergence(params, current_error, new_error)
            if not math.isfinite(current_error):
                break
        values = opt.values()
    except RuntimeError as exc:
        # e.g. IndeterminantLinearSystemException: report it, don't dump a traceback.
        raise PoseGraphError(f"optimization failed: {str(exc).strip().splitlines()[0]}") from None
    seconds = clock.seconds()
    return OptimizeResult(values, int(opt.iterations()), initial_error, new_error, seconds,
                          bool(converged), history)


def _optimize_batch(graph, initial, max_iterations=100, progress=None, params=None) -> OptimizeResult:
    # Imported on use: lie_factors.batch compiles its loops, which native/custom never need.
    from lie_factors.batch import run_batch

    return run_batch(graph, initial, max_iterations, progress, params)


def _optimize_batch_robust(graph, initial, max_iterations=100, progress=None, params=None) -> OptimizeResult:
    # Robust noise models vectorized (Σ ρ, rows reweighted by √w) instead of linearized by GTSAM.
    from lie_factors.batch import run_batch
    from lie_factors.batch.robust import WeightedLevenbergMarquardt

    return run_batch(graph, initial, max_iterations, progress, params,
                     optimizer_class=WeightedLevenbergMarquardt)


BACKENDS.update(
    native=Backend(_native_factors, optimize, "GTSAM's own BetweenFactor/PriorFactor (reference)"),
    custom=Backend(_custom_factors, optimize, "lie_factors.factors (closed-form Jacobians)"),
    batch=Backend(_custom_factors, _optimize_batch, "lie_factors factors, vectorized LM driven from Python"),
)


# --------------------------------------------------------------------------- #
# Results and output files
# --------------------------------------------------------------------------- #

@dataclass
class RunRecord:
    """What ``lie-factors posegraph --json`` prints (``to_dict``).

    ``factors`` counts the optimized graph: the file's edges + 1 prior;
    ``seconds`` is optimization only (LM construction + iterations, not loading
    and not initialization); ``init`` is the initialization method used
    (:data:`lie_factors.initialize.METHODS`) and ``init_seconds`` its cost;
    ``initial_error``/``final_error`` are GTSAM's 0.5·Σ‖whitened residual‖²
    (Σ ρ(‖whitened residual‖) for robust factors).  ``robust``: the loss
    (``name:k``, with ``+all`` if on every edge); ``gnc``: the GNC loss.  With
    GNC, ``iterations`` counts GNC's outer iterations, ``final_error`` is GNC's
    weighted cost Σ w_k·½‖R_k e_k‖², and ``outliers`` lists the rejected edges
    (0-based, in the file's edge order).
    """

    backend: str
    dataset: str
    dimension: int
    poses: int
    factors: int
    iterations: int
    initial_error: float
    final_error: float
    seconds: float
    converged: bool
    init: str = "file"
    init_seconds: float = 0.0
    robust: str | None = None
    gnc: str | None = None
    outliers: list[int] | None = None

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        # robust / gnc / outliers appear only in runs that use them.
        for key in ("robust", "gnc", "outliers"):
            if d[key] is None:
                del d[key]
        return d


def loop_closures(pg: PoseGraph) -> np.ndarray:
    """Indices of the file's edges whose pose ids are not consecutive (|id1 − id2| ≠ 1)."""
    return np.array([k for k in range(pg.between.size())
                     if abs(int(pg.between.at(k).keys()[0]) - int(pg.between.at(k).keys()[1])) != 1],
                    dtype=np.int64)


def run(
    dataset: str | PoseGraph,
    backend: str = "native",
    max_iterations: int = 100,
    progress: Callable[[IterationInfo], None] | None = None,
    init: str = "auto",
    on_init: Callable[[Initialization], None] | None = None,
    robust=None,
    robust_all: bool = False,
    gnc: str | None = None,
    gnc_progress: Callable | None = None,
) -> tuple[RunRecord, OptimizeResult, PoseGraph]:
    """Load (unless given a :class:`PoseGraph`), build with ``backend``, initialize, optimize.

    ``init``: a method of :func:`lie_factors.initialize.initialize`, run on the
    graph ``backend`` built (so every backend starts from the same values);
    ``file`` is the file's vertices.  ``on_init`` is called with the
    :class:`~lie_factors.initialize.Initialization` before LM starts.
    ``result.start`` holds the values LM started from.

    ``robust``: a :class:`lie_factors.batch.robust.RobustLoss` on the loop
    closures (all edges with ``robust_all``).  ``gnc``: "tls" or "gm" runs
    graduated non-convexity instead of plain LM (odometry edges and the prior
    are known inliers; ``max_iterations`` limits each inner LM;
    ``gnc_progress(it, λ, cost, lm_iterations)`` after each outer iteration).
    """
    pg = load(dataset) if isinstance(dataset, str) else dataset
    get_backend(backend)
    if gnc is not None and loop_closures(pg).size == 0:
        raise PoseGraphError(f"{pg.name}: --gnc needs loop closures (edges between non-consecutive "
                             "poses); this graph has none")
    graph = build_graph(pg, backend)
    start = initialize(graph, init, None if pg.initialized_from_edges else pg.initial)
    if on_init is not None:
        on_init(start)
    if gnc is not None:
        return _run_gnc(pg, graph, start, backend, max_iterations, gnc, gnc_progress)
    if robust is not None:
        graph = build_graph(pg, backend, robust, robust_all)
    opt = get_backend(backend).optimize or optimize
    if robust is not None and backend == "batch":
        opt = _optimize_batch_robust
    result = opt(graph, start.values, max_iterations=max_iterations, progress=progress)
    result.start = start.values
    record = RunRecord(
        backend=backend,
        dataset=pg.name,
        dimension=3 if pg.is3d else 2,
        poses=pg.poses,
        factors=int(graph.size()),
        iterations=result.iterations,
        initial_error=result.initial_error,
        final_error=result.final_error,
        seconds=result.seconds,
        converged=result.converged,
        init=start.method,
        init_seconds=start.seconds,
        robust=None if robust is None else str(robust) + ("+all" if robust_all else ""),
    )
    return record, result, pg


def _run_gnc(pg: PoseGraph, graph, start, backend: str, max_iterations: int, loss: str,
             gnc_progress: Callable | None) -> tuple[RunRecord, OptimizeResult, PoseGraph]:
    """GNC per backend: native = gtsam.GncLMOptimizer; custom = our outer loop over GTSAM's LM
    with lie_factors factors (GTSAM's GncOptimizer cannot clone CustomFactors); batch = our
    outer loop over the batch solver."""
    from lie_factors.batch import gnc as gncm

    closures = loop_closures(pg)
    known = np.setdiff1d(np.arange(graph.size()), closures)  # odometry + the prior
    lm = gtsam.LevenbergMarquardtParams()
    lm.setMaxIterations(int(max_iterations))
    params = gncm.GncParams(loss=loss, known_inliers=known.tolist(), lm_params=lm)
    try:
        if backend == "native":
            res = gncm.gtsam_gnc(graph, start.values, params)
        elif backend == "batch":
            res = gncm.gnc_optimize(gncm.BatchInner(graph, start.values, lm), params, gnc_progress)
        else:
            res = gncm.gnc_optimize(gncm.GtsamInner(graph, start.values, lm), params, gnc_progress)
    except RuntimeError as exc:
        raise PoseGraphError(f"optimization failed: {str(exc).strip().splitlines()[0]}") from None
    values = res.values
    if not isinstance(values, gtsam.Values):
        values = values.to_values()
    initial_error = float(graph.error(start.values))
    result = OptimizeResult(values, res.iterations, initial_error, res.cost, res.seconds,
                            res.stop != "maxIterations", [])
    result.start = start.values
    outliers = [int(k) for k in res.outliers if k < pg.between.size()]
    record = RunRecord(
        backend=backend,
        dataset=pg.name,
        dimension=3 if pg.is3d else 2,
        poses=pg.poses,
        factors=int(graph.size()),
        iterations=res.iterations,
        initial_error=initial_error,
        final_error=res.cost,
        seconds=res.seconds,
        converged=result.converged,
        gnc=loss,
        outliers=outliers,
        init=start.method,
        init_seconds=start.seconds,
    )
    return record, result, pg


def positions(values: gtsam.Values, is3d: bool, group: str | None = None) -> np.ndarray:
    """Translations of the poses in ``values`` in key order, shape (N, 3) (z = 0 in 2-D).

    Similarity3 (``group``): the image of the origin, s·t (GTSAM's action p ↦ s(Rp + t)).
    """
    keys = sorted(values.keys())
    if group == "Similarity3":
        origin = np.zeros(3)
        return np.array([values.atSimilarity3(k).transformFrom(origin) for k in keys]).reshape(-1, 3)
    if is3d:
        return np.array([values.atPose3(k).translation() for k in keys]).reshape(-1, 3)
    out = np.zeros((len(keys), 3))
    for n, k in enumerate(keys):
        p = values.atPose2(k)
        out[n, :2] = (p.x(), p.y())
    return out
