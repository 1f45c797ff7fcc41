"""A sweep's cases and what one case measures.

A :class:`Case` is one graph, one corruption (kind, fraction, seed; ``clean``: none) and one
method. :func:`cases_of` expands a spec into them; :func:`measure` runs one: plants the
false closures (:func:`lie_factors.corruption.plant`, the clean optimum as its reference
poses), runs the method (:func:`lie_factors.optimize` or :func:`lie_factors.replay` with the
method's keywords) and scores the result (:mod:`lie_factors.sweeps.metrics`,
:func:`lie_factors.evaluate`). :func:`run_case` does it in a child process when a timeout is set, so
that a case past its timeout is killed and a crash is the case's row.

What a worker needs: the package and :class:`GraphData` (the graph's bytes and the clean
optimum's poses, sent to each worker once); what a case's task carries: its :class:`Case`.
"""

from __future__ import annotations

import json
import os
import pickle
import select
import signal
import socket
import tempfile
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ["Case", "GraphData", "CleanOptimum", "cases_of", "graph_data", "clean_optimum", "measure", "run_case",
           "CLEAN"]

#: The kind of a case without planted closures (a spec without a corruption table).
CLEAN = "clean"


@dataclass(frozen=True)
class Case:
    """One case: ``graph`` (its name in the spec), ``kind``, ``fraction``, ``seed`` of the planted
    closures (``clean``, 0, 0: none), ``method`` (its name), ``run`` (``optimize`` or ``replay``)
    and the method's ``options``; ``align`` and ``delta`` of the evaluation."""

    graph: str
    kind: str
    fraction: float
    seed: int
    method: str
    run: str = "optimize"
    options: dict[str, Any] = field(default_factory=dict, hash=False, compare=False)
    align: str = "se3"
    delta: int = 1

    @property
    def id(self) -> str:
        """The case's name in the results (what a rerun skips): ``graph/kind/fraction/seed/method``."""
        return f"{self.graph}/{self.kind}/{self.fraction:g}/{self.seed}/{self.method}"


@dataclass(frozen=True)
class GraphData:
    """What a worker needs of a graph: ``name``, the g2o file's ``filename`` and ``content`` (bytes),
    and the ground truth's (``truth_filename``, ``truth``), or None."""

    name: str
    filename: str
    content: bytes
    truth_filename: str | None = None
    truth: bytes | None = None


@dataclass(frozen=True)
class CleanOptimum:
    """The graph's optimum without planted closures (:func:`lie_factors.optimize`, the default
    command): ``keys`` (P,), ``poses`` (P, m, m), ``group``."""

    keys: np.ndarray
    poses: np.ndarray
    group: str


def cases_of(spec) -> list["Case"]:
    """The cases of a :class:`~lie_factors.sweeps.spec.Spec`, graph by graph: every kind × fraction
    × seed × method (every method on the clean graph where the spec has no corruption)."""
    corruptions = [(k, f, s) for k in spec.kinds for f in spec.fractions for s in spec.seeds] or [(CLEAN, 0.0, 0)]
    return [Case(g.name, k, f, s, m.name, m.run, dict(m.options), spec.align, spec.delta)
            for g in spec.graphs for (k, f, s) in corruptions for m in spec.methods]


def graph_data(source) -> GraphData:
    """The :class:`GraphData` of a spec's :class:`~lie_factors.sweeps.spec.GraphSource` (its files read)."""
    from ..errors import InputError

    def read(path: str) -> bytes:
        try:
            with open(path, "rb") as fh:
                return fh.read()
        except OSError as exc:
            raise InputError(f"{path}: cannot read ({exc.strerror})") from None

    truth = source.groundtruth
    return GraphData(source.name, os.path.basename(source.path), read(source.path),
                     None if truth is None else os.path.basename(truth), None if truth is None else read(truth))


def _written(directory: str, filename: str, content: bytes) -> str:
    path = os.path.join(directory, filename)
    with open(path, "wb") as fh:
        fh.write(content)
    return path


def _read_graph(data: GraphData, directory: str):
    from ..files import read_g2o

    return read_g2o(_written(directory, data.filename, data.content))


