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
    ``readG2o`` built them (no prior); ``landmarks``: the landmark
    measurements (GTSAM's BearingRangeFactor2D/3D, pose key → landmark key
    ``symbol('l', j)``), used as they are by every backend; ``initial``:
    Values with every pose and landmark; ``first_key``: smallest pose id, gets
    the prior; ``group``: GTSAM type of the poses, Pose2, Pose3 or Similarity3
    (the latter read by :func:`lie_factors.g2o.read_g2o` from Sim(3) records;
    ``is3d`` is true for it).
    """

    path: str
    name: str
    is3d: bool
    between: gtsam.NonlinearFactorGraph
    initial: gtsam.Values
    first_key: int
    initialized_from_edges: bool
    landmarks: gtsam.NonlinearFactorGraph = dataclasses.field(default_factory=gtsam.NonlinearFactorGraph)
    landmark_vertex_keys: frozenset = frozenset()
    group: str = ""

    def __post_init__(self):
        if not self.group:
            self.group = "Pose3" if self.is3d else "Pose2"

    @property
    def poses(self) -> int:
        return len(pose_keys(self.initial))

    @property
    def landmark_count(self) -> int:
        return int(self.initial.size()) - self.poses

    @property
    def edges(self) -> int:
        return int(self.between.size())

    @property
    def observations(self) -> int:
        return int(self.landmarks.size())

    def native_graph(self) -> gtsam.NonlinearFactorGraph:
        """The file's factors as GTSAM built them (what :func:`lie_factors.g2o.write_g2o` writes)."""
        graph = gtsam.NonlinearFactorGraph(self.between)
        graph.push_back(self.landmarks)
        return graph


def is_landmark_key(key: int) -> bool:
    return gtsam.Symbol(int(key)).chr() != 0


def pose_keys(values: gtsam.Values) -> list[int]:
    """Sorted pose keys of ``values`` (plain ids; landmarks are ``symbol('l', j)``)."""
    return sorted(k for k in values.keys() if not is_landmark_key(k))


def landmark_keys(values: gtsam.Values) -> list[int]:
    return sorted(k for k in values.keys() if is_landmark_key(k))


def load(dataset: str) -> PoseGraph:
    """Resolve, check and read ``dataset``; raise :class:`PoseGraphError` if unusable."""
    path = resolve_dataset(dataset)
    summary = check_g2o(path)
    graph, initial = read_g2o(path, summary)
    between = gtsam.NonlinearFactorGraph()
    landmarks = gtsam.NonlinearFactorGraph()
    for k in range(graph.size()):
        f = graph.at(k)
        keys = f.keys()
        (landmarks if any(is_landmark_key(key) for key in keys) else between).add(f)
    pose_ids = summary.pose_ids
    from_edges = len(summary.pose_vertex_ids) == 0
    if from_edges:
        # readG2o leaves 3-D edge-only files (sphere2500.txt) without Values; for
        # 2-D it chains odometry itself.  Do the same thing for both: a spanning tree.
        poses = spanning_tree_initial(between, summary.is3d, pose_ids[0], getattr(gtsam, summary.group)())
        for key in landmark_keys(initial):
            if int(gtsam.Symbol(key).index()) in set(summary.landmark_vertex_ids.tolist()):
                poses.insert(key, initial.atPoint3(key) if summary.is3d else initial.atPoint2(key))
        initial = poses
    identity = getattr(gtsam, summary.group)()
    for i in pose_ids:
        if not initial.exists(i):
            # Seen only in landmark measurements: GTSAM's reader starts it at the identity too.
            initial.insert(i, identity)
    with_vertex = frozenset(gtsam.symbol("l", int(j)) for j in summary.landmark_vertex_ids.tolist())
    _initialize_landmarks(initial, landmarks, summary.is3d, with_vertex)
    return PoseGraph(
        path=path,
        name=os.path.basename(path),
        is3d=summary.is3d,
        between=between,
        initial=initial,
        first_key=pose_ids[0],
        initialized_from_edges=from_edges,
        landmarks=landmarks,
        landmark_vertex_keys=with_vertex,
        group=summary.group,
    )


