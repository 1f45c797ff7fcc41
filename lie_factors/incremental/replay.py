"""Online replay of a pose graph: :func:`replay` adds it to an incremental smoother as a robot would have built it.

The rules of the replay (:func:`schedule`):

- Poses come in id order, one per update. Each factor is added in the update
  where the last of its poses (in that order) appears: an edge between poses
  i < j in update j, the prior on the first pose in the first update, a
  landmark measurement in the update of its pose.
- The new pose's initial value is the current estimate of the previous pose
  composed with the odometry edge between them (either direction), or the
  graph's start value where there is no such edge. A landmark enters with its
  first measurement: at its vertex if it has one, else placed from that
  measurement at its pose's initial value.

Backends: ``batch`` runs the incremental smoother
(:class:`lie_factors.incremental.Smoother`) on arrays, with no factor object
(:func:`replay_arrays`), or on the graph's factors where it has landmarks;
``dropin`` puts lie_factors' factors in :class:`lie_factors.optimizers.ISAM2`
(GTSAM's ISAM2 whose callbacks receive its own linearization point instead of
a copy of it); ``native`` puts GTSAM's own factors in ``gtsam.ISAM2``.
:func:`replay_graph` replays any factor graph through any ISAM2-like object
(the benchmark runs lie_factors' factors in plain ``gtsam.ISAM2`` with it).

Each update's time is that of ``update`` plus reading back the new pose's
estimate (what the next pose's initial value needs). The result is a
:class:`lie_factors.result.ReplayResult`: ``error`` is the whole graph's error
(the backend's factors) at the final estimate, ``initial_error`` at the values
the poses and landmarks entered with.

Only ``batch`` loads numba (``native`` on a file that the reader takes without
numba never does): the smoother and lie_factors' factors are imported when used.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Callable

import gtsam
import numpy as np

from ..errors import InputError
from ..interop import to_gtsam
from ..kernels import registry
from ..posegraph.graph import PoseGraph
from ..posegraph.landmarks import is_landmark_key
from ..result import ReplayResult
from ..util.timing import Stopwatch, warm_up_factors

#: The backends of a replay.
BACKENDS = ("batch", "dropin", "native")
#: GTSAM's ISAM2Params defaults (relinearizeThreshold, relinearizeSkip).
DEFAULT_RELINEARIZE_THRESHOLD = 0.1
DEFAULT_RELINEARIZE_SKIP = 10
#: ``progress`` is called every this many updates.
PROGRESS_EVERY = 1000


@dataclass
class Step:
    """One update: the pose it adds, the graph indices of its factors, the landmarks it adds,
    and its odometry edge (edge index, True if stored previous → new) or None."""

    key: int
    factors: list[int]
    landmarks: list[int] = field(default_factory=list)
    odometry: tuple[int, bool] | None = None


def schedule(pose_graph: PoseGraph, factors) -> list[Step]:
    """The updates of the replay of ``factors``: a graph built by :func:`factor_graph` from
    ``pose_graph`` (edge k is factor k, then the prior, then the landmark measurements), or the
    keys of those factors in that order.  Raises :class:`InputError` for a pose that no factor
    ties to an earlier one."""
    if isinstance(factors, gtsam.NonlinearFactorGraph):
        factors = [[int(key) for key in factors.at(k).keys()] for k in range(factors.size())]
    order = pose_graph.keys.tolist()
    position = {k: n for n, k in enumerate(order)}
    steps = [Step(k, []) for k in order]
    seen_landmarks: set[int] = set()
    for k, keys in enumerate(factors):
        poses = [key for key in keys if not is_landmark_key(key)]
        if not poses:
            raise InputError(f"factor {k} has no pose: it cannot be placed in the replay")
        step = steps[max(position[key] for key in poses)]
        step.factors.append(k)
        for key in keys:
            if is_landmark_key(key) and key not in seen_landmarks:
                seen_landmarks.add(key)
                step.landmarks.append(key)
    for k, (i, j) in enumerate(pose_graph.edge_keys.tolist()):
        a, b = position[i], position[j]
        if abs(a - b) == 1:
            step = steps[max(a, b)]
            if step.odometry is None:
                step.odometry = (k, a < b)
    for step in steps:
        if not step.factors:
            raise InputError(
                f"pose {step.key} has no edge to an earlier pose (in id order) and no prior: "
                "it cannot be added online (--incremental needs every pose constrained when it appears)")
    return steps


def isam2_params(relinearize_threshold: float = DEFAULT_RELINEARIZE_THRESHOLD,
                 relinearize_skip: int = DEFAULT_RELINEARIZE_SKIP) -> gtsam.ISAM2Params:
    """GTSAM's ISAM2Params with these two set (the rest at GTSAM's defaults)."""
    params = gtsam.ISAM2Params()
    params.setRelinearizeThreshold(float(relinearize_threshold))
    params.relinearizeSkip = int(relinearize_skip)
    return params


def factor_graph(pose_graph: PoseGraph, backend: str) -> gtsam.NonlinearFactorGraph:
    """The graph ``backend`` replays: the edges, the prior on the first pose, the landmark
    measurements, with GTSAM's factor classes (``native``) or lie_factors' (the others)."""
    from .. import factors

    return pose_graph.with_first_prior().factor_graph(gtsam if backend == "native" else factors)


def new_isam(backend: str, relinearize_threshold: float = DEFAULT_RELINEARIZE_THRESHOLD,
             relinearize_skip: int = DEFAULT_RELINEARIZE_SKIP, robust: str | None = None):
    """The incremental smoother of ``backend`` with ISAM2's two parameters: the smoother for
    ``batch`` (``robust``: its online rejection), the drop-in :class:`lie_factors.optimizers.ISAM2`
    for ``dropin``, ``gtsam.ISAM2`` for ``native``."""
    if backend == "batch":
        from .params import SmootherParams
        from .smoother import Smoother

        return Smoother(SmootherParams(relinearizeThreshold=float(relinearize_threshold),
                                       relinearizeSkip=int(relinearize_skip)), robust=robust)
    if backend == "dropin":
        from ..optimizers.isam2 import ISAM2

        return ISAM2(isam2_params(relinearize_threshold, relinearize_skip))
    return gtsam.ISAM2(isam2_params(relinearize_threshold, relinearize_skip))


def replay(pose_graph: PoseGraph, *, backend: str = "batch",
           relinearize_threshold: float = DEFAULT_RELINEARIZE_THRESHOLD,
           relinearize_skip: int = DEFAULT_RELINEARIZE_SKIP,
           progress: Callable[[int, int, float], None] | None = None,
           max_seconds: float | None = None, gnc: str | None = None) -> ReplayResult:
    """Replay ``pose_graph`` online (module docstring) through ``backend``'s smoother.

    ``relinearize_threshold``, ``relinearize_skip``: ISAM2's ``relinearizeThreshold`` and
    ``relinearizeSkip``.  ``progress(done, total, seconds)`` is called every
    :data:`PROGRESS_EVERY` updates.  ``max_seconds``: stop after the update that passes this
    many seconds; ``updates`` then counts the updates done, ``converged`` is False and the
    errors are NaN.  ``gnc``: ``"tls"`` rejects false loop closures as they arrive
    (:mod:`lie_factors.robust.online`; the ``batch`` backend on a graph without landmarks);
    the result's ``outliers`` are then the edges the smoother does not hold at the end, and
    ``error`` the error of the edges it holds.  Raises :class:`InputError` for an unknown
    backend, bad parameters, a pose that cannot be added online, or an update that fails
    (naming the update and its pose).
    """
    if backend not in BACKENDS:
        raise InputError(f"unknown backend {backend!r} for a replay (choose from {', '.join(BACKENDS)})")
    if gnc is not None:
        from ..robust.online import check_loss

        check_loss(gnc, "gnc")
        if backend != "batch" or pose_graph.landmarks is not None:
            raise InputError("an online rejection of loop closures runs on the batch backend, on a pose "
                             "graph without landmarks")
        closures = len(pose_graph.loop_closures())
        if not closures or closures == len(pose_graph.edge_keys):
            raise InputError("an online rejection needs odometry (edges between consecutive ids) and loop "
                             "closures (the other edges); this graph has "
                             + ("no loop closure" if not closures else "no odometry"))
    if not (math.isfinite(relinearize_threshold) and relinearize_threshold >= 0):
        raise InputError(f"relinearize_threshold must be finite and >= 0, got {relinearize_threshold}")
    if int(relinearize_skip) < 1:
        raise InputError(f"relinearize_skip must be >= 1, got {relinearize_skip}")
    isam = new_isam(backend, relinearize_threshold, relinearize_skip, gnc)
    if backend == "batch" and pose_graph.landmarks is None:
        return replay_arrays(pose_graph, isam, progress=progress, max_seconds=max_seconds, gnc=gnc)
    return replay_graph(pose_graph, factor_graph(pose_graph, backend), isam, backend=backend, progress=progress,
                        max_seconds=max_seconds)


def _landmark_initial(pose_graph: PoseGraph, f, key: int, poses: gtsam.Values):
    """A landmark's initial value: its vertex, else where its measurement ``f`` puts it from its
    pose's initial value (``poses``)."""
    lm = pose_graph.landmarks
    assert lm is not None  # only a landmark measurement asks
    if key in lm.with_vertex:
        return lm.vertices.atPoint3(key) if pose_graph.is3d else lm.vertices.atPoint2(key)
    return lm.place(f, poses)


