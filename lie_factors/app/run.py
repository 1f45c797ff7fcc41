"""A pose-graph run, from the command line's arguments to the output files: :class:`PoseGraphRun`.

``lie-factors posegraph`` is one; :func:`run` is one without outputs.  Step by step:

1. check the invocation (backend, robust loss, output paths) before any work;
2. load the file (:func:`lie_factors.g2o.read_pose_graph`: checked, its pose graph on arrays);
3. initialize (:func:`lie_factors.initialization.initialize` on the pose graph and a
   prior on its first pose): ours on the arrays for the ``batch`` backend, GTSAM's own
   initializers for the others (so ``--backend native`` never loads numba);
4. optimize: ``batch`` on a plain pose graph builds
   :meth:`lie_factors.batch.Problem.from_pose_graph` (no factor object); otherwise the
   backend's graph (:func:`lie_factors.backends.build_graph`) and its LM
   (:mod:`lie_factors.backends`), or GNC;
5. write the output files (g2o, png), each atomically.

``lie-factors posegraph --incremental`` replays the file through ISAM2 instead of
steps 3–4 (:class:`lie_factors.app.incremental.IncrementalRun`, the same run otherwise).
"""

from __future__ import annotations

import time
from typing import Callable

import gtsam
import numpy as np

from ..errors import InputError, first_line
from ..initialization import Initialization, initialize
from ..lm import IterationInfo, OptimizeResult
from ..util.timing import Stopwatch
from ..backends import optimize_batch_robust, backend_name, build_graph, get_backend, load_factors, optimize
from ..g2o import read_pose_graph
from ..posegraph.graph import PoseGraph
from .record import TIMING_KEYS, Record, RunRecord

#: --robust LOSS names the command accepts (a subset of lie_factors.robust.losses.LOSSES)
CLI_LOSSES = ("huber", "cauchy", "tukey", "gm", "dcs")

#: Factors × (tangent dimension)² below which the default path runs the batch loops on one
#: numba thread: their fork/join costs more than it saves there.  Whole command, 2 runs each,
#: load 2–4 (docs/benchmarks.md): 1 thread made the iterations faster on intel
#: (2.5k SE(2) factors, 0.05–0.08 vs 0.22–0.26 s), sphere2500 (5k SE(3)), city10000 (21k SE(2):
#: 1.9·10⁵) and torus3D (9k SE(3): 3.3·10⁵, 0.28 vs 0.38–0.41 s); 2 threads were faster from
#: the 20k-pose helix (22k SE(3): 7.9·10⁵, 0.33 vs 0.37 s) and equal at 100k.
PARALLEL_MIN_WORK = 500_000


def parse_robust(robust, robust_all: bool = False, gnc: str | None = None):
    """The run's robust loss: None, a ``RobustLoss`` as given, or one parsed from ``LOSS[:K]``.

    Raises :class:`InputError` with a one-line reason (unknown loss or GNC
    loss, bad parameter, ``robust_all`` without a loss, both robust and GNC).
    """
    if gnc is not None and gnc not in ("tls", "gm"):
        raise InputError(f"--gnc: unknown loss {gnc!r} (choose from tls, gm)")
    if robust is None:
        if robust_all:
            raise InputError("--robust-all needs --robust LOSS")
        return None
    if isinstance(robust, str):
        name = robust.partition(":")[0].strip().lower()
        if name not in CLI_LOSSES:
            raise InputError(f"--robust: unknown loss {name!r} (choose from {', '.join(CLI_LOSSES)})")
        from lie_factors.robust.losses import parse_loss  # numba: only runs with a loss load it

        try:
            robust = parse_loss(robust)
        except ValueError as exc:
            raise InputError(f"--robust: {exc}") from None
    if gnc:
        raise InputError("--robust and --gnc are alternatives (GNC replaces the loss); give one")
    return robust


