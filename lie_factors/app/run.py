"""Pose-graph optimization of g2o files with GTSAM, native or lie_factors factors.

:class:`PoseGraphRun` owns a run (``lie-factors posegraph`` is one; :func:`run`
is one without outputs), step by step:

1. :func:`lie_factors.g2o.resolve_dataset` — a path, or the name of a file shipped with GTSAM
   (``sphere2500.txt``) found with ``gtsam.findExampleDataFile``.
2. :func:`lie_factors.g2o.check_g2o` — our own vectorized check of every line, so a bad
   file gives ``file:line: what was expected`` instead of GTSAM silently skipping lines
   (``readG2o`` drops every edge after a ``#`` comment, for instance).
3. :func:`load` — a pose graph as arrays (:func:`lie_factors.g2o.read_arrays`); its
   GTSAM form (``gtsam.readG2o``; poses without a vertex line initialized by
   composing measurements along a BFS spanning tree) on first use.
4. Initialization — on the arrays (:mod:`lie_factors.initialization.arrays`) on the
   default path, else :func:`lie_factors.initialization.initialize` on GTSAM's factors:
   the chordal relaxation (3-D) or LAGO (2-D) by default, the file's vertices on request.
5. The backend: ``batch`` on a plain pose graph builds
   :meth:`lie_factors.batch.Problem.from_arrays` (no factor object); otherwise
   :func:`build_graph` re-creates the between factors with the backend's
   constructors, plus a prior on the first pose, and :func:`optimize` (or the
   batch solver) runs Levenberg–Marquardt one ``iterate()`` at a time from
   Python, with GTSAM's own stopping rule, reporting each iteration.
6. Output files (g2o, png), each written atomically.

g2o formats (checking, reading, writing) live in :mod:`lie_factors.g2o`; the
LM loop and the result type in :mod:`lie_factors.lm`.
"""

from __future__ import annotations

import dataclasses
import math
import os
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

import gtsam

from ..errors import PoseGraphError
from ..kernels.elements import values_from_matrices
from ..g2o import arrays_supported, check_g2o, read_arrays, read_g2o, resolve_dataset
from ..initialization import METHODS as INIT_METHODS
from ..initialization import Initialization, InitializationError, initialize, spanning_tree_initial
from ..lm import IterationInfo, OptimizeResult, default_optimize
from ..stack import large_stack
from ..timing import Stopwatch, warm_up_factors


# --------------------------------------------------------------------------- #
# Loading
# --------------------------------------------------------------------------- #

