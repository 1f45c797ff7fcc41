"""The front door's optimization: :func:`optimize` a pose graph (what ``lie-factors posegraph`` runs) or
any ``gtsam.NonlinearFactorGraph`` with its ``Values``.

A pose graph goes through the default command's stages: a prior on its first
pose (unless it has priors), the start (``init``), then the backend's solver:
``batch`` (the vectorized solver, on the arrays themselves where nothing else is
asked), ``dropin`` (GTSAM's Levenberg–Marquardt driven from Python on our
factors) or ``native`` (GTSAM's own factors and optimizer, the reference);
``robust`` losses on the loop closures; or ``gnc`` with the false-closure
pipeline (:mod:`lie_factors.robust.pipeline`).
"""

from __future__ import annotations

import contextlib
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Callable

import numpy as np

from .backends import BACKENDS, DEFAULT_BACKEND
from .errors import InputError, gtsam_failure
from .events import Events
from .posegraph.graph import PoseGraph
from .result import Result

if TYPE_CHECKING:
    import gtsam

    from .batch.marginals import Marginals
    from .initialization import Initialization
    from .result import ReplayResult
    from .robust.losses import RobustLoss

__all__ = ["BACKENDS", "DEFAULT_BACKEND", "ROBUST_LOSSES", "GNC_LOSSES", "INIT_METHODS", "Options", "options",
           "check_graph", "optimize", "optimize_pose_graph", "replay", "replay_options", "RELINEARIZE_THRESHOLD",
           "RELINEARIZE_SKIP"]

#: The robust losses ``robust=`` names (``name`` or ``name:k``).
ROBUST_LOSSES = ("huber", "cauchy", "tukey", "gm", "dcs")
#: The losses of graduated non-convexity.
GNC_LOSSES = ("tls", "gm")
#: The initializers (:data:`lie_factors.initialization.METHODS`).
INIT_METHODS = ("auto", "chordal", "lago", "spanning-tree", "odometry", "file")
#: Iterations accepted: beyond this no run finishes in any useful time, and GTSAM's counter is an int.
MAX_ITERATIONS = 1_000_000

def _keyword(name: str) -> str:
    return name


@dataclass(frozen=True)
class Options:
    """Checked options of :func:`optimize` (see there); ``robust`` parsed."""

    backend: str = DEFAULT_BACKEND
    init: str = "auto"
    max_iterations: int | None = None
    robust: "RobustLoss | None" = None
    robust_all: bool = False
    gnc: str | None = None
    consistency: bool = True
    linear_solver: str = "auto"

    @property
    def robust_name(self) -> str | None:
        """The robust loss as reported: ``name:k``, with ``+all`` on every edge."""
        return None if self.robust is None else str(self.robust) + ("+all" if self.robust_all else "")


def options(*, backend: str = DEFAULT_BACKEND, init: str = "auto", max_iterations: int | None = None,
            robust: "str | RobustLoss | None" = None, robust_all: bool = False, gnc: str | None = None,
            consistency: bool = True, linear_solver: str = "auto",
            spell: Callable[[str], str] = _keyword) -> Options:
    """The options of :func:`optimize`, checked: a one-line :class:`~lie_factors.errors.InputError`
    for anything wrong, naming the option as ``spell(keyword)`` says (the command line spells
    ``max_iterations`` as ``--max-iterations``)."""
    if backend not in BACKENDS:
        raise InputError(f"unknown backend {backend!r} (choose from {', '.join(BACKENDS)})")
    if init not in INIT_METHODS:
        raise InputError(f"{spell('init')}: unknown initializer {init!r} (choose from {', '.join(INIT_METHODS)})")
    if max_iterations is not None:
        if isinstance(max_iterations, bool) or not isinstance(max_iterations, (int, np.integer)):
            raise InputError(f"{spell('max_iterations')}: expected an integer, got {max_iterations!r}")
        if not 0 <= max_iterations <= MAX_ITERATIONS:
            raise InputError(f"{spell('max_iterations')}: must be from 0 to {MAX_ITERATIONS}, got {max_iterations}")
        max_iterations = int(max_iterations)
    if gnc is not None and gnc not in GNC_LOSSES:
        raise InputError(f"{spell('gnc')}: unknown loss {gnc!r} (choose from {', '.join(GNC_LOSSES)})")
    if not consistency and gnc is None:
        raise InputError(f"{spell('consistency')} applies to {spell('gnc')} only")
    if robust is None:
        if robust_all:
            raise InputError(f"{spell('robust_all')} needs {spell('robust')} LOSS")
    else:
        if gnc is not None:
            raise InputError(f"{spell('robust')} and {spell('gnc')} are alternatives (GNC replaces the loss); "
                             "give one")
        robust = _robust_loss(robust, spell)
    return Options(backend, init, max_iterations, robust, bool(robust_all), gnc, bool(consistency), linear_solver)