def _initialize_landmarks(initial: gtsam.Values, landmarks: gtsam.NonlinearFactorGraph, is3d: bool,
                          with_vertex: frozenset) -> None:
    """Landmarks without a vertex line: placed by their first measurement from its pose (in place).

    (``readG2o`` does this for ``BR``/``LANDMARK`` from the pose it had at that
    line; we redo it from the current initial poses, and for ``LANDMARK2``.)
    3-D measurements always have landmark vertices (GTSAM requires them).
    """
    if is3d:
        return
    done = set()
    for k in range(landmarks.size()):
        f = landmarks.at(k)
        pose_key, point_key = f.keys()
        if point_key in with_vertex or point_key in done:
            continue
        br = f.measured()
        theta, r = br.bearing().theta(), br.range()
        point = initial.atPose2(pose_key).transformFrom(np.array([r * math.cos(theta), r * math.sin(theta)]))
        if initial.exists(point_key):
            # erase + insert: update() from Python would store a dynamic Vector, not a Point2.
            initial.erase(point_key)
        initial.insert(point_key, point)
        done.add(point_key)


def _poses_only(values: gtsam.Values, group: str) -> gtsam.Values:
    out = gtsam.Values()
    get = getattr(values, f"at{group}")
    for k in pose_keys(values):
        out.insert(k, get(k))
    return out


