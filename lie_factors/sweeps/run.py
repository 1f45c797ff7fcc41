"""Running a sweep's cases on Dask (``dask.distributed``): a ``LocalCluster`` on this machine by
default, or the cluster of a running scheduler given its address.

Each graph's :class:`~lie_factors.sweeps.cases.GraphData` (its file's bytes, and the ground
truth's) is scattered once; its clean optimum is one task on it; each case is one task taking
those two and its :class:`~lie_factors.sweeps.cases.Case`. Rows are written as cases finish
(:class:`~lie_factors.sweeps.results.ResultsFile`); a case already in the results file is not
run again.
"""

from __future__ import annotations

import os
import sys
import time
import uuid
from typing import Any, Callable, Sequence

from ..errors import InputError, first_line
from .cases import Case, cases_of, clean_optimum, graph_data, run_case
from .results import ResultsFile
from .spec import Spec, read_spec

__all__ = ["sweep", "CONNECT_TIMEOUT"]

#: Seconds to wait for a scheduler given by address before saying it cannot be reached.
CONNECT_TIMEOUT = 10.0


def _distributed():
    try:
        import distributed
    except ImportError:
        raise InputError("the sweep needs Dask: pip install \"dask[distributed]\" (or the extra: "
                         "pip install -e \".[sweep]\")") from None
    return distributed


def _spec(spec) -> Spec:
    if isinstance(spec, Spec):
        return spec
    if isinstance(spec, (str, os.PathLike)):
        return read_spec(os.fspath(spec))
    raise InputError(f"sweep: expected a spec file's path or a Spec, got {type(spec).__name__}")


def _positive(name: str, value, kind=float):
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float) if kind is float else int) or not value > 0 \
            or value == float("inf"):
        raise InputError(f"{name}: expected a {'number' if kind is float else 'whole number'} > 0, got {value!r}")
    return kind(value)


class _Progress:
    """One line on stderr, rewritten as cases finish: done, failed, time left."""

    def __init__(self, total: int, skipped: int, show: bool):
        self.total, self.done, self.failed, self.show = total, skipped, 0, show
        self.start, self.skipped = time.perf_counter(), skipped

    def update(self, row: dict[str, Any]) -> None:
        self.done += 1
        self.failed += row["status"] != "ok"
        if not self.show:
            return
        ran = self.done - self.skipped
        left = (time.perf_counter() - self.start) / ran * (self.total - self.done) if ran else float("nan")
        width = 30
        filled = int(width * self.done / max(self.total, 1))
        print(f"\r[{'#' * filled}{'.' * (width - filled)}] {self.done}/{self.total} cases, {self.failed} failed, "
              f"{_duration(left)} left ", end="", file=sys.stderr, flush=True)

    def close(self) -> None:
        if self.show:
            print(file=sys.stderr, flush=True)


def _duration(seconds: float) -> str:
    if seconds != seconds:
        return "?"
    s = int(round(seconds))
    return f"{s // 3600}h{s % 3600 // 60:02d}m" if s >= 3600 else f"{s // 60}m{s % 60:02d}s"


def _check_reachable(address: str) -> None:
    """For a TCP address (``tcp://host:port`` or ``host:port``), a one-line InputError now if nothing
    listens there (Dask's own client would retry until its timeout)."""
    import socket
    from urllib.parse import urlsplit

    if "://" in address and not address.startswith("tcp://"):
        return  # TLS, in-process, ...: Dask's client says
    try:
        parts = urlsplit(address if "://" in address else f"tcp://{address}")
        host, port = parts.hostname, parts.port
    except ValueError:
        raise InputError(f"scheduler: {address} is not an address such as tcp://host:8786") from None
    if not host or port is None:
        raise InputError(f"scheduler: {address} is not an address such as tcp://host:8786")
    try:
        socket.create_connection((host, port), timeout=CONNECT_TIMEOUT).close()
    except OSError as exc:
        raise InputError(f"cannot reach the Dask scheduler at {address} ({exc.strerror or first_line(exc)})") from None


