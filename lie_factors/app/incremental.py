"""``lie-factors posegraph FILE --incremental``: the run whose start and optimization are an online replay.

The replay itself is :func:`lie_factors.incremental.replay.replay`; this module
holds what the command adds to it: the run (:class:`IncrementalRun`, a
:class:`~lie_factors.app.run.PoseGraphRun` that reads, replays and writes) and
its ``--json`` record (:class:`ReplayRecord`).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import gtsam

from ..incremental.replay import DEFAULT_RELINEARIZE_SKIP, DEFAULT_RELINEARIZE_THRESHOLD, replay
from ..result import ReplayResult
from .record import Record
from .run import PoseGraphRun, RunEvents


@dataclass
class ReplayRecord(Record):
    """What ``lie-factors posegraph --incremental --json`` prints (``to_dict``): :class:`Record`'s
    fields, ``incremental``, the replay's figures (``seconds``: the whole replay;
    ``final_error``: the graph's error at its final estimate), the smoother's counts and
    ISAM2's two parameters."""

    replay: ReplayResult
    relinearize_threshold: float
    relinearize_skip: int

    def to_dict(self) -> dict:
        r = self.replay
        return {**{f.name: getattr(self, f.name) for f in dataclasses.fields(Record)}, "incremental": True,
                "updates": r.updates, "update_seconds": r.update_seconds, "update_p50": r.update_p50,
                "update_p99": r.update_p99, "seconds": r.seconds, "final_error": r.error,
                "relinearizations": r.relinearizations, "reorderings": r.reorderings,
                "relinearize_threshold": float(self.relinearize_threshold),
                "relinearize_skip": int(self.relinearize_skip)}


class IncrementalRun(PoseGraphRun):
    """A :class:`~lie_factors.app.run.PoseGraphRun` whose start and optimization are the online
    replay; ``events.replayed`` hears its progress.  After :meth:`execute`: ``replay``
    (:class:`~lie_factors.result.ReplayResult`) and ``record`` (:class:`ReplayRecord`)."""

    def __init__(self, dataset, backend: str = "dropin",
                 relinearize_threshold: float = DEFAULT_RELINEARIZE_THRESHOLD,
                 relinearize_skip: int = DEFAULT_RELINEARIZE_SKIP, output: str | None = None,
                 plot: str | None = None, events: RunEvents | None = None):
        super().__init__(dataset, backend, output=output, plot=plot, events=events)
        self.relinearize_threshold, self.relinearize_skip = relinearize_threshold, relinearize_skip
        self.replay: ReplayResult | None = None

    @property
    def uses_arrays(self) -> bool:
        return False  # the replay, not the run, chooses between arrays and factor objects

    def initialize(self):
        """Nothing: the replay chooses each pose's start as it adds it."""
        return None

    def optimize(self) -> ReplayResult:
        self.replay = r = replay(self.pg, backend=self.backend, relinearize_threshold=self.relinearize_threshold,
                                 relinearize_skip=self.relinearize_skip, progress=self.events.replayed)
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