def _robust_loss(robust, spell) -> "RobustLoss":
    from .robust.losses import RobustLoss, parse_loss

    if isinstance(robust, RobustLoss):
        return robust
    if not isinstance(robust, str):
        raise InputError(f"{spell('robust')}: expected a loss name or a RobustLoss, got {type(robust).__name__}")
    name = robust.partition(":")[0].strip().lower()
    if name not in ROBUST_LOSSES:
        raise InputError(f"{spell('robust')}: unknown loss {name!r} (choose from {', '.join(ROBUST_LOSSES)})")
    try:
        return parse_loss(robust)
    except ValueError as exc:
        raise InputError(f"{spell('robust')}: {exc}") from None


# --------------------------------------------------------------------------- #
# The front door
# --------------------------------------------------------------------------- #

def optimize(graph: "PoseGraph | gtsam.NonlinearFactorGraph", initial: "gtsam.Values | None" = None,
             params: "gtsam.LevenbergMarquardtParams | gtsam.GaussNewtonParams | gtsam.DoglegParams | None" = None, *,
             backend: str = DEFAULT_BACKEND, init: str = "auto", max_iterations: int | None = None,
             robust: "str | RobustLoss | None" = None, robust_all: bool = False, gnc: str | None = None,
             consistency: bool = True, linear_solver: str = "auto", events: Events | None = None) -> Result:
    """Optimize a pose graph, or any GTSAM graph from its values; returns a :class:`~lie_factors.result.Result`.

    ``optimize(pose_graph, **options)``: a :class:`~lie_factors.posegraph.graph.PoseGraph`
    (:func:`lie_factors.read_g2o`) as ``lie-factors posegraph FILE`` optimizes it: a prior
    on its first pose unless it has priors, the start from ``init`` (``auto``: chordal in
    3-D, LAGO then chordal in 2-D, then the file's vertices, then a spanning tree; with
    ``robust`` or ``gnc``, from the odometry and the prior only), then the backend.

    ``optimize(graph, initial, params=None, **options)``: a ``gtsam.NonlinearFactorGraph``
    (our factors and GTSAM's, mixed) from ``initial`` (``gtsam.Values``), with GTSAM's
    ``LevenbergMarquardtParams``, ``GaussNewtonParams`` or ``DoglegParams``: the algorithm of
    GTSAM's optimizer for those params runs, with their settings; ``robust`` and ``gnc``
    need a graph of Between/Prior factors on one group (it is read as a pose graph), and
    ``gnc`` Levenberg–Marquardt's or Gauss–Newton's params.

    Options (every one a ``lie-factors posegraph`` option of the same name):

    - ``backend``: ``batch`` (default: the vectorized solver), ``dropin`` (GTSAM's LM on
      our factors, from Python), ``native`` (GTSAM's own factors and optimizer);
    - ``max_iterations``: the optimizer's limit of iterations (default: ``params``' own, 100);
      the caller's ``params`` are left as they were;
    - ``robust``: a loss on the loop closures (``huber``, ``cauchy``, ``tukey``, ``gm``,
      ``dcs``, optionally ``:k``), on every edge with ``robust_all``;
    - ``gnc``: ``tls`` or ``gm``: graduated non-convexity, the odometry and the priors known
      inliers; with ``consistency`` (default) the loop closures pass an odometry gate and a
      pairwise-consistency stage first and a final χ² check after (``result.outliers``,
      ``result.rejected_by``);
    - ``linear_solver``: the batch solver's (``auto``, ``cholmod``, ``gtsam``, ``pardiso``);
    - ``events``: an :class:`~lie_factors.events.Events` hearing the stages and iterations.

    Raises :class:`~lie_factors.errors.InputError` for bad input or options,
    :class:`~lie_factors.errors.InitializationError`, and
    :class:`~lie_factors.errors.IndeterminantLinearSystem` where the graph does not
    determine every variable.
    """
    opts = options(backend=backend, init=init, max_iterations=max_iterations, robust=robust,
                   robust_all=robust_all, gnc=gnc, consistency=consistency, linear_solver=linear_solver)
    events = events if events is not None else Events()
    if isinstance(graph, PoseGraph):
        if initial is not None:
            raise InputError("optimize(pose_graph): the start comes from init=, not from initial values")
        return optimize_pose_graph(graph, opts, params, events)
    import gtsam

    if not isinstance(graph, gtsam.NonlinearFactorGraph):
        raise InputError(f"optimize: expected a PoseGraph or a gtsam.NonlinearFactorGraph, got {type(graph).__name__}")
    if not isinstance(initial, gtsam.Values):
        raise InputError("optimize(graph, initial): initial must be gtsam.Values")
    if opts.robust is not None or opts.gnc is not None:
        return optimize_pose_graph(_as_pose_graph(graph, initial, opts), opts, params, events)
    if opts.init != "auto":
        raise InputError("optimize(graph, initial): the start is initial; init= applies to a pose graph")
    return _optimize_factor_graph(graph, initial, params, opts, events)


