"""Levenberg–Marquardt on robust (M-estimator) and weighted factors, GTSAM's semantics.

The losses themselves (GTSAM's ``noiseModel.mEstimator`` as numba kernels,
:class:`RobustLoss`, :func:`parse_loss`, :func:`from_gtsam`) are in
:mod:`lie_factors.robust.losses`, below the graph reader that groups robust
factors.
"""

from __future__ import annotations

import time

import gtsam
import numpy as np

from ..batch.optimizer import BatchLevenbergMarquardt
from .losses import weights_and_losses

__all__ = ["WeightedLevenbergMarquardt", "graph_losses"]


# --------------------------------------------------------------------------- #
# Levenberg–Marquardt on robust / weighted factors
# --------------------------------------------------------------------------- #

def graph_losses(problem) -> tuple[np.ndarray, np.ndarray]:
    """(kinds, ks) per graph slot from ``problem.robust`` (slot → RobustLoss); GAUSSIAN elsewhere."""
    kinds = np.zeros(problem.graph_size, dtype=np.int64)
    ks = np.ones(problem.graph_size)
    for slot, rl in problem.robust.items():
        kinds[slot] = rl.kind
        ks[slot] = rl.k
    return kinds, ks


class WeightedLevenbergMarquardt(BatchLevenbergMarquardt):
    """Batch LM on ``Σ_f s_f·ρ_f(‖R_f e_f‖)``: robust noise models and GNC weights.

    ``ρ_f`` is factor f's robust loss (``noiseModel.Robust`` with a Huber,
    Cauchy, Tukey, Geman–McClure, DCS or Welsch estimator and Block
    reweighting; ½d² for Gaussian noise) and ``s_f`` a fixed scale (the GNC
    weight, 1 by default; :meth:`restart` sets it).  At each linearization the
    whitened rows of factor f are scaled by ``√(s_f·w_f(d_f))`` — GTSAM's
    ``Robust::WhitenSystem`` (and, with s, its ``makeWeightedGraph``) — through
    the solver's per-factor weights; the error is the robust one, as GTSAM's
    ``NoiseModelFactor::error``.  The LM loop (λ schedule, model fidelity,
    convergence) is :mod:`lie_factors.lm`'s, through
    :class:`~lie_factors.batch.optimizer.BatchLevenbergMarquardt`.

    The solver's own factors are its groups and its kinds' factors (a kind's, and GTSAM's own
    with a twin kind).  Factors GTSAM linearizes itself (native factors, other estimators) keep
    GTSAM's own robust handling and are only scaled by ``s_f``.
    """

    group_robust = True

    def _small_losses(self):
        return self.kinds, self.ks, self.scale

    def __init__(self, graph, initial, params=None, scale=None, **kwargs):
        self._scale0 = scale  # read by _setup, which the base __init__ calls before the initial objective
        super().__init__(graph, initial, params, **kwargs)

    def _setup(self) -> None:
        P = self.problem
        F = P.graph_size
        self.kinds, self.ks = graph_losses(P)
        scale = self._scale0
        self.scale = np.ones(F) if scale is None else np.asarray(scale, dtype=np.float64).copy()
        # the factors whose rows the solver whitens itself: groups and kinds (their losses here)
        self._grouped = (*P.groups, *P.kinds)
        self._group_slots = (np.concatenate([g.fidx for g in self._grouped]) if self._grouped
                             else np.zeros(0, dtype=np.int64))
        self._native_slots = (P.native_arrays.fidx if P.native_arrays is not None
                              else np.zeros(0, dtype=np.int64))
        self._gk = self.kinds[self._group_slots]
        self._gkk = self.ks[self._group_slots]
        self._w = np.empty(len(self._group_slots))
        self._rho = np.empty(len(self._group_slots))
        self._other0 = gtsam.Values(P.other)

    # ------------------------------------------------------------ objective
    def objective(self, Xs=None, other=None) -> float:
        """Σ_f s_f·ρ_f at the given (or current) estimate (the base LM's cost hook)."""
        P = self.problem
        sq = np.zeros(P.graph_size)
        P.error(Xs, other, sq_out=sq)
        return self._weighted(sq)

    def _weighted(self, sq: np.ndarray) -> float:
        gs = self._group_slots
        weights_and_losses(self._gk, self._gkk, sq[gs], self._w, self._rho)
        total = float(np.dot(self.scale[gs], self._rho))
        ns = self._native_slots
        if len(ns):
            total += 0.5 * float(np.dot(self.scale[ns], sq[ns]))  # sq = 2·(GTSAM's error)
        return total

    def factor_errors(self, Xs=None, other=None) -> np.ndarray:
        """(graph size,) each factor's unscaled error (½‖R e‖² for Gaussian noise, ρ for robust)."""
        P = self.problem
        sq = np.zeros(P.graph_size)
        P.error(Xs, other, sq_out=sq)
        gs = self._group_slots
        weights_and_losses(self._gk, self._gkk, sq[gs], self._w, self._rho)
        out = 0.5 * sq
        out[gs] = self._rho
        return out

    # ------------------------------------------------------------ LM hooks
    def _linearize(self) -> float:
        T = self.timings
        t = time.perf_counter()
        P = self.problem
        P.linearize()
        sys_w = self.system.weights
        total = 0.0
        for g in self._grouped:
            sq = g.sq
            w = np.empty(g.E)
            rho = np.empty(g.E)
            weights_and_losses(self.kinds[g.fidx], self.ks[g.fidx], sq, w, rho)
            sw = self.scale[g.fidx] * w
            sys_w[g.fidx] = sw
            total += 0.5 * float(np.dot(sw, sq))
        nat = P.native_arrays
        if nat is not None:
            sys_w[nat.fidx] = self.scale[nat.fidx]
            total += 0.5 * float(np.dot(self.scale[nat.fidx], nat.sq))
        t1 = time.perf_counter()
        self.system.assemble()
        T["linearize"] += t1 - t
        T["assemble"] += time.perf_counter() - t1
        return total

    # ------------------------------------------------------------ restarts (GNC)
    def restart(self, scale: np.ndarray, start: tuple | None = None) -> None:
        """Back to the initial values (or ``start``: block name → its values, and the other
        ``gtsam.Values``) and LM's initial state, with factor scales ``scale`` (GNC's weights)."""
        P = self.problem
        for name, b in (*P.blocks.items(), *P.value_blocks.items()):
            b.X = (b.X0 if start is None else start[0][name]).copy()
        P.other = gtsam.Values(self._other0 if start is None else start[1])
        self.scale = np.asarray(scale, dtype=np.float64).copy()
        self._lm_reset()
        self._iterations = 0
        self.timings = dict.fromkeys(self.timings, 0.0)
        self._error = self.objective()