def _first_sentence(exc: Exception) -> str:
    """GTSAM's message up to its first full stop (the indeterminate-system message names the
    variable on its second line)."""
    lines = [line.strip() for line in str(exc).strip().splitlines() if line.strip()]
    text = " ".join(lines[:2]) if len(lines) > 1 and not lines[0].endswith(".") else lines[0]
    if "Indeterminate" in text:
        text += (" (ISAM2 solves without damping: a variable is under-constrained when it appears, "
                 "or the system is too poorly conditioned)")
    return text


def _stop_after(n: int, total: int, clock: Stopwatch, progress, max_seconds: float | None) -> bool:
    """After update ``n`` (0-based) of ``total``: the progress call every :data:`PROGRESS_EVERY`
    updates, and whether ``max_seconds`` have passed with updates left."""
    if progress is not None and (n + 1) % PROGRESS_EVERY == 0:
        progress(n + 1, total, clock.seconds())
    return max_seconds is not None and n + 1 < total and clock.seconds() > max_seconds


def _new_values(pose_graph: PoseGraph, graph, step: Step, previous) -> gtsam.Values:
    """The values update ``step`` inserts: its pose (the previous pose's estimate composed with
    the odometry, else the start value) and the landmarks it adds."""
    group = pose_graph.group
    if step.odometry is not None and previous is not None:
        k, forward = step.odometry
        measured = to_gtsam(group, pose_graph.measured[k])
        guess = previous.compose(measured if forward else measured.inverse())
    else:
        guess = getattr(pose_graph.initial, f"at{group}")(step.key)
    new_theta = gtsam.Values()
    new_theta.insert(step.key, guess)
    for key in step.landmarks:
        f = next(graph.at(i) for i in step.factors if key in graph.at(i).keys())
        new_theta.insert(key, _landmark_initial(pose_graph, f, key, new_theta))
    return new_theta