def _as_pose_graph(graph, initial, opts: Options) -> PoseGraph:
    """``graph`` read as a pose graph (its priors kept) starting at ``initial``: what robust losses
    and GNC work on."""
    import dataclasses

    from .interop import matrices_from_values

    if opts.init not in ("auto", "file"):
        raise InputError("optimize(graph, initial): the start is initial; init= applies to a pose graph")
    pg = PoseGraph.from_gtsam(graph)
    try:
        X = matrices_from_values(initial, pg.group, pg.keys)
    except RuntimeError as exc:
        raise InputError(f"initial: {exc}") from None
    return dataclasses.replace(pg, vertices=X)


@contextlib.contextmanager
def _max_iterations(params, max_iterations: int | None):
    """``params`` with its iteration limit set for the block (the caller's value restored after)."""
    if max_iterations is None:
        yield params
        return
    before = params.getMaxIterations()
    params.setMaxIterations(int(max_iterations))
    try:
        yield params
    finally:
        params.setMaxIterations(before)


#: The params whose optimizer's algorithm :func:`optimize` runs (``gnc``: the first two).
PARAMS = ("LevenbergMarquardtParams", "GaussNewtonParams", "DoglegParams")


def _optimizer_params(params, gnc: bool = False):
    """``params``, checked (default: GTSAM's default ``LevenbergMarquardtParams``)."""
    import gtsam

    if params is None:
        return gtsam.LevenbergMarquardtParams()
    names = PARAMS[:2] if gnc else PARAMS
    if not isinstance(params, tuple(getattr(gtsam, name) for name in names)):
        what = "gnc runs Levenberg-Marquardt or Gauss-Newton inside: " if gnc else ""
        raise InputError(f"params: {what}expected gtsam.{', gtsam.'.join(names[:-1])} or gtsam.{names[-1]}, "
                         f"got {type(params).__name__}")
    return params


# --------------------------------------------------------------------------- #
# A GTSAM graph
# --------------------------------------------------------------------------- #

def _optimize_factor_graph(graph, initial, params, opts: Options, events: Events) -> Result:
    params = _optimizer_params(params)
    with _max_iterations(params, opts.max_iterations):
        if opts.backend == "batch":
            from .batch.optimizer import BatchLevenbergMarquardt
            from .util.timing import Stopwatch

            clock = Stopwatch()
            try:
                opt = BatchLevenbergMarquardt(graph, initial, params, linear_solver=opts.linear_solver)
            except InputError:
                done = _converged_start(graph, initial, params, opts)
                if done is None:
                    raise
                return done
            setup = clock.seconds()
            events.set_up(setup)
            res = opt.optimize(events.iteration)
            seconds = clock.seconds()
            timings = {"setup": setup, "iterations": seconds - setup}
        else:
            from .backends import gtsam_optimizer, step_optimizer

            res = step_optimizer(graph, initial, params, gtsam_optimizer(opts.backend, params), events.iteration)
            seconds = res.seconds
            timings = {"setup": 0.0, "iterations": seconds}
    values = res.values
    return Result(res.final_error, res.initial_error, res.iterations, res.converged, seconds,
                  errors=list(res.errors), timings=timings, backend=opts.backend, factors=int(graph.size()),
                  _values=values, _start=initial, _marginals_of=lambda: _marginals(graph, values))