def clean_optimum(data: GraphData) -> CleanOptimum:
    """The :class:`CleanOptimum` of a graph: what the cases' map error and planted references use."""
    from ..solve import optimize

    fork_safe_threads()
    with tempfile.TemporaryDirectory(prefix="lie-factors-sweep-") as tmp:
        pg = _read_graph(data, tmp)
    result = optimize(pg)
    return CleanOptimum(np.asarray(result.keys), np.asarray(result.poses), pg.group)


def measure(case: Case, data: GraphData, clean: CleanOptimum) -> dict[str, Any]:
    """Run ``case`` on the graph and score it: the row's figures (``lie_factors.sweeps.results.COLUMNS``)
    without the case's identity, its timing and its status."""
    from .. import corruption, solve
    from ..evaluation.trajectory import Trajectory, planar_poses
    from ..files import evaluate
    from ..interop import values_from_matrices
    from ..testing.outliers import classify
    from . import metrics

    with tempfile.TemporaryDirectory(prefix="lie-factors-sweep-") as tmp:
        pg = _read_graph(data, tmp)
        truth = None if data.truth is None else _written(tmp, data.truth_filename or "groundtruth.tum", data.truth)
        if case.kind == CLEAN:
            graph, planted = pg, np.zeros(0, dtype=np.int64)
        else:
            c = corruption.plant(pg, fraction=case.fraction, kind=case.kind, seed=case.seed, reference=clean.poses)
            graph, planted = c.graph, c.planted
        run = solve.optimize if case.run == "optimize" else solve.replay
        result = run(graph, **case.options)
        if not np.array_equal(result.keys, clean.keys):
            raise RuntimeError("the result's poses are not the clean optimum's")
        reference = truth if truth is not None else Trajectory(clean.keys, planar_poses(clean.poses), True,
                                                               "clean optimum")
        ev = evaluate(result, reference, case.align, case.delta)
    row: dict[str, Any] = {
        "planted": int(planted.size), "ate_rmse": float(ev.ate.rmse), "rpe_rmse": float(ev.rpe.rmse),
        "reference": "groundtruth" if truth is not None else "clean optimum",
        "map_error": metrics.map_error_percent(metrics.positions(result.poses), metrics.positions(clean.poses)),
        "final_error": float(result.error), "iterations": int(result.iterations), "seconds": float(result.seconds)}
    status = getattr(result, "robust_status", None)
    if status is not None:
        row["robust_status"] = status["status"] + "".join(f"; {r}" for r in status["reasons"])
    rejected = getattr(result, "outliers", None)
    if rejected is not None:
        row["rejected"] = int(len(rejected))
        row["rejected_by"] = metrics.stage_counts(result.rejected_by or {})
    if rejected is not None and planted.size:
        c1 = classify(rejected, planted)
        # riSAM's rule: a planted closure that fits the clean optimum is not an outlier
        ref_values = values_from_matrices(clean.group, clean.keys, clean.poses)
        fits = planted[metrics.consistent_planted(graph.with_edges(planted).factor_graph(),
                                                  np.arange(planted.size), ref_values, graph.info.dim)]
        c2 = classify(np.setdiff1d(rejected, fits), np.setdiff1d(planted, fits))
        row.update(true_positives=c1.true_positives, precision=c1.precision, recall=c1.recall,
                   planted_consistent=int(fits.size), precision_consistent=c2.precision,
                   recall_consistent=c2.recall)
    return row


def fork_safe_threads() -> bool:
    """Choose numba's ``workqueue`` threads for this process, and take their count from
    ``NUMBA_NUM_THREADS`` as the environment holds it now, unless its threads already run (GNU
    OpenMP's cannot survive a fork); whether a child forked now can run numba's parallel code."""
    import numba
    from numba.core import config

    try:
        return numba.threading_layer() in ("workqueue", "tbb")
    except ValueError:  # no parallel code has run yet: the layer and the thread count are still ours to set
        # A worker that imported numba before its environment was set (a spawned process re-imports
        # its parent's main module first) holds the default thread count, not NUMBA_NUM_THREADS; its
        # first compile after the threads start would re-read the environment and refuse the change.
        config.reload_config()
        # numba.core.config sets its names from the environment at run time: no attribute a checker sees
        if getattr(config, "THREADING_LAYER") in ("default", "safe", "threadsafe", "forksafe", "omp"):
            setattr(config, "THREADING_LAYER", "workqueue")
        return True