@dataclass
class PoseGraph:
    """A checked g2o file: as arrays (pose graphs) and, when asked for, as GTSAM reads it.

    ``arrays``: :class:`lie_factors.pose_graph.PoseGraph` (poses, edges,
    measurements and information in GTSAM's conventions) for files of poses
    and pose–pose edges, else None.  The GTSAM form (``between``,
    ``initial``, ``landmarks``) of such a file is read on first use
    (``gtsam.readG2o``, see :func:`load`); pass None for them with ``summary``
    (:func:`lie_factors.g2o.check_g2o`'s) to defer it:

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
    between: gtsam.NonlinearFactorGraph | None
    initial: gtsam.Values | None
    first_key: int
    initialized_from_edges: bool
    # default_factory (not default): no class attribute, so a deleted one reaches __getattr__
    landmarks: gtsam.NonlinearFactorGraph | None = dataclasses.field(default_factory=gtsam.NonlinearFactorGraph)
    landmark_vertex_keys: frozenset = frozenset()
    group: str = ""
    arrays: object = None
    summary: object = dataclasses.field(default=None, repr=False)

    def __post_init__(self):
        if not self.group:
            self.group = "Pose3" if self.is3d else "Pose2"
        if self.between is None:
            if self.summary is None:
                raise ValueError("PoseGraph: give the GTSAM graph, or the checked file's summary")
            # Read by GTSAM on first use (__getattr__ runs only for missing attributes).
            del self.between, self.initial, self.landmarks

    def __getattr__(self, name):
        if name in ("between", "initial", "landmarks") and "summary" in self.__dict__:
            self.between, self.initial, self.landmarks, self.landmark_vertex_keys = \
                _read_gtsam(self.path, self.summary)
            return self.__dict__[name]
        raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")

    @property
    def poses(self) -> int:
        if self.arrays is not None:
            return len(self.arrays.keys)
        return len(pose_keys(self.initial))

    @property
    def landmark_count(self) -> int:
        if self.arrays is not None:
            return 0
        return int(self.initial.size()) - self.poses

    @property
    def edges(self) -> int:
        if self.arrays is not None:
            return len(self.arrays.edge_keys)
        return int(self.between.size())

    @property
    def observations(self) -> int:
        if self.arrays is not None:
            return 0
        return int(self.landmarks.size())

    def describe(self) -> str:
        """``"name: SE(3), N poses, M edges[, K landmarks, L landmark measurements]"``: the
        first line a run prints (batch and incremental alike)."""
        kind = {"Pose2": "SE(2)", "Pose3": "SE(3)", "Similarity3": "Sim(3)"}[self.group]
        lms = (f", {self.landmark_count} landmarks, {self.observations} landmark measurements"
               if self.observations else "")
        return f"{self.name}: {kind}, {self.poses} poses, {self.edges} edges{lms}"

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
    """Resolve, check and read ``dataset``; raise :class:`PoseGraphError` if unusable.

    Pose graphs are read into arrays only (:func:`lie_factors.g2o.read_arrays`);
    the GTSAM graph and Values are built when first asked for.  Files with
    landmarks are read by GTSAM at once.
    """
    path = resolve_dataset(dataset)
    summary = check_g2o(path)
    pose_ids = summary.pose_ids
    common = dict(path=path, name=os.path.basename(path), is3d=summary.is3d, first_key=pose_ids[0],
                  initialized_from_edges=len(summary.pose_vertex_ids) == 0, group=summary.group,
                  summary=summary)
    if arrays_supported(summary):
        return PoseGraph(between=None, initial=None, arrays=read_arrays(summary), **common)
    between, initial, landmarks, with_vertex = _read_gtsam(path, summary)
    return PoseGraph(between=between, initial=initial, landmarks=landmarks,
                     landmark_vertex_keys=with_vertex, **common)


def _read_gtsam(path: str, summary) -> tuple:
    """(between graph, initial Values, landmark graph, landmark keys with a vertex) as GTSAM reads ``path``."""
    graph, initial = read_g2o(path, summary)
    landmarks = gtsam.NonlinearFactorGraph()
    if summary.observation_count == 0:
        between = graph  # a pose graph: no factor to sort out (no Python loop over them)
    else:
        between = gtsam.NonlinearFactorGraph()
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
    return between, initial, landmarks, with_vertex


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
    warmed first; see :mod:`lie_factors.timing`).
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
            raise PoseGraphError(f"the initial error is {initial_error}: some residual overflows "
                                 f"(coordinates or information values too large?)")
        result = default_optimize(opt, params, progress)
        result.values = opt.values()
    except RuntimeError as exc:
        # e.g. IndeterminantLinearSystemException: report it, don't dump a traceback.
        raise PoseGraphError(f"optimization failed: {str(exc).strip().splitlines()[0]}") from None
    result.seconds = clock.seconds()
    return result


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
    (:data:`lie_factors.initialization.METHODS`) and ``init_seconds`` its cost;
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
    #: seconds of each step of a PoseGraphRun (see PoseGraphRun.timings)
    timings: dict | None = None

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        # robust / gnc / outliers / init_inliers_only appear only in runs that use them.
        for key in ("robust", "gnc", "outliers", "init_inliers_only", "timings"):
            if d[key] is None:
                del d[key]
        return d


def loop_closures(pg: PoseGraph) -> np.ndarray:
    """Indices of the file's edges whose pose ids are not consecutive (|id1 − id2| ≠ 1)."""
    if pg.arrays is not None:
        k = pg.arrays.edge_keys
        return np.flatnonzero(np.abs(k[:, 0] - k[:, 1]) != 1).astype(np.int64)
    return np.array([k for k in range(pg.between.size())
                     if abs(int(pg.between.at(k).keys()[0]) - int(pg.between.at(k).keys()[1])) != 1],
                    dtype=np.int64)


#: --robust LOSS names the command accepts (a subset of lie_factors.batch.robust.LOSSES)
CLI_LOSSES = ("huber", "cauchy", "tukey", "gm", "dcs")


