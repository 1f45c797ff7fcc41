"""The false-closure pipeline on a pose graph: graduated non-convexity, with the consistency
stage before it and the final check after it (:mod:`lie_factors.robust.rejection`).

The odometry (edges between consecutive poses), the priors and every other
factor are known inliers; the loop closures are the ones in doubt
(:func:`lie_factors.posegraph.graph.is_loop_closure`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import gtsam_failure
from ..posegraph.graph import PoseGraph
from .gnc import GncSettings, GncResult
from .rejection import Solver, reject_false_closures, uncertainty

__all__ = ["GNC_LOSSES", "RobustOutcome", "reject_and_optimize"]

#: The GNC losses: truncated least squares and Geman–McClure.
GNC_LOSSES = ("tls", "gm")


@dataclass
class RobustOutcome:
    """What :func:`reject_and_optimize` found: ``gnc`` (GNC's result, its estimate and weights
    after the final check), ``outliers`` (k,) the rejected edges, increasing, ``rejected_by``
    edge → stage (``gate``, ``clique``, ``gnc``, ``final``; None without the consistency
    stage), ``seconds`` (the whole pipeline, compilation excluded), ``reasons``: why the verdict
    may be wrong (:func:`~lie_factors.robust.rejection.uncertainty`; empty: ``status`` "ok")."""

    gnc: GncResult
    outliers: np.ndarray
    rejected_by: dict[int, str] | None
    seconds: float
    reasons: tuple = ()

    @property
    def status(self) -> str:
        return "uncertain" if self.reasons else "ok"

    @property
    def converged(self) -> bool:
        return self.gnc.stop != "maxIterations"


def reject_and_optimize(graph: PoseGraph, solver: Solver, size: int, *, loss: str = "tls",
                        consistency: bool = True, lm_params=None, gtsam_semantics: bool = False) -> RobustOutcome:
    """GNC on ``graph`` through ``solver`` (:class:`~lie_factors.robust.rejection.Solver`,
    ``size`` factor slots: the edges, the priors, then any other factor), with the
    consistency stage and the final check unless ``consistency`` is False.

    ``loss``: ``tls`` or ``gm``; ``lm_params``: the inner Levenberg–Marquardt's
    ``gtsam.LevenbergMarquardtParams``; ``gtsam_semantics``: GTSAM's own GNC, whose
    first solve weighs every factor 1 and whose every solve starts from the initial values
    (ours, with the consistency stage, starts from the known inliers alone and continues each
    solve from the last).  A ``RuntimeError`` from GTSAM becomes a
    :class:`~lie_factors.errors.LieFactorsError`.
    """
    known = np.setdiff1d(np.arange(size), graph.loop_closures())
    ours = consistency and not gtsam_semantics
    params = GncSettings(loss=loss, known_inliers=known.tolist(), lm_params=lm_params,
                         first_solve_known_inliers=ours, warm_start=ours)
    try:
        if consistency:
            rejection = reject_false_closures(graph, solver, params)
            res, seconds = rejection.gnc, rejection.seconds
            rejected_by = {int(k): v for k, v in rejection.rejected_by.items()}
            outliers = np.array(sorted(rejected_by), dtype=np.int64)
            reasons = rejection.reasons
        else:
            res = solver.gnc(params)
            seconds, rejected_by = res.seconds, None
            outliers = np.array([int(k) for k in res.outliers if k < len(graph.edge_keys)], dtype=np.int64)
            reasons = uncertainty(None, res)
    except RuntimeError as exc:
        raise gtsam_failure(exc) from None
    return RobustOutcome(res, outliers, rejected_by, seconds, reasons)
