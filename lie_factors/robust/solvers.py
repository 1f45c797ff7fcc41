"""The backends of the false-closure pipeline: :class:`~lie_factors.robust.rejection.Solver` on
arrays (the batch solver on a pose graph, no factor object) and on a GTSAM graph.

Both run GNC (:func:`lie_factors.robust.gnc.gnc_optimize`, or GTSAM's own
``GncLMOptimizer`` for ``native``) and the re-solves of the final check on
one graph whose factor slots are the pose graph's edges, then its priors,
then its other factors (landmark measurements).
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from ..interop import matrices_from_values, values_from_matrices
from ..posegraph.graph import PoseGraph
from . import gnc as gncm
from .inner import BatchInner, GtsamInner, gtsam_gnc

__all__ = ["ArraySolver", "GraphSolver"]


class ArraySolver:
    """The batch solver on a pose graph's arrays (:meth:`~lie_factors.robust.inner.BatchInner.from_pose_graph`).

    ``graph``: the pose graph with its priors (no landmarks); ``X0`` (P, m, m): the start
    in its key order; ``lm_params``: the inner LM's ``gtsam.LevenbergMarquardtParams``;
    ``progress``: GNC's outer-iteration hook. An estimate is a batch state (its poses:
    ``state.Xs[group]``).
    """

    def __init__(self, graph: PoseGraph, X0: np.ndarray, lm_params, progress: Callable | None = None):
        if graph.landmarks is not None:
            raise ValueError("ArraySolver: a graph with landmarks runs on factor objects (GraphSolver)")
        self.graph, self.X0, self.lm_params, self.progress = graph, X0, lm_params, progress
        self._scorer = None

    def inner(self, X: np.ndarray, exclude=()) -> BatchInner:
        return BatchInner.from_pose_graph(self.graph, X, self.lm_params, exclude=exclude)

    def gnc(self, params: gncm.GncSettings, start: np.ndarray | None = None, proceed=None,
            first_iterations: int | None = None) -> gncm.GncResult:
        X = self.X0 if start is None else start
        return gncm.gnc_optimize(self.inner(X, params.known_outliers), params, self.progress, proceed,
                                 first_iterations)

    def errors(self, state) -> np.ndarray:
        return self._scorer_at().factor_errors(state)

    def refine(self, state, weights: np.ndarray):
        return self.inner(self.poses(state), np.flatnonzero(weights == 0.0)).optimize(weights)[0]

    def poses(self, state) -> np.ndarray:
        return state.Xs[self.graph.group]

    def start(self):
        """The start as an estimate (what GNC starts from)."""
        return self._scorer_at().initial

    def _scorer_at(self) -> BatchInner:
        """The solver on every edge at the start, built once: it scores any estimate."""
        if self._scorer is None:
            self._scorer = self.inner(self.X0)
        return self._scorer


class GraphSolver:
    """GNC and its re-solves on a GTSAM graph with ``backend``'s factors: ``batch`` (the batch
    solver, reading the graph once per solve), ``dropin`` (GTSAM's LM on our factors),
    ``native`` (GTSAM's ``GncLMOptimizer`` on GTSAM's factors, GTSAM's LM for the re-solves).

    ``graph``: the pose graph (its arrays give the poses' keys); ``factors``: the
    ``gtsam.NonlinearFactorGraph`` of its edges, priors and landmark measurements, in
    that order; ``initial``: ``gtsam.Values``. An estimate is a ``gtsam.Values``.
    """

    def __init__(self, graph: PoseGraph, factors, initial, backend: str, lm_params,
                 progress: Callable | None = None):
        self.graph, self.factors, self.initial = graph, factors, initial
        self.backend, self.lm_params, self.progress = backend, lm_params, progress
        self._scorer = BatchInner(factors, initial, lm_params) if backend == "batch" else None

    def inner(self, start, exclude=()):
        if self.backend == "batch":
            # the batch solver leaves out what weighs 0 throughout (see BatchInner)
            return BatchInner(self.factors, start, self.lm_params, exclude=exclude)
        return GtsamInner(self.factors, start, self.lm_params)

    def gnc(self, params: gncm.GncSettings, start: np.ndarray | None = None, proceed=None,
            first_iterations: int | None = None) -> gncm.GncResult:
        initial = self.initial if start is None else self._values_at(start)
        if self.backend == "native":
            if proceed is not None or first_iterations is not None:
                raise ValueError("GTSAM's GncOptimizer has no hook after its first solve (proceed) "
                                 "and no limit of its own on it (first_iterations)")
            return gtsam_gnc(self.factors, initial, params)
        # the batch inner's states are shown to ``proceed`` as this solver's estimates, Values
        hook = proceed if proceed is None or self.backend != "batch" else (lambda s: proceed(s.to_values()))
        res = gncm.gnc_optimize(self.inner(initial, params.known_outliers), params, self.progress, hook,
                                first_iterations)
        if self.backend == "batch":
            res.values = res.values.to_values()
        return res

    def _values_at(self, poses: np.ndarray):
        """The start's values with the poses (P, m, m), in the pose graph's key order, replaced."""
        import gtsam

        values = gtsam.Values(self.initial)
        values.update(values_from_matrices(self.graph.group, self.graph.keys, poses))
        return values

    def errors(self, values) -> np.ndarray:
        if self._scorer is not None:
            return self._scorer.factor_errors(self._scorer.state(values))
        return np.array([self.factors.at(k).error(values) for k in range(self.factors.size())])

    def refine(self, values, weights: np.ndarray):
        out = self.inner(values, np.flatnonzero(weights == 0.0)).optimize(weights)[0]
        return out.to_values() if self.backend == "batch" else out

    def poses(self, values) -> np.ndarray:
        return matrices_from_values(values, self.graph.group, self.graph.keys)
