"""GNC's inner solver on the batch Levenberg–Marquardt (:class:`lie_factors.gnc.InnerSolver`)."""

from __future__ import annotations

import gtsam
import numpy as np

from .batch import BatchLevenbergMarquardt
from .gnc import GtsamInner


class BatchInner(GtsamInner):
    """Weighted LM with the batch solver: the re-weighted graph (``Gaussian.Information(w·Ω)``,
    GTSAM's ``makeWeightedGraph``) optimized by :class:`lie_factors.batch.BatchLevenbergMarquardt`."""

    def optimize(self, weights: np.ndarray):
        opt = BatchLevenbergMarquardt(self.weighted_graph(weights), self.initial, self.lm_params)
        res = opt.optimize()
        return res.values, int(res.iterations)
