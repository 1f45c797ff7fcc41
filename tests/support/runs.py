"""A pose-graph run from the tests: :func:`lie_factors.optimize` on a file or a pose graph, and the
record ``lie-factors posegraph --json`` prints for it (its fields as attributes)."""

from __future__ import annotations

from types import SimpleNamespace

import lie_factors as lf
from lie_factors.app.posegraph import record as command_record


class Record(SimpleNamespace):
    """The ``--json`` record of a run, its fields as attributes."""

    def to_dict(self) -> dict:
        return dict(vars(self))


def run(dataset, backend: str = "batch", max_iterations: int = 100, **options):
    """(record, result, pose graph) of ``lf.optimize`` on ``dataset`` (a path or a PoseGraph)."""
    pg = dataset if isinstance(dataset, lf.PoseGraph) else lf.read_g2o(str(dataset))
    result = lf.optimize(pg, backend=backend, max_iterations=max_iterations, **options)
    args = SimpleNamespace(incremental=False)
    timings = {"imports": 0.0, "read": 0.0, **result.timings, "write": 0.0}
    return Record(**command_record(pg, result, timings, args)), result, pg