def parse_robust(robust, robust_all: bool = False, gnc: str | None = None):
    """The run's robust loss: None, a ``RobustLoss`` as given, or one parsed from ``LOSS[:K]``.

    Raises :class:`PoseGraphError` with a one-line reason (unknown loss or GNC
    loss, bad parameter, ``robust_all`` without a loss, both robust and GNC).
    """
    if gnc is not None and gnc not in ("tls", "gm"):
        raise PoseGraphError(f"--gnc: unknown loss {gnc!r} (choose from tls, gm)")
    if robust is None:
        if robust_all:
            raise PoseGraphError("--robust-all needs --robust LOSS")
        return None
    if isinstance(robust, str):
        name = robust.partition(":")[0].strip().lower()
        if name not in CLI_LOSSES:
            raise PoseGraphError(f"--robust: unknown loss {name!r} (choose from {', '.join(CLI_LOSSES)})")
        from lie_factors.batch.robust import parse_loss  # numba: only runs with a loss load it

        try:
            robust = parse_loss(robust)
        except ValueError as exc:
            raise PoseGraphError(f"--robust: {exc}") from None
    if gnc:
        raise PoseGraphError("--robust and --gnc are alternatives (GNC replaces the loss); give one")
    return robust


class RunEvents:
    """What a :class:`PoseGraphRun` reports while it runs (the CLI prints them); all no-ops here."""

    def loaded(self, run: "PoseGraphRun") -> None:
        """The file is read and checked (``run.pg``)."""

    def started(self, start: Initialization) -> None:
        """The initial values are chosen; LM starts next."""

    def iteration(self, info: IterationInfo) -> None:
        """One LM iteration done."""

    def gnc_iteration(self, it: int, lam: float, cost: float, lm_iterations: int) -> None:
        """One GNC outer iteration done."""

    def optimized(self, run: "PoseGraphRun") -> None:
        """The optimization is done (``run.record``, ``run.result``); the files come next."""

    def wrote(self, path: str) -> None:
        """An output file (``output`` or ``plot``) is complete."""