def _client(distributed, scheduler: str | None, workers: int | None):
    """A Dask client of the scheduler at ``scheduler``, or of a new LocalCluster of ``workers`` worker
    processes (default: one per core), one thread each; and the cluster to close (None)."""
    if scheduler is not None:
        _check_reachable(scheduler)
        try:
            return distributed.Client(scheduler, timeout=CONNECT_TIMEOUT, set_as_default=False), None
        except (OSError, TimeoutError, ValueError) as exc:
            raise InputError(f"cannot reach the Dask scheduler at {scheduler} ({first_line(exc)})") from None
    n = workers or os.cpu_count() or 1
    # numba's parallel kernels: the cores shared among the workers, not each worker taking them all
    threads = str(max(1, (os.cpu_count() or 1) // n))
    import logging

    cluster = distributed.LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None,
                                       silence_logs=logging.ERROR, env={"NUMBA_NUM_THREADS": threads})
    return distributed.Client(cluster, set_as_default=False), cluster


def sweep(spec, out: str, *, scheduler: str | None = None, workers: int | None = None, timeout: float | None = None,
          progress: bool = False, on_row: Callable[[dict], None] | None = None) -> list[dict[str, Any]]:
    """Run every case of ``spec`` (a spec file's path, :mod:`lie_factors.sweeps.spec`, or a
    :class:`~lie_factors.sweeps.spec.Spec`) on Dask and write one row per case to ``out``
    (``.csv`` or ``.parquet``, :mod:`lie_factors.sweeps.results`) as cases finish; returns every
    row of ``out``, those of earlier runs included (``lie-factors sweep SPEC --out RESULTS``).

    ``scheduler``: a running Dask scheduler's address (``tcp://host:8786``); without it a
    ``LocalCluster`` of ``workers`` worker processes (default: one per core). ``timeout``:
    seconds after which a case is abandoned (default: the spec's ``timeout``, else none).
    ``progress``: a progress line on stderr; ``on_row``: called with each new row.

    Cases already in ``out`` are not run again (a killed sweep resumes); a case that fails or
    runs past the timeout is a row with its ``error``, and the sweep goes on. The spec, ``out``
    and the scheduler are checked before any case runs: :class:`~lie_factors.errors.InputError`.
    """
    spec = _spec(spec)
    if scheduler is not None and not isinstance(scheduler, str):
        raise InputError(f"scheduler: expected an address such as tcp://host:8786, got {scheduler!r}")
    if scheduler is not None and workers is not None:
        raise InputError("workers: applies to the local cluster; a scheduler's workers are its own")
    workers = _positive("workers", workers, int)
    timeout = _positive("timeout", timeout) if timeout is not None else spec.timeout
    distributed = _distributed()
    results = ResultsFile(out)
    try:
        cases = cases_of(spec)
        todo = [c for c in cases if c.id not in results.done]
        bar = _Progress(len(cases), len(cases) - len(todo), progress)
        if todo:
            _run(distributed, spec, todo, results, scheduler, workers, timeout, bar, on_row)
        bar.close()
    finally:
        results.close()
    return results.rows


def _run(distributed, spec: Spec, todo: Sequence[Case], results: ResultsFile, scheduler, workers, timeout,
         bar: _Progress, on_row) -> None:
    sources = {g.name: g for g in spec.graphs}
    data = {name: graph_data(sources[name]) for name in dict.fromkeys(c.graph for c in todo)}
    sweep_run = uuid.uuid4().hex[:12]
    client, cluster = _client(distributed, scheduler, workers)
    try:
        futures = {}
        for name, d in data.items():
            scattered = client.scatter(d, broadcast=False, hash=False)
            optimum = client.submit(clean_optimum, scattered, pure=False, key=f"clean-optimum-{name}-{sweep_run}")
            for case in (c for c in todo if c.graph == name):
                f = client.submit(run_case, case, scattered, optimum, timeout, sweep_run, pure=False,
                                  key=f"case-{case.id}-{sweep_run}")
                futures[f] = case
        for future in distributed.as_completed(futures, loop=client.loop):
            case = futures[future]
            try:
                row = future.result()
            except Exception as exc:  # the clean optimum failed, or the worker running the case died
                row = _failed(case, exc, sweep_run)
            if not results.add(row):
                continue
            bar.update(row)
            if on_row is not None:
                on_row(row)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def _failed(case: Case, exc: BaseException, sweep_run: str) -> dict[str, Any]:
    import json

    from ..errors import LieFactorsError

    what = first_line(exc, 500) if isinstance(exc, LieFactorsError) else f"{type(exc).__name__}: {first_line(exc, 500)}"
    return {"case": case.id, "graph": case.graph, "kind": case.kind, "fraction": case.fraction, "seed": case.seed,
            "method": case.method, "run": case.run, "options": json.dumps(case.options, sort_keys=True),
            "status": "failed", "error": what, "sweep_run": sweep_run}
