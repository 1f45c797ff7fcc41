"""What a run reports: the record ``lie-factors posegraph --json`` prints as its last line."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from ..posegraph.graph import PoseGraph

#: Keys of ``RunRecord.timings`` (``--json``): the steps of a :class:`~lie_factors.app.run.PoseGraphRun`, in order.
TIMING_KEYS = ("imports", "read", "init", "setup", "iterations", "write")


@dataclass
class Record:
    """What every run reports first: ``backend``, ``dataset`` (the file's name), ``dimension`` (2
    or 3), ``poses``, ``landmarks`` (landmark variables) and ``factors`` (the optimized graph:
    the file's edges and landmark measurements + 1 prior)."""

    backend: str
    dataset: str
    dimension: int
    poses: int
    landmarks: int
    factors: int

    @staticmethod
    def of(ds: PoseGraph, backend: str, factors: int) -> dict:
        """The fields of :class:`Record` for a run of ``backend`` on ``ds`` with ``factors`` factors."""
        return dict(backend=backend, dataset=ds.name, dimension=3 if ds.is3d else 2, poses=ds.pose_count,
                    landmarks=ds.landmark_count, factors=int(factors))

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


@dataclass
class RunRecord(Record):
    """What ``lie-factors posegraph --json`` prints (``to_dict``): :class:`Record`'s fields, then

    ``seconds``: optimization only (LM construction + iterations, not loading
    and not initialization); ``init`` is the initialization method used
    (:data:`lie_factors.initialization.METHODS`) and ``init_seconds`` its cost;
    ``initial_error``/``final_error`` are GTSAM's 0.5·Σ‖whitened residual‖²
    (Σ ρ(‖whitened residual‖) for robust factors).  ``robust``: the loss
    (``name:k``, with ``+all`` if on every edge); ``gnc``: the GNC loss;
    ``init_inliers_only`` (robust and GNC runs): whether the start was built
    from the odometry edges and the prior alone.  With
    GNC, ``iterations`` counts GNC's outer iterations, ``final_error`` is GNC's
    weighted cost Σ w_k·½‖R_k e_k‖², ``outliers`` lists the rejected edges
    (0-based, in the file's edge order) and ``rejected_by`` maps each of them
    (as a string) to the stage that rejected it: ``gate``, ``clique``, ``gnc``
    or ``final`` (:mod:`lie_factors.robust.rejection`; absent with
    ``--no-consistency``).
    """

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
    rejected_by: dict | None = None
    init_inliers_only: bool | None = None
    #: seconds of each step of a PoseGraphRun (see PoseGraphRun.timings)
    timings: dict | None = None

    def to_dict(self) -> dict:
        d = super().to_dict()
        # robust / gnc / outliers / rejected_by / init_inliers_only appear only in runs that use them.
        for key in ("robust", "gnc", "outliers", "rejected_by", "init_inliers_only", "timings"):
            if d[key] is None:
                del d[key]
        return d