class PoseGraphRun:
    """One pose-graph run from reading to writing: ``lie-factors posegraph`` is one of these.

    :meth:`execute` checks the invocation (backend, loss, output paths)
    before any work, then reads the file (:func:`load`), initializes
    (:func:`lie_factors.initialization.initialize`), optimizes with the backend,
    and writes ``output`` (g2o) and ``plot`` (png); ``events``
    (:class:`RunEvents`) hears each step.  The default path — ``batch`` on a
    pose graph without robust loss or GNC — never builds a factor object: the
    file's arrays become a :meth:`lie_factors.batch.Problem.from_arrays`.

    After :meth:`execute`: ``record`` (:class:`RunRecord`), ``result``
    (:class:`OptimizeResult`; ``result.values`` is built on first use by
    :meth:`values` when ``lazy_values``), ``pg``, ``start``, and
    ``timings`` (seconds: ``imports`` of the backend's modules, ``read``
    (resolve, check, arrays), ``init``, ``setup`` (graph or problem, linear
    system, symbolic analysis), ``iterations``, ``write``).
    """

    def __init__(self, dataset, backend: str = "batch", max_iterations: int = 100, init: str = "auto",
                 robust=None, robust_all: bool = False, gnc: str | None = None,
                 output: str | None = None, plot: str | None = None, events: RunEvents | None = None,
                 lazy_values: bool = False):
        self.dataset, self.backend, self.max_iterations, self.init = dataset, backend, max_iterations, init
        self.robust_text = robust
        self.robust = None  # the parsed loss (check)
        self._checked = False
        self.robust_all, self.gnc = robust_all, gnc
        self.output, self.plot = output, plot
        self.events = events if events is not None else RunEvents()
        self.lazy_values = lazy_values
        self.timings: dict[str, float] = {}
        self.pg: PoseGraph | None = dataset if isinstance(dataset, PoseGraph) else None
        self.record: RunRecord | None = None
        self.result: OptimizeResult | None = None
        self.start: Initialization | None = None
        self._opt = None  # the batch optimizer of an array run (values() on demand)
        self._start_X = None  # the array initializer's poses (P, m, m), in pg.arrays.keys order

    # ------------------------------------------------------------------ steps
    def check(self) -> None:
        """Everything that can be wrong with the invocation, before the (possibly long) work."""
        get_backend(self.backend)
        self.robust = parse_robust(self.robust_text, self.robust_all, self.gnc)
        self._checked = True
        for path in (self.output, self.plot):
            if path:
                from ..atomic import check_writable

                check_writable(path)

    @property
    def uses_arrays(self) -> bool:
        """The default path: batch backend, plain LM, a pose graph held as arrays."""
        return (self.backend == "batch" and self.robust is None and self.gnc is None
                and self.pg is not None and self.pg.arrays is not None)

    def load(self) -> PoseGraph:
        if not self._checked:
            self.check()
        t = time.perf_counter()
        if self.pg is None:
            self.pg = load(self.dataset)
        self.timings["read"] = time.perf_counter() - t
        if self.gnc is not None and loop_closures(self.pg).size == 0:
            raise PoseGraphError(f"{self.pg.name}: --gnc needs loop closures (edges between "
                                 "non-consecutive poses); this graph has none")
        t = time.perf_counter()
        if not self.uses_arrays:  # the array path needs no factor namespace
            load_factors(self.backend)
        else:
            from lie_factors.batch import optimizer  # noqa: F401  (numba, the batch loops, CHOLMOD)
        self.timings["imports"] = self.timings.get("imports", 0.0) + time.perf_counter() - t
        self.events.loaded(self)
        return self.pg

    def initialize(self) -> Initialization:
        """The initial values (every backend starts from the same ones; see :func:`run`)."""
        pg, init = self.pg, self.init
        # The initializers handle poses: give them the pose-pose part and the prior,
        # then place the landmarks.  They run on GTSAM's own factors (the same
        # measurements and noise models every backend's graph holds) before the
        # backend's graph exists: the chordal relaxation's transient memory then
        # does not stack on numba's (torus3D, batch: peak RSS 394 → 343 MiB; native 253).
        t = time.perf_counter()
        self._start_X = None
        skipped: list = []
        if self.uses_arrays and pg.initialized_from_edges == (pg.arrays.vertices is None):
            # On the file's arrays (no GTSAM graph); None hands over to GTSAM's path below
            # (as does a PoseGraph whose file values are load()'s spanning tree, not vertices).
            from ..initialization import arrays as initialize_arrays

            start, self._start_X = initialize_arrays.initialize(
                pg.arrays, init, pg.first_key, _first_element(pg),
                np.diag(1.0 / prior_noise(pg.is3d, pg.group).sigmas() ** 2))
            if start is not None:
                self.start = start
                if not self.lazy_values:  # a Python caller gets gtsam.Values, as from GTSAM's path
                    self.start_values()
                self.timings["init"] = time.perf_counter() - t
                self.events.started(self.start)
                return self.start
            skipped = self._start_X
            self._start_X = None
        pose_part = gtsam.NonlinearFactorGraph(pg.between)
        pose_part.add(_prior_factor(pg, gtsam))
        file_poses = (None if pg.initialized_from_edges
                      else _poses_only(pg.initial, pg.group) if pg.landmark_count else pg.initial)
        if pg.edges == 0 and init in ("auto", "file"):
            # Landmark measurements only (e.g. one pose seeing one landmark): no pose
            # graph for an initializer to relax; the file's values are the start.
            start = Initialization(_poses_only(pg.initial, pg.group), "file", 0.0)
        else:
            # Robust and GNC runs doubt the loop closures: auto starts from the odometry and the prior.
            inliers = (np.setdiff1d(np.arange(pg.edges + 1), loop_closures(pg))
                       if self.gnc is not None or self.robust is not None else None)
            start = initialize(pose_part, "spanning-tree" if skipped else init, file_poses, inliers=inliers)
            start.skipped[:0] = skipped
        del pose_part
        self.start = dataclasses.replace(start, values=_with_landmarks(start.values, pg))
        self.timings["init"] = time.perf_counter() - t
        self.events.started(self.start)
        return self.start

    def optimize(self) -> OptimizeResult:
        pg, backend, start = self.pg, self.backend, self.start
        if self.uses_arrays:
            return self._optimize_arrays()
        t = time.perf_counter()
        # GNC weighs the plain graph itself; a robust run wraps the loop closures' noise models.
        loss = self.robust if self.gnc is None else None
        graph = build_graph(pg, backend, loss, self.robust_all)
        self._graph_size = int(graph.size())
        self.timings["setup"] = time.perf_counter() - t
        if self.gnc is not None:
            self.record, self.result = _run_gnc(pg, graph, start, backend, self.max_iterations, self.gnc,
                                                self.events.gnc_iteration)
            self.timings["iterations"] = self.result.seconds
            return self.result
        opt = get_backend(backend).optimize or optimize
        if self.robust is not None and backend == "batch":
            opt = _optimize_batch_robust
        result = opt(graph, start.values, max_iterations=self.max_iterations,
                     progress=self.events.iteration)
        result.start = start.values
        self.timings["iterations"] = result.seconds
        self.result = result
        self.record = _record(pg, backend, graph, start, result,
                              robust=None if self.robust is None
                              else str(self.robust) + ("+all" if self.robust_all else ""),
                              init_inliers_only=None if self.robust is None else start.inliers_only)
        return result

    def _optimize_arrays(self) -> OptimizeResult:
        from lie_factors.batch import BatchLevenbergMarquardt, Problem
        from lie_factors.batch.graph import BatchError, first_line, matrices_of

        pg, a, start = self.pg, self.pg.arrays, self.start
        # Compilation of the kernels (first run on a machine) is not optimization time.
        clock = Stopwatch()
        X = self._start_X if self._start_X is not None else matrices_of(start.values, pg.group, a.keys)
        prior = (pg.first_key, _first_element(pg), prior_noise(pg.is3d, pg.group).R())
        params = gtsam.LevenbergMarquardtParams()
        params.setMaxIterations(int(self.max_iterations))
        import numba

        threads = numba.get_num_threads()
        try:
            problem = Problem.from_arrays(pg.group, a.keys, X, a.edge_keys, a.measured, a.information,
                                          [prior])
            del X
            if problem.graph_size * problem.blocks[pg.group].spec.dim ** 2 < PARALLEL_MIN_WORK:
                numba.set_num_threads(1)
            self._opt = opt = BatchLevenbergMarquardt(problem, None, params)
            self.timings["setup"] = clock.seconds()
            result = opt.optimize(self.events.iteration, values=not self.lazy_values)
        except BatchError as exc:
            raise PoseGraphError(f"batch backend: {exc}") from None
        except RuntimeError as exc:
            raise PoseGraphError(f"optimization failed: {first_line(exc)}") from None
        finally:
            numba.set_num_threads(threads)
        result.seconds = clock.seconds()
        self.timings["iterations"] = result.seconds - self.timings["setup"]
        result.start = start.values if start.values is not None or self.lazy_values else self.start_values()
        self.result = result
        self._graph_size = problem.graph_size
        self.record = _record(pg, self.backend, None, start, result, factors=problem.graph_size)
        return result

    def values(self) -> gtsam.Values:
        """The optimized values (built now if the run kept them as arrays)."""
        if self.result.values is None:
            self.result.values = self._opt.values()
        return self.result.values

    def start_values(self) -> gtsam.Values:
        """The values LM started from (built now if the array initializer gave matrices)."""
        if self.start.values is None:
            self.start.values = values_from_matrices(self.pg.group, self.pg.arrays.keys, self._start_X)
        if self.result is not None and self.result.start is None:
            self.result.start = self.start.values
        return self.start.values

    def write(self) -> None:
        """Write ``output`` (the optimized graph, g2o) and ``plot`` (png), each atomically."""
        from .. import atomic
        from ..g2o import write_g2o

        pg, record = self.pg, self.record
        t = time.perf_counter()
        if self.output:
            write_g2o(self.output, pg.native_graph(), self.values())
            self.events.wrote(self.output)
        if self.plot:
            from lie_factors.app.plotting import plot_trajectories

            values, begin = self.values(), self.start_values()
            trajectories = {f"initial ({record.init})": positions(begin, pg.is3d, pg.group),
                            "optimized": positions(values, pg.is3d, pg.group)}
            points = ({"initial landmarks": landmark_positions(begin, pg.is3d),
                       "optimized landmarks": landmark_positions(values, pg.is3d)}
                      if pg.landmark_count else None)
            atomic.replace_atomically(self.plot, lambda tmp: plot_trajectories(
                tmp, trajectories, f"{pg.name} ({self.backend})", three_d=pg.is3d, points=points),
                suffix=".png")
            self.events.wrote(self.plot)
        self.timings["write"] = time.perf_counter() - t

    def execute(self) -> RunRecord:
        """check → load → initialize → optimize → write; returns the :class:`RunRecord`."""
        self.check()
        self.load()
        self.initialize()
        self.optimize()
        self.events.optimized(self)
        self.write()
        self.record.timings = {k: self.timings.get(k, 0.0) for k in TIMING_KEYS}
        return self.record