class RunEvents:
    """What a :class:`PoseGraphRun` reports while it runs (the CLI prints them); all no-ops here."""

    def loaded(self, run: "PoseGraphRun") -> None:
        """The file is read and checked (``run.pg``)."""

    def started(self, start: Initialization) -> None:
        """The initial values are chosen; the optimizer is set up next."""

    def set_up(self, run: "PoseGraphRun") -> None:
        """The optimizer is set up (graph or problem, linear system, symbolic analysis:
        ``run.timings["setup"]``); its iterations come next."""

    def iteration(self, info: IterationInfo) -> None:
        """One LM iteration done."""

    def gnc_iteration(self, it: int, lam: float, cost: float, lm_iterations: int) -> None:
        """One GNC outer iteration done."""

    def replayed(self, done: int, total: int, seconds: float) -> None:
        """An incremental replay has done ``done`` of ``total`` updates."""

    def optimized(self, run: "PoseGraphRun") -> None:
        """The optimization is done (``run.record``, ``run.result``); the files come next."""

    def wrote(self, path: str) -> None:
        """An output file (``output`` or ``plot``) is complete."""


class PoseGraphRun:
    """One pose-graph run from reading to writing: ``lie-factors posegraph`` is one of these.

    :meth:`execute` checks the invocation (backend, loss, output paths)
    before any work, then reads the file (:func:`~lie_factors.g2o.read_pose_graph`),
    initializes (:func:`lie_factors.initialization.initialize`), optimizes with
    the backend, and writes ``output`` (g2o) and ``plot`` (png); ``events``
    (:class:`RunEvents`) hears each step.  The default path — ``batch`` on a
    pose graph without robust loss or GNC — never builds a factor object: the
    file's arrays become a :meth:`lie_factors.batch.Problem.from_pose_graph`.

    After :meth:`execute`: ``record`` (:class:`~lie_factors.app.record.RunRecord`),
    ``result`` (:class:`OptimizeResult`; ``result.values`` is built on first use
    by :meth:`values` when ``lazy_values``), ``pg`` (the
    :class:`~lie_factors.posegraph.graph.PoseGraph`), ``start``, and ``timings``
    (seconds: ``imports`` of the backend's modules, ``read`` (resolve, check,
    arrays), ``init``, ``setup`` (graph or problem, linear system, symbolic
    analysis), ``iterations``, ``write``).
    """

    def __init__(self, dataset, backend: str = "batch", max_iterations: int = 100, init: str = "auto",
                 robust=None, robust_all: bool = False, gnc: str | None = None,
                 output: str | None = None, plot: str | None = None, events: RunEvents | None = None,
                 lazy_values: bool = False, consistency: bool = True):
        self.consistency = consistency
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
        self.record: Record | None = None
        self.result: OptimizeResult | None = None
        self.start: Initialization | None = None
        self._start_values = None  # the start with the landmarks, as gtsam.Values
        self._opt = None  # the batch optimizer of an array run (values() on demand)

    # ------------------------------------------------------------------ steps
    def check(self) -> None:
        """Everything that can be wrong with the invocation, before the (possibly long) work."""
        self.backend = backend_name(self.backend)
        self.robust = parse_robust(self.robust_text, self.robust_all, self.gnc)
        self._checked = True
        for path in (self.output, self.plot):
            if path:
                from ..util.atomic import check_writable

                check_writable(path)

    @property
    def uses_arrays(self) -> bool:
        """The default path: batch backend, plain LM, a pose graph without landmarks."""
        return (self.backend == "batch" and self.robust is None and self.gnc is None
                and self.pg is not None and self.pg.landmarks is None)

    def load(self) -> PoseGraph:
        if not self._checked:
            self.check()
        t = time.perf_counter()
        if self.pg is None:
            self.pg = read_pose_graph(self.dataset)
        self.timings["read"] = time.perf_counter() - t
        if self.gnc is not None and self.pg.loop_closures().size == 0:
            raise InputError(f"{self.pg.name}: --gnc needs loop closures (edges between "
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
        """The initial poses (every backend starts from the same ones; see :func:`run`).

        The initializers take the pose graph and the prior; the landmarks are
        placed afterwards.  They run before the backend's graph exists: the
        chordal relaxation's transient memory then does not stack on numba's
        (torus3D, batch: peak RSS 394 → 343 MiB; native 253).
        """
        pg, t = self.pg, time.perf_counter()
        if pg.edge_count == 0 and self.init in ("auto", "file"):
            # Landmark measurements only (e.g. one pose seeing one landmark): no pose
            # graph for an initializer to relax; the file's values are the start.
            self.start = Initialization("file", 0.0, poses=pg.start_poses, keys=pg.keys, group=pg.group)
        else:
            # Robust and GNC runs doubt the loop closures: auto starts from the odometry and the prior.
            doubt = self.gnc is not None or self.robust is not None
            inliers = np.setdiff1d(np.arange(pg.edge_count), pg.loop_closures()) if doubt else None
            self.start = initialize(pg.with_first_prior(), self.init, inliers=inliers,
                                    engine="lie_factors" if self.backend == "batch" else "gtsam")
        self._start_values = None
        if not self.lazy_values:  # a Python caller gets gtsam.Values at once
            self.start_values()
        self.timings["init"] = time.perf_counter() - t
        self.events.started(self.start)
        return self.start

    def optimize(self) -> OptimizeResult:
        pg, backend = self.pg, self.backend
        if self.uses_arrays:
            return self._optimize_arrays()
        t = time.perf_counter()
        # GNC weighs the plain graph itself; a robust run wraps the loop closures' noise models.
        loss = self.robust if self.gnc is None else None
        graph = build_graph(pg, backend, loss, self.robust_all)
        self.timings["setup"] = time.perf_counter() - t
        self.events.set_up(self)
        start = self.start_values()
        if self.gnc is not None:
            self.record, self.result = _run_gnc(pg, graph, self.start, start, backend, self.max_iterations,
                                                self.gnc, self.events.gnc_iteration, self.consistency)
            self.timings["iterations"] = self.result.seconds
            return self.result
        opt = get_backend(backend).optimize or optimize
        if self.robust is not None and backend == "batch":
            opt = optimize_batch_robust
        result = opt(graph, start, max_iterations=self.max_iterations, progress=self.events.iteration)
        result.start = start
        self.timings["iterations"] = result.seconds
        self.result = result
        self.record = _record(pg, backend, graph.size(), self.start, result,
                              robust=None if self.robust is None
                              else str(self.robust) + ("+all" if self.robust_all else ""),
                              init_inliers_only=None if self.robust is None else self.start.inliers_only)
        return result

    def _optimize_arrays(self) -> OptimizeResult:
        from lie_factors.batch import BatchLevenbergMarquardt, Problem

        pg = self.pg
        # Compilation of the kernels (first run on a machine) is not optimization time.
        clock = Stopwatch()
        params = gtsam.LevenbergMarquardtParams()
        params.setMaxIterations(int(self.max_iterations))
        import numba

        threads = numba.get_num_threads()
        try:
            problem = Problem.from_pose_graph(pg.with_first_prior(), self.start.poses)
            if problem.graph_size * problem.blocks[pg.group].spec.dim ** 2 < PARALLEL_MIN_WORK:
                numba.set_num_threads(1)
            self._opt = opt = BatchLevenbergMarquardt(problem, None, params)
            self.timings["setup"] = clock.seconds()
            self.events.set_up(self)
            result = opt.optimize(self.events.iteration, values=not self.lazy_values)
        except InputError as exc:
            raise InputError(f"batch backend: {exc}") from None
        except RuntimeError as exc:
            raise InputError(f"optimization failed: {first_line(exc)}") from None
        finally:
            numba.set_num_threads(threads)
        result.seconds = clock.seconds()
        self.timings["iterations"] = result.seconds - self.timings["setup"]
        result.start = None if self.lazy_values else self.start_values()
        self.result = result
        self.record = _record(pg, self.backend, problem.graph_size, self.start, result)
        return result

    def values(self) -> gtsam.Values:
        """The optimized values (built now if the run kept them as arrays)."""
        if self.result.values is None:
            self.result.values = self._opt.values()
        return self.result.values

    def start_values(self) -> gtsam.Values:
        """The values the run started from, landmarks included (built on first use)."""
        if self._start_values is None:
            self._start_values = self.pg.with_landmarks(self.start.values)
        if self.result is not None and self.result.start is None:
            self.result.start = self._start_values
        return self._start_values

    def write(self) -> None:
        """Write ``output`` (the optimized graph, g2o) and ``plot`` (png), each atomically."""
        from ..util import atomic
        from ..g2o import write_g2o
        from .plotting import edge_segments, landmark_positions, positions

        pg = self.pg
        t = time.perf_counter()
        if self.output:
            write_g2o(self.output, pg.factor_graph(), self.values())
            self.events.wrote(self.output)
        if self.plot:
            from .plotting import plot_trajectories

            values, begin = self.values(), self.start_values()
            title, start, result, start_points, result_points = self.plot_labels()
            trajectories = {start: positions(begin, pg.is3d, pg.group), result: positions(values, pg.is3d, pg.group)}
            points = ({start_points: landmark_positions(begin, pg.is3d),
                       result_points: landmark_positions(values, pg.is3d)} if pg.landmark_count else None)
            rejected = getattr(self.record, "outliers", None)
            # under --robust/--gnc: the loop closures set aside, drawn between their optimized poses
            segments = ({"rejected loop closures": edge_segments(trajectories[result], pg, rejected)}
                        if rejected else None)
            atomic.replace_atomically(self.plot, lambda tmp: plot_trajectories(
                tmp, trajectories, title, three_d=pg.is3d, points=points, segments=segments), suffix=".png")
            self.events.wrote(self.plot)
        self.timings["write"] = time.perf_counter() - t

    def plot_labels(self) -> tuple[str, str, str, str, str]:
        """The plot's title and the names of the start, the result and their landmarks."""
        return (f"{self.pg.name} ({self.backend})", f"initial ({self.record.init})", "optimized",
                "initial landmarks", "optimized landmarks")

    def execute(self) -> Record:
        """check → load → initialize → optimize → write; returns the record."""
        from ..sparse.cholmod import reuse_factor_memory

        self.check()
        self.load()
        with reuse_factor_memory():  # the initializer's factor memory serves the optimizer's
            self.initialize()
            self.optimize()
        self.events.optimized(self)
        self.write()
        if isinstance(self.record, RunRecord):
            self.record.timings = {k: self.timings.get(k, 0.0) for k in TIMING_KEYS}
        return self.record


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
    """Load (unless given a :class:`~lie_factors.posegraph.graph.PoseGraph`), initialize, optimize with ``backend``.

    ``init``: a method of :func:`lie_factors.initialization.initialize`, run on
    the file's pose graph and the prior (every backend starts from the same
    values, to 1e-9); ``file`` is the file's vertices.  With ``robust`` or
    ``gnc``, ``auto`` builds the start from the odometry edges and the prior
    only (their measurements composed: the loop closures, false ones included,
    are left out; ``start.inliers_only``).  Landmarks keep their file vertex, or
    are placed from their first measurement.  ``on_init`` is called with the
    :class:`~lie_factors.initialization.Initialization` before LM starts.
    ``result.start`` holds the values LM started from.

    ``robust``: a :class:`lie_factors.robust.losses.RobustLoss` (or its text,
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


def _record(pg: PoseGraph, backend: str, factors: int, start: Initialization, result: OptimizeResult,
            **extra) -> RunRecord:
    """The run's :class:`~lie_factors.app.record.RunRecord`: its graph's size, start and
    ``result``'s figures, plus ``extra`` fields."""
    return RunRecord(**Record.of(pg, backend, factors), iterations=result.iterations,
                     initial_error=result.initial_error, final_error=result.final_error,
                     seconds=result.seconds, converged=result.converged, init=start.method,
                     init_seconds=start.seconds, **extra)


def _run_gnc(pg: PoseGraph, graph, start: Initialization, values: gtsam.Values, backend: str,
             max_iterations: int, loss: str, gnc_progress: Callable | None,
             consistency: bool = True) -> tuple[RunRecord, OptimizeResult]:
    """GNC per backend: native = gtsam.GncLMOptimizer; dropin = our outer loop over GTSAM's LM
    with lie_factors factors (GTSAM's GncOptimizer cannot clone CustomFactors); batch = our
    outer loop over the batch solver.  The odometry and the prior are known inliers.  With
    ``consistency``, the loop closures go through the consistency stage first and the final
    χ² check after (:func:`lie_factors.robust.rejection.reject_false_closures`)."""
    from lie_factors.robust import gnc as gncm
    from lie_factors.robust.rejection import reject_false_closures

    known = np.setdiff1d(np.arange(graph.size()), pg.loop_closures())
    lm = gtsam.LevenbergMarquardtParams()
    lm.setMaxIterations(int(max_iterations))
    params = gncm.GncParams(loss=loss, known_inliers=known.tolist(), lm_params=lm,
                            first_solve_known_inliers=consistency and backend != "native")
    Inner = gncm.BatchInner if backend == "batch" else gncm.GtsamInner

    def inner(start, exclude):
        # the batch solver leaves out what weighs 0 throughout (see BatchInner)
        return Inner(graph, start, lm, exclude=exclude) if backend == "batch" else Inner(graph, start, lm)

    def run_gnc(p):
        if backend == "native":
            return gncm.gtsam_gnc(graph, values, p)
        res = gncm.gnc_optimize(inner(values, p.known_outliers), p, gnc_progress)
        if not isinstance(res.values, gtsam.Values):
            res.values = res.values.to_values()
        return res

    scorer = gncm.BatchInner(graph, values, lm) if backend == "batch" else None

    def errors(v):
        if scorer is not None:
            return scorer.factor_errors(scorer.state(v))
        return np.array([graph.at(k).error(v) for k in range(graph.size())])

    def refine(v, weights):
        out = inner(v, np.flatnonzero(weights == 0.0)).optimize(weights)[0]
        return out if isinstance(out, gtsam.Values) else out.to_values()

    def poses(v):
        from lie_factors.interop import matrices_from_values

        return matrices_from_values(v, pg.group, pg.keys)

    try:
        if consistency:
            rejection = reject_false_closures(pg.with_first_prior(), run_gnc, errors, refine, poses, params)
            res, rejected_by = rejection.gnc, rejection.rejected_by
            seconds = rejection.seconds
        else:
            res = run_gnc(params)
            rejected_by, seconds = None, res.seconds
    except RuntimeError as exc:
        raise InputError(f"optimization failed: {first_line(exc)}") from None
    initial_error = float(graph.error(values))
    result = OptimizeResult(res.values, res.iterations, [initial_error, res.cost], [], seconds,
                            res.stop != "maxIterations")
    result.start = values
    if rejected_by is None:
        outliers = [int(k) for k in res.outliers if k < pg.edge_count]
    else:
        outliers = sorted(int(k) for k in rejected_by)
        rejected_by = {str(k): v for k, v in rejected_by.items()}
    record = _record(pg, backend, graph.size(), start, result, gnc=loss, outliers=outliers,
                     rejected_by=rejected_by, init_inliers_only=start.inliers_only)
    return record, result