def _with_landmarks(poses: gtsam.Values, pg: "PoseGraph") -> gtsam.Values:
    """``poses`` + every landmark: the file's vertex, else placed from its first measurement."""
    if not pg.landmark_count:
        return poses
    values = gtsam.Values(poses)
    for key in landmark_keys(pg.initial):
        values.insert(key, pg.initial.atPoint3(key) if pg.is3d else pg.initial.atPoint2(key))
    _initialize_landmarks(values, pg.landmarks, pg.is3d, pg.landmark_vertex_keys)
    return values


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
    """Graph of ``pg.edges`` between factors + 1 prior, built with ``backend``'s constructors,
    followed by the landmark measurements (GTSAM's own factors in every backend).

    The prior pins the first pose at its initial value (identity for edge-only
    files), fixing the gauge.  With ``robust`` (a
    :class:`lie_factors.batch.robust.RobustLoss`) the loop closures' noise models —
    every edge's with ``robust_all`` — become ``noiseModel.Robust(loss,
    Gaussian)``.  Edge k of the file is factor k; the prior follows the edges, then the landmark
    measurements.
    """
    F = load_factors(backend)
    Between = getattr(F, f"BetweenFactor{pg.group}")
    Prior = getattr(F, f"PriorFactor{pg.group}")
    mestimator = robust.to_gtsam() if robust is not None else None
    graph = gtsam.NonlinearFactorGraph()
    # readG2o gives every edge its own noise model object, even where the file
    # repeats one information matrix; equal Gaussian models (same type, same
    # R) become one object, which the factors' and the batch solver's
    # per-object caches then check and read once.
    shared: dict = {}
    robust_of: dict = {}  # id(shared Gaussian) → its one Robust wrapper
    gaussian = (gtsam.noiseModel.Gaussian, gtsam.noiseModel.Diagonal,
                gtsam.noiseModel.Isotropic, gtsam.noiseModel.Unit)
    for k in range(pg.between.size()):
        f = pg.between.at(k)
        i, j = f.keys()
        noise = f.noiseModel()
        is_shared = type(noise) in gaussian
        if is_shared:
            noise = shared.setdefault((type(noise), noise.R().tobytes()), noise)
        if mestimator is not None and (robust_all or abs(int(i) - int(j)) != 1):
            wrapped = robust_of.get(id(noise)) if is_shared else None
            if wrapped is None:
                wrapped = gtsam.noiseModel.Robust.Create(mestimator, noise)
                if is_shared:  # `shared` holds the Gaussian, so its id stays its own
                    robust_of[id(noise)] = wrapped
            noise = wrapped
        graph.add(Between(i, j, f.measured(), noise))
    first = getattr(pg.initial, f"at{pg.group}")(pg.first_key)
    graph.add(Prior(pg.first_key, first, prior_noise(pg.is3d, pg.group)))
    graph.push_back(pg.landmarks)
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
    optimizer: type | None = None,
) -> OptimizeResult:
    """Levenberg–Marquardt, stepped from Python exactly like ``optimizer.optimize()``.

    ``optimizer``: ``gtsam.LevenbergMarquardtOptimizer`` (default) or a drop-in
    with its interface (``lie_factors.optimizers.LevenbergMarquardtOptimizer``).

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
        opt = (optimizer or gtsam.LevenbergMarquardtOptimizer)(graph, initial, params)
        initial_error = new_error = float(opt.error())
        if not math.isfinite(initial_error):
            raise PoseGraphError(f"the initial error is {initial_error}: some residual overflows "
                                 f"(coordinates or information values too large?)")
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


def _optimize_custom(graph, initial, max_iterations=100, progress=None, params=None) -> OptimizeResult:
    # GTSAM's LM run from Python on Values it holds: callbacks get that object, not a copy each.
    from lie_factors.optimizers import LevenbergMarquardtOptimizer

    return optimize(graph, initial, max_iterations, progress, params, optimizer=LevenbergMarquardtOptimizer)


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
    custom=Backend(_custom_factors, _optimize_custom,
                   "lie_factors.factors (closed-form Jacobians) in lie_factors.optimizers' drop-in LM"),
    batch=Backend(_custom_factors, _optimize_batch, "lie_factors factors, vectorized LM driven from Python"),
)


# --------------------------------------------------------------------------- #
# Results and output files
# --------------------------------------------------------------------------- #

@dataclass
class RunRecord:
    """What ``lie-factors posegraph --json`` prints (``to_dict``).

    ``factors`` counts the optimized graph: the file's edges and landmark
    measurements + 1 prior; ``landmarks`` the landmark variables;
    ``seconds`` is optimization only (LM construction + iterations, not loading
    and not initialization); ``init`` is the initialization method used
    (:data:`lie_factors.initialize.METHODS`) and ``init_seconds`` its cost;
    ``initial_error``/``final_error`` are GTSAM's 0.5·Σ‖whitened residual‖²
    (Σ ρ(‖whitened residual‖) for robust factors).  ``robust``: the loss
    (``name:k``, with ``+all`` if on every edge); ``gnc``: the GNC loss;
    ``init_inliers_only`` (robust and GNC runs): whether the start was built
    from the odometry edges and the prior alone.  With
    GNC, ``iterations`` counts GNC's outer iterations, ``final_error`` is GNC's
    weighted cost Σ w_k·½‖R_k e_k‖², and ``outliers`` lists the rejected edges
    (0-based, in the file's edge order).
    """

    backend: str
    dataset: str
    dimension: int
    poses: int
    landmarks: int
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
    init_inliers_only: bool | None = None

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        # robust / gnc / outliers / init_inliers_only appear only in runs that use them.
        for key in ("robust", "gnc", "outliers", "init_inliers_only"):
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

    ``init``: a method of :func:`lie_factors.initialize.initialize`, run on
    GTSAM's own factors of the file (the measurements and noise models every
    backend's graph holds, so every backend starts from the same values);
    ``file`` is the file's vertices.  With ``robust`` or ``gnc``, ``auto``
    builds the start from the odometry edges and the prior only (their
    measurements composed: the loop closures, false ones included, are left
    out; ``start.inliers_only``).  Landmarks keep their file vertex, or are
    placed from their first measurement.  ``on_init`` is called with the
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
    # The initializers handle poses: give them the pose-pose part (build_graph
    # puts the landmark measurements last), then place the landmarks.  They run
    # on GTSAM's own factors (what every backend's graph holds, measurement and
    # noise model alike, so every backend starts from the same values) before
    # the backend's graph exists: the chordal relaxation's transient memory then
    # does not stack on numba's (torus3D, batch: peak RSS 394 → 343 MiB; native 253).
    native = build_graph(pg, "native")
    pose_part = gtsam.NonlinearFactorGraph()
    for k in range(pg.edges + 1):
        pose_part.add(native.at(k))
    file_poses = (None if pg.initialized_from_edges
                  else _poses_only(pg.initial, pg.group) if pg.landmark_count else pg.initial)
    if pg.edges == 0 and init in ("auto", "file"):
        # Landmark measurements only (e.g. one pose seeing one landmark): no pose
        # graph for an initializer to relax; the file's values are the start.
        start = Initialization(_poses_only(pg.initial, pg.group), "file", 0.0)
    else:
        # Robust and GNC runs doubt the loop closures: auto starts from the odometry and the prior.
        inliers = (np.setdiff1d(np.arange(pg.edges + 1), loop_closures(pg))
                   if gnc is not None or robust is not None else None)
        start = initialize(pose_part, init, file_poses, inliers=inliers)
    start = dataclasses.replace(start, values=_with_landmarks(start.values, pg))
    del pose_part
    if on_init is not None:
        on_init(start)
    # GNC weighs the plain graph itself; a robust run wraps the loop closures' noise models.
    loss = robust if gnc is None else None
    graph = native if backend == "native" and loss is None else build_graph(pg, backend, loss, robust_all)
    del native
    if gnc is not None:
        return _run_gnc(pg, graph, start, backend, max_iterations, gnc, gnc_progress)
    opt = get_backend(backend).optimize or optimize
    if robust is not None and backend == "batch":
        opt = _optimize_batch_robust
    result = opt(graph, start.values, max_iterations=max_iterations, progress=progress)
    result.start = start.values
    record = _record(pg, backend, graph, start, result,
                     robust=None if robust is None else str(robust) + ("+all" if robust_all else ""),
                     init_inliers_only=None if robust is None else start.inliers_only)
    return record, result, pg


def _record(pg: PoseGraph, backend: str, graph, start, result: OptimizeResult, **extra) -> RunRecord:
    """The run's :class:`RunRecord`: the graph, its start and ``result``'s figures, plus ``extra`` fields."""
    return RunRecord(
        backend=backend,
        dataset=pg.name,
        dimension=3 if pg.is3d else 2,
        poses=pg.poses,
        landmarks=pg.landmark_count,
        factors=int(graph.size()),
        iterations=result.iterations,
        initial_error=result.initial_error,
        final_error=result.final_error,
        seconds=result.seconds,
        converged=result.converged,
        init=start.method,
        init_seconds=start.seconds,
        **extra,
    )


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
    record = _record(pg, backend, graph, start, result, gnc=loss, outliers=outliers,
                     init_inliers_only=start.inliers_only)
    return record, result, pg


def positions(values: gtsam.Values, is3d: bool, group: str | None = None) -> np.ndarray:
    """Translations of the poses in ``values`` in key order, shape (N, 3) (z = 0 in 2-D).

    Similarity3 (``group``): the image of the origin, s·t (GTSAM's action p ↦ s(Rp + t)).
    """
    keys = pose_keys(values)
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


def landmark_positions(values: gtsam.Values, is3d: bool) -> np.ndarray:
    """Landmark points of ``values`` in key order, shape (M, 3) (z = 0 in 2-D)."""
    keys = landmark_keys(values)
    out = np.zeros((len(keys), 3))
    for n, k in enumerate(keys):
        if is3d:
            out[n] = values.atPoint3(k)
        else:
            out[n, :2] = values.atPoint2(k)
    return out