def _converged_start(graph, initial, params, opts: Options) -> Result | None:
    """GTSAM's optimizers stop before their first iteration where the error at the start is at
    most ``errorTol``: the result of that (the start), for a graph the batch solver cannot read
    (factors of GTSAM's on keys the values lack, say), or None where GTSAM's would iterate."""
    import gtsam

    try:
        error = float(graph.error(initial))
    except (RuntimeError, ValueError, TypeError):
        return None
    if not error <= params.getErrorTol():
        return None
    values = gtsam.Values(initial)
    return Result(error, error, 0, True, 0.0, errors=[error], timings={"setup": 0.0, "iterations": 0.0},
                  backend=opts.backend, factors=int(graph.size()), _values=values, _start=initial,
                  _marginals_of=lambda: _marginals(graph, values))


# --------------------------------------------------------------------------- #
# A pose graph
# --------------------------------------------------------------------------- #

def check_graph(pg: PoseGraph, opts: Options, spell: Callable[[str], str] = _keyword) -> None:
    """What :class:`Options` ask of the graph itself: ``gnc`` needs loop closures."""
    if opts.gnc is not None and pg.loop_closures().size == 0:
        raise InputError(f"{pg.name or 'the graph'}: {spell('gnc')} needs loop closures (edges between "
                         "non-consecutive poses); this graph has none")


def optimize_pose_graph(pg: PoseGraph, opts: Options, params=None, events: Events | None = None) -> Result:
    """:func:`optimize` on a pose graph with checked :class:`Options`."""
    events = events if events is not None else Events()
    check_graph(pg, opts)
    params = _optimizer_params(params, gnc=opts.gnc is not None)
    posed = pg.with_first_prior()
    start = _start(posed, opts)
    events.started(start)
    with _max_iterations(params, opts.max_iterations):
        if opts.gnc is not None:
            result = _optimize_gnc(posed, start, opts, params, events)
        elif opts.backend == "batch" and opts.robust is None and pg.landmarks is None:
            result = _optimize_arrays(posed, start, opts, params, events)
        else:
            result = _optimize_graph(posed, start, opts, params, events)
    result.pose_graph = pg
    if start.poses is not None and start.keys is not None and np.array_equal(start.keys, pg.keys):
        result._start_poses = start.poses
    result.init, result.init_seconds = start.method, start.seconds
    result.init_inliers_only = start.inliers_only if (opts.robust is not None or opts.gnc is not None) else None
    result.backend, result.robust, result.gnc = opts.backend, opts.robust_name, opts.gnc
    result.timings = {"init": start.seconds, **result.timings}
    return result


def _start(posed: PoseGraph, opts: Options) -> "Initialization":
    """The initial poses: every backend starts from the same ones (to 1e-9); under ``robust`` or
    ``gnc``, ``auto`` composes the odometry and the prior only (the loop closures are in doubt)."""
    from .initialization import Initialization, initialize

    if posed.edge_count == 0 and opts.init in ("auto", "file"):
        # landmark measurements only: no pose graph for an initializer to relax
        return Initialization("file", 0.0, poses=posed.start_poses, keys=posed.keys, group=posed.group)
    doubt = opts.gnc is not None or opts.robust is not None
    inliers = np.setdiff1d(np.arange(posed.edge_count), posed.loop_closures()) if doubt else None
    return initialize(posed, opts.init, inliers=inliers, engine="lie_factors" if opts.backend == "batch" else "gtsam")


def _poses_by_key(keys: np.ndarray, block, fallback: np.ndarray) -> np.ndarray:
    """(P, m, m): the block's elements in the order of ``keys`` (``fallback`` where the block has none)."""
    bk = np.asarray(block.keys, dtype=np.int64)
    if len(bk) == len(keys) and np.array_equal(bk, keys):
        return block.X
    out = np.array(fallback, dtype=np.float64, copy=True)
    pos = np.searchsorted(keys, bk)
    out[pos] = block.X
    return out