#: Keys of ``RunRecord.timings`` (``--json``): the steps of a :class:`PoseGraphRun`, in order.
TIMING_KEYS = ("imports", "read", "init", "setup", "iterations", "write")


#: Factors × (tangent dimension)² below which the default path runs the batch loops on one
#: numba thread: their fork/join costs more than it saves there.  Whole command, 2 runs each,
#: load 2–4 (docs/benchmarks.md): 1 thread made the iterations faster on intel
#: (2.5k SE(2) factors, 0.05–0.08 vs 0.22–0.26 s), sphere2500 (5k SE(3)), city10000 (21k SE(2):
#: 1.9·10⁵) and torus3D (9k SE(3): 3.3·10⁵, 0.28 vs 0.38–0.41 s); 2 threads were faster from
#: the 20k-pose helix (22k SE(3): 7.9·10⁵, 0.33 vs 0.37 s) and equal at 100k.
PARALLEL_MIN_WORK = 500_000


def _first_element(pg: PoseGraph) -> np.ndarray:
    """The prior's element: the first pose's file vertex (the identity for edge-only files)."""
    a = pg.arrays
    if a is not None:
        if a.vertices is None:
            return np.eye(a.measured.shape[1])
        return a.vertices[0]
    return np.asarray(getattr(pg.initial, f"at{pg.group}")(pg.first_key).matrix())