def _figures(times: np.ndarray, total: int, seconds: float) -> dict:
    """The fields of a :class:`ReplayResult` its update times give."""
    done = len(times)
    return dict(iterations=done, converged=done == total, seconds=seconds, updates=done,
                update_seconds=float(times.sum()), update_p50=float(np.percentile(times, 50)),
                update_p99=float(np.percentile(times, 99)), times=times)


def replay_graph(pose_graph: PoseGraph, graph: gtsam.NonlinearFactorGraph, isam, *, backend: str,
                 progress: Callable[[int, int, float], None] | None = None,
                 max_seconds: float | None = None) -> ReplayResult:
    """Replay the factors of ``graph`` (built by :func:`factor_graph` from ``pose_graph``, or
    any graph in its order) through ``isam``, an object with ISAM2's ``update`` and
    ``calculateEstimate<Group>``.  ``backend`` is what the result reports; its errors read
    "update" for ``batch`` (the smoother), "ISAM2 update" otherwise.  ``progress`` and
    ``max_seconds``: as for :func:`replay`."""
    steps = schedule(pose_graph, graph)
    estimate = getattr(type(isam), f"calculateEstimate{pose_graph.group}")
    batches = []
    for step in steps:
        g = gtsam.NonlinearFactorGraph()
        for k in step.factors:
            g.add(graph.at(k))
        batches.append(g)
    warm_up_factors()  # compile before the clock starts
    relinearized = 0
    start = gtsam.Values()
    times = np.empty(len(steps))
    previous = None
    clock = Stopwatch()
    for n, (step, new_factors) in enumerate(zip(steps, batches)):
        new_theta = _new_values(pose_graph, graph, step, previous)
        start.insert(new_theta)
        t0 = time.perf_counter()
        try:
            result = isam.update(new_factors, new_theta)
            previous = estimate(isam, step.key)
        except (RuntimeError, ValueError) as exc:
            what = "update" if backend == "batch" else "ISAM2 update"
            raise InputError(f"{what} {n + 1} (pose {step.key}) failed: {_first_sentence(exc)}") from None
        times[n] = time.perf_counter() - t0
        relinearized += int(result.getVariablesRelinearized())
        if _stop_after(n, len(steps), clock, progress, max_seconds):
            times = times[:n + 1]
            break
    seconds = clock.seconds()
    values = isam.calculateEstimate()
    complete = len(times) == len(steps)
    return ReplayResult(error=float(graph.error(values)) if complete else math.nan,
                        initial_error=float(graph.error(start)) if complete else math.nan,
                        **_figures(times, len(steps), seconds), relinearizations=relinearized,
                        reorderings=getattr(isam, "reorderings", None), factors=int(graph.size()),
                        backend=backend, pose_graph=pose_graph, _values=values, _start=start)