def _optimize_arrays(posed: PoseGraph, start, opts: Options, params, events: Events) -> Result:
    """The default path: the batch solver on the pose graph's arrays, no factor object."""
    from .batch.graph import Problem
    from .batch.optimizer import BatchLevenbergMarquardt
    from .util.timing import Stopwatch

    clock = Stopwatch()  # compilation of the kernels is not optimization time
    try:
        problem = Problem.from_pose_graph(posed, start.poses)
        opt = BatchLevenbergMarquardt(problem, None, params, linear_solver=opts.linear_solver)
        setup = clock.seconds()
        events.set_up(setup)
        res = opt.optimize(events.iteration, values=False)
    except RuntimeError as exc:
        raise gtsam_failure(exc) from None
    seconds = clock.seconds()
    block = problem.blocks[posed.group]
    poses = _poses_by_key(posed.keys, block, start.poses)
    return Result(res.final_error, res.initial_error, res.iterations, res.converged, seconds,
                  errors=list(res.errors), timings={"setup": setup, "iterations": seconds - setup},
                  factors=int(problem.graph_size), _keys=np.asarray(posed.keys, dtype=np.int64), _poses=poses,
                  _group=posed.group, _start=lambda: posed.with_landmarks(start.values),
                  _marginals_of=lambda: _pose_graph_marginals(posed, poses))


def _optimize_graph(posed: PoseGraph, start, opts: Options, params, events: Events) -> Result:
    """A backend's own factor objects: native, dropin, robust losses, landmarks."""
    from .backends import build_graph, optimize_with

    t = time.perf_counter()
    graph = build_graph(posed, opts.backend, opts.robust, opts.robust_all)
    setup = time.perf_counter() - t
    events.set_up(setup)
    values0 = posed.with_landmarks(start.values)
    res = optimize_with(opts.backend, graph, values0, params, events.iteration, robust=opts.robust is not None)
    return Result(res.final_error, res.initial_error, res.iterations, res.converged, res.seconds,
                  errors=list(res.errors), timings={"setup": setup, "iterations": res.seconds},
                  factors=int(graph.size()), _values=res.values, _start=values0,
                  _marginals_of=lambda: _marginals(graph, res.values))


def _optimize_gnc(posed: PoseGraph, start, opts: Options, params, events: Events) -> Result:
    """The false-closure pipeline: on the arrays for the batch backend, on the backend's factor
    objects otherwise (and where the graph has landmarks)."""
    from .robust.pipeline import reject_and_optimize

    t = time.perf_counter()
    if opts.backend == "batch" and posed.landmarks is None:
        from .batch.graph import Problem
        from .robust.solvers import ArraySolver

        solver: Any = ArraySolver(posed, start.poses, params, events.gnc_iteration)
        size = posed.edge_count + len(posed.prior_keys)
        initial_error = float(Problem.from_pose_graph(posed, start.poses).error())
        values0 = None
    else:
        from .backends import build_graph
        from .robust.solvers import GraphSolver

        graph = build_graph(posed, opts.backend)
        values0 = posed.with_landmarks(start.values)
        solver = GraphSolver(posed, graph, values0, opts.backend, params, events.gnc_iteration)
        size = int(graph.size())
        initial_error = float(graph.error(values0))
    setup = time.perf_counter() - t
    events.set_up(setup)
    assert opts.gnc is not None
    out = reject_and_optimize(posed, solver, size, loss=opts.gnc, consistency=opts.consistency,
                              lm_params=params, gtsam_semantics=opts.backend == "native")
    res = out.gnc
    result = Result(float(res.cost), initial_error, int(res.iterations), out.converged, out.seconds,
                    errors=[initial_error, float(res.cost)], timings={"setup": setup, "iterations": out.seconds},
                    outliers=out.outliers, rejected_by=out.rejected_by, factors=size,
                    robust_status={"status": out.status, "reasons": list(out.reasons)})
    inliers = posed.with_edges(np.setdiff1d(np.arange(posed.edge_count), out.outliers))
    if values0 is None:
        result._keys, result._group = np.asarray(posed.keys, dtype=np.int64), posed.group
        result._poses = poses = solver.poses(res.values)
        result._start = lambda: posed.with_landmarks(start.values)
        result._marginals_of = lambda: _pose_graph_marginals(inliers, poses)
    else:
        from .backends import build_graph

        result._values, result._start = res.values, values0
        result._marginals_of = lambda: _marginals(build_graph(inliers, opts.backend), res.values)
    return result