def _peak_reset() -> None:
    """Start the process's peak resident size afresh (Linux: writing 5 to clear_refs)."""
    try:
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")
    except OSError:
        pass


def _measured(case: Case, data: GraphData, clean: CleanOptimum) -> dict[str, Any]:
    """:func:`measure` with its wall time and peak memory; an exception becomes the row's error."""
    from ..errors import LieFactorsError, first_line
    from ..util.memory import usage

    _peak_reset()
    t = time.perf_counter()
    try:
        row = {**measure(case, data, clean), "status": "ok", "error": ""}
    except LieFactorsError as exc:
        row = {"status": "failed", "error": first_line(exc, 500)}
    except Exception as exc:
        row = {"status": "failed", "error": f"{type(exc).__name__}: {first_line(exc, 500)}"}
    row["case_seconds"] = time.perf_counter() - t
    row["peak_rss"] = usage()[1]
    return row


def run_case(case: Case, data: GraphData, clean: CleanOptimum, timeout: float | None = None,
             sweep_run: str = "") -> dict[str, Any]:
    """One case's row (``lie_factors.sweeps.results.COLUMNS``): its identity, :func:`measure`'s
    figures, ``status`` (``ok``, ``failed``, ``timeout``) and ``error``, ``case_seconds`` (the whole
    case: reading, planting, the run, scoring), ``peak_rss`` (bytes), ``worker`` (host:pid) and
    ``sweep_run`` (which invocation of the sweep ran it).

    With a ``timeout``, where the process can fork (POSIX, numba's threads fork-safe), the case
    runs in a forked child: after ``timeout`` seconds the child is killed and the row says so, and
    a crash is the row's error. Without one it runs in this process, whose loaded kernels then
    serve the next case too (a child loads them again from numba's cache)."""
    identity = {"case": case.id, "graph": case.graph, "kind": case.kind, "fraction": case.fraction,
                "seed": case.seed, "method": case.method, "run": case.run,
                "options": json.dumps(case.options, sort_keys=True), "sweep_run": sweep_run,
                "worker": f"{socket.gethostname()}:{os.getpid()}"}
    # chosen before any case's parallel code runs in this worker: a later sweep's timeout forks it
    forkable = hasattr(os, "fork") and fork_safe_threads()
    if timeout is not None and forkable:
        row = _in_child(case, data, clean, timeout)
    else:
        row = _measured(case, data, clean)
    return {**identity, **row}


def _in_child(case: Case, data: GraphData, clean: CleanOptimum, timeout: float | None) -> dict[str, Any]:
    """:func:`_measured` in a forked child, its row read back through a pipe; killed after ``timeout``."""
    read, write = os.pipe()
    t = time.perf_counter()
    pid = os.fork()
    if pid == 0:  # the child: measure, send the row, leave without the parent's exit handlers
        os.close(read)
        try:
            payload = pickle.dumps(_measured(case, data, clean))
            with os.fdopen(write, "wb") as fh:
                fh.write(payload)
        finally:
            os._exit(0)
    os.close(write)
    chunks, timed_out = [], False
    with os.fdopen(read, "rb") as fh:
        while True:
            left = None if timeout is None else timeout - (time.perf_counter() - t)
            if left is not None and left <= 0:
                timed_out = True
                break
            ready, _, _ = select.select([fh], [], [], left)
            if not ready:
                continue
            chunk = os.read(fh.fileno(), 1 << 20)
            if not chunk:
                break
            chunks.append(chunk)
    if timed_out:
        os.kill(pid, signal.SIGKILL)
    _, status = os.waitpid(pid, 0)
    if timed_out:
        return {"status": "timeout", "error": f"ran past the timeout of {timeout:g} s",
                "case_seconds": time.perf_counter() - t}
    if not chunks:
        how = (f"signal {signal.Signals(os.WTERMSIG(status)).name}" if os.WIFSIGNALED(status)
               else f"exit status {os.WEXITSTATUS(status)}")
        return {"status": "failed", "error": f"the case's process died ({how})",
                "case_seconds": time.perf_counter() - t}
    return pickle.loads(b"".join(chunks))