def replay_arrays(pose_graph: PoseGraph, smoother=None, *, progress: Callable[[int, int, float], None] | None = None,
                  max_seconds: float | None = None, gnc: str | None = None) -> ReplayResult:
    """The replay of a pose graph (no landmarks) through the smoother on arrays: the same updates,
    initial values and figures as :func:`replay_graph`, and no factor object at all.
    ``smoother``: a :class:`~lie_factors.incremental.Smoother` (default: ISAM2's parameters);
    ``gnc``: as for :func:`replay` (checked there; the smoother given is then robust)."""
    from ..batch.graph import Problem
    from ..interop import values_from_matrices
    from .factor_arrays import FactorArrays
    from .smoother import Smoother

    pg = pose_graph.with_first_prior()
    E = len(pg.edge_keys)
    fa = FactorArrays(pg.group, pg.edge_keys, pg.measured, pg.information, pg.prior_keys, pg.prior_measured,
                      pg.prior_information)
    steps = schedule(pose_graph, pg.edge_keys.tolist() + [[k] for k in pg.prior_keys.tolist()])
    edges = [np.array([k for k in s.factors if k < E], dtype=np.int64) for s in steps]
    priors = [np.array([k - E for k in s.factors if k >= E], dtype=np.int64) for s in steps]
    if gnc is not None:
        from ..robust.online import robust_update
    warm_up_smoother(fa.group)  # compile before the clock starts
    smoother = Smoother(robust=gnc) if smoother is None else smoother
    start = np.empty((len(steps), fa.spec.mat, fa.spec.mat))
    file_poses = pose_graph.start_poses
    times = np.empty(len(steps))
    previous = None
    clock = Stopwatch()
    for n, step in enumerate(steps):
        if step.odometry is not None and previous is not None:
            k, forward = step.odometry
            guess = previous @ (pg.measured[k] if forward else fa.Minv[k])
        else:
            guess = file_poses[n]
        start[n] = guess
        t0 = time.perf_counter()
        try:
            if gnc is None:
                smoother.update_prepared(fa, [step.key], guess[None], edges[n], priors[n])
            else:
                robust_update(smoother, fa, [step.key], guess[None], None, edges[n], priors[n])
            previous = smoother.estimate_matrix(step.key)
        except ValueError as exc:
            raise InputError(f"update {n + 1} (pose {step.key}) failed: {str(exc).strip()}") from None
        times[n] = time.perf_counter() - t0
        if _stop_after(n, len(steps), clock, progress, max_seconds):
            times = times[:n + 1]
            break
    done = len(times)
    rejection = smoother.rejection
    if rejection is not None and done == len(steps):
        rejection.settle(smoother)  # the final state: every decision tested at the end
    seconds = clock.seconds()
    keys = pg.keys[:done]
    X = smoother.estimate_matrices(keys)
    complete = done == len(steps)
    robust = {}
    held = pg
    if rejection is not None:
        out = np.sort(np.array([rejection.source[c][1] for c in rejection.outliers().tolist()], dtype=np.int64))
        held = pg.with_edges(np.setdiff1d(np.arange(E), out))
        robust = dict(gnc=gnc, outliers=out, rejected_by={int(e): "online" for e in out.tolist()},
                      robust_status=rejection.status())
    return ReplayResult(error=float(Problem.from_pose_graph(held, X).error()) if complete else math.nan,
                        initial_error=float(Problem.from_pose_graph(held, start).error()) if complete else math.nan,
                        **_figures(times, len(steps), seconds), relinearizations=smoother.relinearizations,
                        reorderings=smoother.reorderings, factors=E + len(pg.prior_keys), backend="batch",
                        pose_graph=pose_graph, _keys=keys, _poses=X, _group=pg.group,
                        _start=lambda: values_from_matrices(pg.group, keys, start[:done]), **robust)