def _marginals(graph, values) -> "Marginals":
    from .batch.marginals import Marginals

    return Marginals(graph, values)


def _pose_graph_marginals(pose_graph: PoseGraph, poses: np.ndarray) -> "Marginals":
    from .batch.marginals import Marginals

    return Marginals.of_pose_graph(pose_graph, poses)


# --------------------------------------------------------------------------- #
# Online
# --------------------------------------------------------------------------- #

#: GTSAM's ``ISAM2Params`` defaults: ``relinearizeThreshold``, ``relinearizeSkip``.
RELINEARIZE_THRESHOLD = 0.1
RELINEARIZE_SKIP = 10


def replay_options(*, backend: str = DEFAULT_BACKEND, relinearize_threshold: float = RELINEARIZE_THRESHOLD,
                   relinearize_skip: int = RELINEARIZE_SKIP, gnc: str | None = None) -> None:
    """The options of :func:`replay`, checked: a one-line :class:`~lie_factors.errors.InputError`
    for anything wrong (as :func:`options` for :func:`optimize`)."""
    if backend not in BACKENDS:
        raise InputError(f"unknown backend {backend!r} (choose from {', '.join(BACKENDS)})")
    if gnc is not None:
        from .robust.online import check_loss

        check_loss(gnc, "gnc")
        if backend != "batch":
            raise InputError(f"replay: gnc runs on the batch backend only, not {backend!r}")
    if isinstance(relinearize_threshold, bool) or not isinstance(relinearize_threshold, (int, float)) \
            or not 0 < relinearize_threshold < float("inf"):
        raise InputError(f"relinearize_threshold: must be a finite number > 0, got {relinearize_threshold!r}")
    if isinstance(relinearize_skip, bool) or not isinstance(relinearize_skip, (int, np.integer)) \
            or not 1 <= relinearize_skip <= MAX_ITERATIONS:
        raise InputError(f"relinearize_skip: must be an integer from 1 to {MAX_ITERATIONS}, got {relinearize_skip!r}")


def replay(pose_graph: PoseGraph, *, backend: str = DEFAULT_BACKEND,
           relinearize_threshold: float = RELINEARIZE_THRESHOLD, relinearize_skip: int = RELINEARIZE_SKIP,
           gnc: str | None = None, events: Events | None = None) -> "ReplayResult":
    """Replay a pose graph online, as a robot would have built it; returns a
    :class:`~lie_factors.result.ReplayResult` (``lie-factors posegraph FILE --incremental``).

    Poses come in key order, one per update, each factor in the update of the last of its
    poses; a new pose starts at the previous pose's estimate composed with the odometry edge
    between them. ``backend``: ``batch`` (default: the incremental smoother,
    :class:`lie_factors.Smoother`, on the arrays), ``dropin`` (our factors in
    :class:`lie_factors.optimizers.ISAM2`) or ``native`` (GTSAM's factors in ``gtsam.ISAM2``);
    ``relinearize_threshold`` and ``relinearize_skip``: ISAM2's. ``gnc="tls"``: the loop closures
    are candidate outliers, tested as they arrive and tested again as the map grows
    (:mod:`lie_factors.robust.online`); ``result.outliers`` are the edges the smoother does not
    hold at the end. ``events.replayed`` hears the progress every thousand updates.
    """
    replay_options(backend=backend, relinearize_threshold=relinearize_threshold, relinearize_skip=relinearize_skip,
                   gnc=gnc)
    if not isinstance(pose_graph, PoseGraph):
        raise InputError(f"replay: expected a PoseGraph, got {type(pose_graph).__name__}")
    from .incremental.replay import replay as run

    events = events if events is not None else Events()
    result = run(pose_graph, backend=backend, relinearize_threshold=float(relinearize_threshold),
                 relinearize_skip=int(relinearize_skip), progress=events.replayed, gnc=gnc)
    result._marginals_of = lambda: _pose_graph_marginals(pose_graph.with_first_prior(), result.poses)
    return result