def _prior_factor(pg: PoseGraph, F):
    """``F``'s prior factor on the first pose (see :func:`build_graph`)."""
    Prior = getattr(F, f"PriorFactor{pg.group}")
    first = (getattr(gtsam, pg.group)() if pg.initialized_from_edges and pg.arrays is not None
             else getattr(pg.initial, f"at{pg.group}")(pg.first_key))
    return Prior(pg.first_key, first, prior_noise(pg.is3d, pg.group))


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
    """Load (unless given a :class:`PoseGraph`), initialize, optimize with ``backend``.

    ``init``: a method of :func:`lie_factors.initialization.initialize`, run on
    GTSAM's own factors of the file (the measurements and noise models every
    backend's graph holds, so every backend starts from the same values);
    ``file`` is the file's vertices.  With ``robust`` or ``gnc``, ``auto``
    builds the start from the odometry edges and the prior only (their
    measurements composed: the loop closures, false ones included, are left
    out; ``start.inliers_only``).  Landmarks keep their file vertex, or are
    placed from their first measurement.  ``on_init`` is called with the
    :class:`~lie_factors.initialization.Initialization` before LM starts.
    ``result.start`` holds the values LM started from.

    ``robust``: a :class:`lie_factors.batch.robust.RobustLoss` (or its text,
    ``huber:1.345``) on the loop closures (all edges with ``robust_all``).
    ``gnc``: "tls" or "gm" runs graduated non-convexity instead of plain LM
    (odometry edges and the prior are known inliers; ``max_iterations``
    limits each inner LM; ``gnc_progress(it, λ, cost, lm_iterations)`` after
    each outer iteration).  A :class:`PoseGraphRun` without outputs.
    """

    class Events(RunEvents):
        def started(self, start):
            if on_init is not None:
                on_init(start)

        def iteration(self, info):
            if progress is not None:
                progress(info)

        def gnc_iteration(self, *args):
            if gnc_progress is not None:
                gnc_progress(*args)

    job = PoseGraphRun(dataset, backend, max_iterations, init, robust, robust_all, gnc, events=Events())
    record = job.execute()
    return record, job.result, job.pg


def _record(pg: PoseGraph, backend: str, graph, start, result: OptimizeResult, **extra) -> RunRecord:
    """The run's :class:`RunRecord`: the graph (or ``factors=``), its start and ``result``'s
    figures, plus ``extra`` fields."""
    factors = extra.pop("factors", None)
    return RunRecord(
        backend=backend,
        dataset=pg.name,
        dimension=3 if pg.is3d else 2,
        poses=pg.poses,
        landmarks=pg.landmark_count,
        factors=int(graph.size()) if factors is None else int(factors),
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
             gnc_progress: Callable | None) -> tuple[RunRecord, OptimizeResult]:
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
    result = OptimizeResult(values, res.iterations, [initial_error, res.cost], [], res.seconds,
                            res.stop != "maxIterations")
    result.start = start.values
    outliers = [int(k) for k in res.outliers if k < pg.between.size()]
    record = _record(pg, backend, graph, start, result, gnc=loss, outliers=outliers,
                     init_inliers_only=start.inliers_only)
    return record, result


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