def warm_up_smoother(group: str) -> None:
    """Compile (or load) every kernel a replay on ``group`` runs, on a three-pose problem."""
    from .params import SmootherParams
    from .smoother import Smoother

    info = registry.group(group)
    I = np.eye(info.mat)  # noqa: E741 (the identity)
    s = Smoother(SmootherParams(relinearizeSkip=2, relinearizeThreshold=0.0))  # every other update relinearizes
    s.update_arrays(group, [0, 1], np.stack([I, I]), [[0, 1]], I[None], np.eye(info.dim)[None], [0], I[None],
                    np.eye(info.dim)[None])
    s.update_arrays(group, [2], I[None], [[1, 2], [0, 2]], np.stack([I, I]), np.stack([np.eye(info.dim)] * 2))
    s.estimate_matrix(2)
    for k in range(3, 8):  # a chain, then a closure whose set is ordered by minimum degree
        s.update_arrays(group, [k], I[None], [[k - 1, k]], I[None], np.eye(info.dim)[None])
    s.update_arrays(group, [8], I[None], [[7, 8], [2, 8]], np.stack([I, I]), np.stack([np.eye(info.dim)] * 2))
    s.estimate_matrix(8)
    # a closure whose set GTSAM's CCOLAMD orders (its first call costs milliseconds), and a
    # pool compaction: both come only after many updates of a replay
    s.bf.max_small = 3
    s.update_arrays(group, [9], I[None], [[8, 9], [3, 9]], np.stack([I, I]), np.stack([np.eye(info.dim)] * 2))
    s.bf._compact()
    s.estimate_matrix(9)
    # the replay's final errors: the batch problem of the graph at the estimate
    from ..batch.graph import Problem
    from ..posegraph.graph import PoseGraph

    tiny = PoseGraph(group, np.arange(2), np.array([[0, 1]]), I[None], np.eye(info.dim)[None], None, None)
    Problem.from_pose_graph(tiny, np.stack([I, I])).error()
