"""Online replay of a pose graph through ISAM2 (``lie-factors posegraph FILE --incremental``).

The file is replayed as a robot would have built it:

- Poses come in id order, one per ISAM2 update. Each factor is added in the
  update where the last of its poses (in that order) appears: an edge between
  poses i < j in update j, the prior on the first pose in the first update, a
  landmark measurement in the update of its pose.
- The new pose's initial value is the current estimate of the previous pose
  composed with the odometry edge between them (either direction), or the
  file's value where there is no such edge. A landmark enters with its first
  measurement: at the file's vertex if it has one, else placed from that
  measurement at its pose's initial value.
- Backends: ``native`` puts GTSAM's own factors in ``gtsam.ISAM2``; ``dropin``
  puts lie_factors' factors in :class:`lie_factors.optimizers.ISAM2` (GTSAM's
  ISAM2 whose callbacks receive its own linearization point instead of a copy
  of it); ``batch`` runs the incremental smoother
  (:class:`lie_factors.incremental.Smoother`): on arrays, with no factor object,
  for a pose graph (:func:`replay_arrays`), on the graph's factors where the
  file has landmarks.

Each update's time is that of ``update`` plus reading back the new pose's
estimate (what the next pose's initial value needs): ``update_seconds`` is
their sum, ``update_p50``/``update_p99`` the median and 99th percentile.
``final_error`` is the error of the whole graph (the backend's factors) at the
final estimate.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

import gtsam

from ..errors import InputError
from ..kernels import registry
from ..interop import to_gtsam, values_from_matrices
from ..util.timing import Stopwatch, warm_up_factors
from ..backends import build_graph
from ..posegraph.graph import PoseGraph
from ..posegraph.landmarks import is_landmark_key
from .record import Record
from .run import PoseGraphRun, RunEvents

#: GTSAM's ISAM2Params defaults (relinearizeThreshold, relinearizeSkip).
DEFAULT_RELINEARIZE_THRESHOLD = 0.1
DEFAULT_RELINEARIZE_SKIP = 10
#: A progress line every this many updates.
PROGRESS_EVERY = 1000


@dataclass
class Step:
    """One update: the pose it adds, the graph indices of its factors, the landmarks it adds,
    and its odometry edge (file edge index, True if stored previous → new) or None."""

    key: int
    factors: list[int]
    landmarks: list[int] = field(default_factory=list)
    odometry: tuple[int, bool] | None = None


def schedule(ds: PoseGraph, factors) -> list[Step]:
    """The updates of the replay of ``factors``: a graph built by
    :func:`lie_factors.backends.build_graph` from ``ds`` (file edge k is factor k, then the
    prior, then the landmark measurements), or the keys of those factors in that order."""
    if isinstance(factors, gtsam.NonlinearFactorGraph):
        factors = [[int(key) for key in factors.at(k).keys()] for k in range(factors.size())]
    order = ds.keys.tolist()
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
    for k, (i, j) in enumerate(ds.edge_keys.tolist()):
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


@dataclass
class Replay:
    """What :func:`replay` measured; ``values``: the final estimate, ``start``: each pose's
    (and landmark's) initial value as inserted."""

    updates: int
    update_seconds: float
    update_p50: float
    update_p99: float
    seconds: float
    final_error: float
    values: gtsam.Values
    start: gtsam.Values
    factors: int
    times: np.ndarray
    relinearizations: int | None = None
    reorderings: int | None = None


def isam2_params(relinearize_threshold: float = DEFAULT_RELINEARIZE_THRESHOLD,
                 relinearize_skip: int = DEFAULT_RELINEARIZE_SKIP) -> gtsam.ISAM2Params:
    params = gtsam.ISAM2Params()
    params.setRelinearizeThreshold(float(relinearize_threshold))
    params.relinearizeSkip = int(relinearize_skip)
    return params


def isam2_class(backend: str) -> type:
    """``gtsam.ISAM2`` for the native backend, the drop-in for ``dropin``, the incremental
    smoother (:class:`lie_factors.incremental.Smoother`) for ``batch``."""
    if backend == "native":
        return gtsam.ISAM2
    if backend == "batch":
        from ..incremental import Smoother

        return Smoother
    from ..optimizers.isam2 import ISAM2

    return ISAM2


def _landmark_initial(ds: PoseGraph, f, key: int, poses: gtsam.Values):
    """A landmark's initial value: its file vertex, else where its measurement ``f`` puts it
    from its pose's initial value (``poses``)."""
    lm = ds.landmarks
    if key in lm.with_vertex:
        return lm.vertices.atPoint3(key) if ds.is3d else lm.vertices.atPoint2(key)
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
    """After update ``n`` (0-based) of ``total``: the progress line every :data:`PROGRESS_EVERY`
    updates, and whether ``max_seconds`` have passed with updates left."""
    if progress is not None and (n + 1) % PROGRESS_EVERY == 0:
        progress(n + 1, total, clock.seconds())
    return max_seconds is not None and n + 1 < total and clock.seconds() > max_seconds


def replay(ds: PoseGraph, backend: str = "dropin",
           params: gtsam.ISAM2Params | None = None,
           progress: Callable[[int, int, float], None] | None = None,
           graph: gtsam.NonlinearFactorGraph | None = None,
           isam_class: type | None = None, max_seconds: float | None = None) -> Replay:
    """Replay ``ds`` online (module docstring) with ``backend``'s factors.

    ``progress(done, total, seconds)`` is called every :data:`PROGRESS_EVERY`
    updates. ``graph``/``isam_class`` override the backend's graph and ISAM2
    class (the benchmark runs our factors in plain ``gtsam.ISAM2`` with them).
    ``max_seconds``: stop after the update that passes this many seconds (the
    benchmark's cut-off for a leg that grows quadratically); ``updates`` then
    counts the updates done and ``final_error`` is NaN.
    """
    if backend == "batch" and graph is None and isam_class is None and ds.landmarks is None:
        return replay_arrays(ds, params, progress, max_seconds)
    if graph is None:
        graph = build_graph(ds, backend)
    if isam_class is None:
        isam_class = isam2_class(backend)
    steps = schedule(ds, graph)
    group = ds.group
    estimate = getattr(isam_class, f"calculateEstimate{group}")
    at = getattr(gtsam.Values, f"at{group}")
    batches = []
    for step in steps:
        g = gtsam.NonlinearFactorGraph()
        for k in step.factors:
            g.add(graph.at(k))
        batches.append(g)
    warm_up_factors()  # compile before the clock starts
    isam = isam_class(params if params is not None else isam2_params())
    relinearized = 0
    start = gtsam.Values()
    times = np.empty(len(steps))
    previous = None
    clock = Stopwatch()
    for n, (step, new_factors) in enumerate(zip(steps, batches)):
        if step.odometry is not None and previous is not None:
            k, forward = step.odometry
            measured = to_gtsam(group, ds.measured[k])
            guess = previous.compose(measured if forward else measured.inverse())
        else:
            guess = at(ds.initial, step.key)
        new_theta = gtsam.Values()
        new_theta.insert(step.key, guess)
        start.insert(step.key, guess)
        for key in step.landmarks:
            f = next(graph.at(i) for i in step.factors if key in graph.at(i).keys())
            point = _landmark_initial(ds, f, key, new_theta)
            new_theta.insert(key, point)
            start.insert(key, point)
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
    final_error = float(graph.error(values)) if len(times) == len(steps) else math.nan
    return Replay(updates=len(times), update_seconds=float(times.sum()),
                  update_p50=float(np.percentile(times, 50)), update_p99=float(np.percentile(times, 99)),
                  seconds=seconds, final_error=final_error, values=values, start=start,
                  factors=int(graph.size()), times=times, relinearizations=relinearized,
                  reorderings=getattr(isam, "reorderings", None))


def replay_arrays(ds: PoseGraph, params=None, progress: Callable[[int, int, float], None] | None = None,
                  max_seconds: float | None = None) -> Replay:
    """The replay of a pose graph (no landmarks) through :class:`lie_factors.incremental.Smoother`
    on arrays: the same updates, initial values and figures as :func:`replay`, and no factor
    object at all.  ``params``: a :class:`~lie_factors.incremental.SmootherParams` or a
    ``gtsam.ISAM2Params``."""
    from ..batch.graph import Problem
    from ..incremental import FactorArrays, Smoother

    pg = ds.with_first_prior()
    E = len(pg.edge_keys)
    fa = FactorArrays(pg.group, pg.edge_keys, pg.measured, pg.information, pg.prior_keys, pg.prior_measured,
                      pg.prior_information)
    steps = schedule(ds, pg.edge_keys.tolist() + [[k] for k in pg.prior_keys.tolist()])
    edges = [np.array([k for k in s.factors if k < E], dtype=np.int64) for s in steps]
    priors = [np.array([k - E for k in s.factors if k >= E], dtype=np.int64) for s in steps]
    warm_up_smoother(fa.group)  # compile before the clock starts
    smoother = Smoother(params)
    start = np.empty((len(steps), fa.spec.mat, fa.spec.mat))
    file_poses = ds.start_poses
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
            smoother.update_prepared(fa, [step.key], guess[None], edges[n], priors[n])
            previous = smoother.estimate_matrix(step.key)
        except ValueError as exc:
            raise InputError(f"update {n + 1} (pose {step.key}) failed: {str(exc).strip()}") from None
        times[n] = time.perf_counter() - t0
        if _stop_after(n, len(steps), clock, progress, max_seconds):
            times = times[:n + 1]
            break
    seconds = clock.seconds()
    done = len(times)
    keys = pg.keys[:done]
    X = smoother.estimate_matrices(keys)
    final_error = Problem.from_pose_graph(pg, X).error() if done == len(steps) else math.nan
    return Replay(updates=done, update_seconds=float(times.sum()),
                  update_p50=float(np.percentile(times, 50)), update_p99=float(np.percentile(times, 99)),
                  seconds=seconds, final_error=float(final_error),
                  values=values_from_matrices(pg.group, keys, X),
                  start=values_from_matrices(pg.group, keys, start[:done]), factors=E + len(pg.prior_keys),
                  times=times, relinearizations=smoother.relinearizations, reorderings=smoother.reorderings)


def warm_up_smoother(group: str) -> None:
    """Compile (or load) every kernel a replay on ``group`` runs, on a three-pose problem."""
    from ..incremental import Smoother, SmootherParams

    info = registry.group(group)
    I = np.eye(info.mat)
    s = Smoother(SmootherParams(relinearizeSkip=1, relinearizeThreshold=0.0))
    s.update_arrays(group, [0, 1], np.stack([I, I]), [[0, 1]], I[None], np.eye(info.dim)[None], [0], I[None],
                    np.eye(info.dim)[None])
    s.update_arrays(group, [2], I[None], [[1, 2], [0, 2]], np.stack([I, I]), np.stack([np.eye(info.dim)] * 2))
    s.estimate_matrix(2)


#: The figures of a :class:`Replay` its record reports.
FIGURES = ("updates", "update_seconds", "update_p50", "update_p99", "seconds", "final_error")


@dataclass
class ReplayRecord(Record):
    """What ``lie-factors posegraph --incremental --json`` prints (``to_dict``): :class:`Record`'s
    fields, ``incremental``, the replay's :data:`FIGURES` (``seconds``: the whole replay) and
    ISAM2's two parameters."""

    replay: Replay
    relinearize_threshold: float
    relinearize_skip: int

    def to_dict(self) -> dict:
        return {**{f.name: getattr(self, f.name) for f in dataclasses.fields(Record)}, "incremental": True,
                **{k: getattr(self.replay, k) for k in FIGURES},
                "relinearizations": self.replay.relinearizations, "reorderings": self.replay.reorderings,
                "relinearize_threshold": float(self.relinearize_threshold),
                "relinearize_skip": int(self.relinearize_skip)}


class IncrementalRun(PoseGraphRun):
    """A :class:`~lie_factors.app.run.PoseGraphRun` whose start and optimization are the ISAM2
    replay (:func:`replay`); ``events.replayed`` hears its progress.  After :meth:`execute`:
    ``replay`` (:class:`Replay`) and ``record`` (:class:`ReplayRecord`)."""

    def __init__(self, dataset, backend: str = "dropin",
                 relinearize_threshold: float = DEFAULT_RELINEARIZE_THRESHOLD,
                 relinearize_skip: int = DEFAULT_RELINEARIZE_SKIP, output: str | None = None,
                 plot: str | None = None, events: RunEvents | None = None):
        super().__init__(dataset, backend, output=output, plot=plot, events=events)
        self.relinearize_threshold, self.relinearize_skip = relinearize_threshold, relinearize_skip
        self.replay: Replay | None = None

    @property
    def uses_arrays(self) -> bool:
        return False  # ISAM2 takes factor objects

    def initialize(self):
        """Nothing: the replay chooses each pose's start as it adds it."""
        return None

    def optimize(self) -> Replay:
        if self.backend == "batch":
            from ..incremental import SmootherParams

            params = SmootherParams(relinearizeThreshold=self.relinearize_threshold,
                                    relinearizeSkip=self.relinearize_skip)
        else:
            params = isam2_params(self.relinearize_threshold, self.relinearize_skip)
        self.replay = r = replay(self.pg, self.backend, params, self.events.replayed)
        self.record = ReplayRecord(**Record.of(self.pg, self.backend, r.factors), replay=r,
                                   relinearize_threshold=self.relinearize_threshold,
                                   relinearize_skip=self.relinearize_skip)
        return r

    def values(self) -> gtsam.Values:
        return self.replay.values

    def start_values(self) -> gtsam.Values:
        return self.replay.start

    def plot_labels(self) -> tuple[str, str, str, str, str]:
        return (f"{self.pg.name} ({self.backend}, incremental)", "initial (online guesses)", "ISAM2 estimate",
                "initial landmarks", "estimated landmarks")
