"""The inner solvers GNC runs (:class:`~lie_factors.robust.gnc.InnerSolver`), and GTSAM's own GNC.

:class:`GtsamInner` runs GTSAM's ``LevenbergMarquardtOptimizer`` on re-weighted
copies of the graph (GTSAM's ``makeWeightedGraph``); :class:`BatchInner` runs the
batch solver on one graph read once (or on a pose graph's arrays), with the
weights as per-factor scales of its normal equations and a restart from the
initial values per solve (the sparsity pattern and CHOLMOD's symbolic analysis
are reused across all of GNC's solves); :func:`gtsam_gnc` is GTSAM's
``GncLMOptimizer`` itself, the reference.
"""

from __future__ import annotations

import contextlib
import dataclasses
import time

import numpy as np

from ..util import stack
from .gnc import GncResult, GncSettings
from .weighted import WeightedLevenbergMarquardt

__all__ = ["GtsamInner", "BatchInner", "gtsam_gnc", "with_noise"]


# --------------------------------------------------------------------------- #
# Inner solver: GTSAM's own LM on re-weighted copies of the graph
# --------------------------------------------------------------------------- #

def _gaussian_part(noise):
    import gtsam

    if isinstance(noise, gtsam.noiseModel.Robust):
        return noise.noise()
    return noise


def with_noise(factor, noise):
    """``factor`` with noise model ``noise`` (GTSAM's ``cloneWithNewNoiseModel``).

    GTSAM's ``CustomFactor`` cannot be cloned, so lie_factors' factors are
    re-created from their measurement instead.
    """
    from .. import factors as F

    if isinstance(factor, F.BetweenFactor):
        k1, k2 = factor.keys()
        return type(factor)(k1, k2, factor.measured(), noise)
    if isinstance(factor, F.PriorFactor):
        return type(factor)(factor.keys()[0], factor.prior(), noise)
    return factor.cloneWithNewNoiseModel(noise)


class GtsamInner:
    """:class:`InnerSolver` running ``gtsam.LevenbergMarquardtOptimizer`` (GTSAM's ``GncLMOptimizer`` inner loop).

    Builds ``nfg`` (robust noise replaced by its Gaussian part) once, and per
    call the weighted graph as ``makeWeightedGraph`` does:
    ``Gaussian.Information(w·Ω)``.
    """

    def __init__(self, graph, initial, lm_params=None):
        import gtsam

        self.gtsam = gtsam
        self.lm_params = lm_params if lm_params is not None else gtsam.LevenbergMarquardtParams()
        self.initial = initial
        self.factors = []
        self.noise = []
        for k in range(graph.size()):
            f = graph.at(k)
            if f is None:
                raise ValueError(f"GNC: factor slot {k} is empty")
            noise = _gaussian_part(f.noiseModel())
            if noise is not f.noiseModel():
                f = with_noise(f, noise)
            self.factors.append(f)
            self.noise.append(noise)
        self.size = len(self.factors)
        self.dims = np.array([f.dim() for f in self.factors], dtype=np.int64)
        self._info = [n.information() for n in self.noise]

    def factor_errors(self, values) -> np.ndarray:
        return np.array([f.error(values) for f in self.factors])

    def weighted_graph(self, weights: np.ndarray):
        gtsam = self.gtsam
        g = gtsam.NonlinearFactorGraph()
        for f, info, w in zip(self.factors, self._info, weights):
            g.add(with_noise(f, gtsam.noiseModel.Gaussian.Information(float(w) * info)))
        return g

    def optimize(self, weights: np.ndarray, start=None, max_iterations: int | None = None):
        with iteration_limit(self.lm_params, max_iterations):
            opt = self.gtsam.LevenbergMarquardtOptimizer(self.weighted_graph(weights),
                                                         self.initial if start is None else start, self.lm_params)
            values = stack.call(opt.optimize)  # GTSAM's elimination recurses: a large stack for long chains
        return values, int(opt.iterations())


@contextlib.contextmanager
def iteration_limit(lm_params, max_iterations: int | None):
    """``lm_params`` (``gtsam.LevenbergMarquardtParams``) with at most ``max_iterations`` iterations
    inside the block (its own limit where that is lower, or where ``max_iterations`` is None), its
    own limit again after."""
    own = int(lm_params.getMaxIterations())
    if max_iterations is None or max_iterations >= own:
        yield lm_params
        return
    lm_params.setMaxIterations(int(max_iterations))
    try:
        yield lm_params
    finally:
        lm_params.setMaxIterations(own)


def _native_iterations(summary: str, max_iterations: int) -> int:
    """Outer iterations from GncOptimizer's SUMMARY output (``final iterations: i``, the loop index)."""
    for line in summary.splitlines():
        if line.startswith("final iterations:"):
            return min(int(line.split(":")[1]) + 1, int(max_iterations))
    return 0  # GNC returned before its loop (λ ≤ 0 or no unknown factors)


def gtsam_gnc(graph, initial, params: GncSettings | None = None) -> GncResult:
    """GTSAM's own ``GncLMOptimizer`` on ``graph`` (the reference), reported as a :class:`GncResult`.

    Thresholds are set as ``params`` says (default: ``½·χ²_dim(0.99)``,
    GTSAM's default too); the number of outer iterations is read from GTSAM's
    SUMMARY output; ``cost`` is ``Σ w_k f_k`` at the result, as GTSAM's
    convergence test computes it.  GTSAM's ``CustomFactor`` cannot be cloned,
    which ``GncOptimizer`` needs, so this takes native factors only.
    """
    import gtsam

    t0 = time.perf_counter()
    p = params if params is not None else GncSettings()
    gp = p.to_gtsam()
    gp.setVerbosityGNC(gtsam.GncLMParams.Verbosity.SUMMARY)
    th = p.inlier_thresholds
    if th is not None and np.ndim(th) != 0:
        raise ValueError("gtsam's GncLMOptimizer (Python) takes one inlier threshold for all factors")
    capture = gtsam.RedirectCout()
    try:
        opt = gtsam.GncLMOptimizer(graph, initial, gp)
        if th is None:
            opt.setInlierCostThresholdsAtProbability(float(p.inlier_probability))
        else:
            opt.setInlierCostThresholds(float(th))
        thresholds = np.asarray(opt.getInlierCostThresholds(), dtype=np.float64).copy()
        values = stack.call(opt.optimize)  # GTSAM's elimination recurses: a large stack for long chains
    finally:
        summary = capture.str()
        del capture
    seconds = time.perf_counter() - t0
    weights = np.asarray(opt.getWeights(), dtype=np.float64).copy()
    errors = np.array([_gaussian_error(graph.at(k), values) for k in range(graph.size())])
    cost = float(np.dot(weights, errors))
    iterations = _native_iterations(summary, p.max_iterations)
    stop = ("binary weights" if "weightsConverged = true" in summary
            else "relative cost change" if "checkCostConvergence = true" in summary
            else "lambda reached 1" if "lambdaConverged = true" in summary
            else "no GNC iterations" if iterations == 0 else "maxIterations")
    return GncResult(values, weights, thresholds, cost, iterations, None, None, stop, seconds)


def _gaussian_error(factor, values) -> float:
    noise = factor.noiseModel()
    if hasattr(noise, "noise") and type(noise).__name__ == "Robust":
        return 0.5 * float(noise.noise().squaredMahalanobisDistance(factor.unwhitenedError(values)))
    return float(factor.error(values))


# --------------------------------------------------------------------------- #
# Inner solver: the batch LM, one graph read for all of GNC
# --------------------------------------------------------------------------- #

class _BatchState:
    """An estimate of the batch problem (element arrays + other Values); ``to_values()`` → gtsam.Values."""

    def __init__(self, lm, Xs, other):
        self._lm, self.Xs, self.other = lm, Xs, other

    def to_values(self):
        P = self._lm.problem
        P.accept(dict(self.Xs), self.other)
        return P.values()


class _GncLevenbergMarquardt(WeightedLevenbergMarquardt):
    # GNC converts only its final estimate to a gtsam.Values.
    def values(self):
        return None


class BatchInner:
    """:class:`InnerSolver` on :class:`~lie_factors.robust.weighted.WeightedLevenbergMarquardt`.

    GNC's graph (robust noise models replaced by their Gaussian part, as
    ``GncOptimizer``'s constructor does) is read once; each solve restarts LM
    from the initial values with the GNC weights as per-factor scales ``s_f``:
    the rows of factor f scaled by √s_f, i.e. information ``s_f·Ω_f`` — GTSAM's
    ``makeWeightedGraph`` without building a graph.

    ``exclude``: factor slots that weigh 0 in every solve (GNC's known
    outliers), left out of the solver's graph: a false loop closure joins
    far-apart poses, and its mere place in the sparsity pattern fills the
    Cholesky factor of every solve.  A slot whose variables no other factor
    holds stays in.  Their :meth:`factor_errors` are reported as 0.
    """

    def __init__(self, graph, initial, lm_params=None, linear_solver: str = "auto", exclude=()):
        import gtsam

        size = int(graph.size())
        excluded = {int(k) for k in exclude}
        if any(not 0 <= k < size for k in excluded):
            raise ValueError(f"BatchInner: excluded slots must be factor slots (0..{size - 1})")
        held: set = set()
        for k in range(size):
            if k not in excluded:
                held.update(graph.at(k).keys())
        slots = [k for k in range(size) if k not in excluded or not set(graph.at(k).keys()) <= held]
        stripped = gtsam.NonlinearFactorGraph()
        for k in slots:
            f = graph.at(k)
            noise = _gaussian_part(f.noiseModel())
            stripped.add(f if noise is f.noiseModel() else with_noise(f, noise))
        self.lm = _GncLevenbergMarquardt(stripped, initial, lm_params, linear_solver=linear_solver)
        self._pose_graph = None
        self.size = size
        self.slots = np.asarray(slots, dtype=np.int64)
        self._left_out = np.setdiff1d(np.arange(size), self.slots)
        self.dims = np.array([graph.at(k).dim() for k in range(size)], dtype=np.int64)
        P = self.lm.problem
        self.initial = _BatchState(self.lm, {n: b.X0 for n, b in P.blocks.items()},
                                   gtsam.Values(P.other))

    @classmethod
    def from_pose_graph(cls, pg, X: np.ndarray, lm_params=None, linear_solver: str = "auto",
                        exclude=()) -> "BatchInner":
        """The same solver on a :class:`~lie_factors.posegraph.graph.PoseGraph` (its edges, then its
        priors, are the factor slots), starting from the poses ``X`` (P, m, m) in ``pg.keys``
        order: the arrays become the batch problem directly, with no factor object.

        Here a solve also leaves out every slot its weights set to 0 (TLS's weights are exactly 0
        beyond its outer threshold): a rejected closure's place in the pattern fills the factor
        as a known outlier's would.  The pattern is read again when that set changes; the
        factor errors still cover every slot."""
        import gtsam

        size = len(pg.edge_keys) + len(pg.prior_keys)
        excluded = {int(k) for k in exclude}
        if any(not 0 <= k < size for k in excluded):
            raise ValueError(f"BatchInner: excluded slots must be factor slots (0..{size - 1})")
        self = cls.__new__(cls)
        self._pose_graph = (pg, X, lm_params, linear_solver)
        self.lm, self.slots = self._pose_graph_lm(excluded)
        self.size = size
        self._left_out = np.setdiff1d(np.arange(size), self.slots)
        self.dims = np.full(size, pg.info.dim, dtype=np.int64)
        self._solver = (frozenset(), self.lm, self.slots)
        P = self.lm.problem
        self.initial = _BatchState(self.lm, {n: b.X0 for n, b in P.blocks.items()}, gtsam.Values())
        return self

    def _pose_graph_lm(self, excluded: set):
        """(LM on the pose graph without the slots ``excluded``, the slots it holds)."""
        from ..batch.graph import Problem

        pg, X, lm_params, linear_solver = self._pose_graph
        E, Q = len(pg.edge_keys), len(pg.prior_keys)
        edge_out = {k for k in excluded if k < E}
        prior_out = {k - E for k in excluded if k >= E}
        ek, pk = pg.edge_keys.tolist(), pg.prior_keys.tolist()
        held = {key for k in range(E) if k not in edge_out for key in ek[k]}
        held |= {pk[q] for q in range(Q) if q not in prior_out}
        # a left-out slot whose variables no other factor holds stays in (as for a graph)
        edges = np.array([k for k in range(E) if k not in edge_out or not set(ek[k]) <= held], dtype=np.int64)
        priors_in = np.array([q for q in range(Q) if q not in prior_out or pk[q] not in held], dtype=np.int64)
        kept = dataclasses.replace(pg.with_edges(edges), prior_keys=pg.prior_keys[priors_in],
                                   prior_measured=pg.prior_measured[priors_in],
                                   prior_information=pg.prior_information[priors_in], landmarks=None)
        lm = _GncLevenbergMarquardt(Problem.from_pose_graph(kept, X), None, lm_params, linear_solver=linear_solver)
        return lm, np.concatenate([edges, E + priors_in]).astype(np.int64)

    def _solver_for(self, weights: np.ndarray):
        """(LM, its slots) for a solve at ``weights``: the one holding every slot not permanently
        left out, or, on a pose graph, one without the slots weighing 0."""
        if self._pose_graph is None:
            return self.lm, self.slots
        zero = frozenset(self.slots[weights[self.slots] == 0.0].tolist())
        if zero != self._solver[0]:
            lm, slots = (self.lm, self.slots) if not zero else self._pose_graph_lm(set(self._left_out.tolist()) | zero)
            self._solver = (zero, lm, slots)
        return self._solver[1], self._solver[2]

    def factor_errors(self, state) -> np.ndarray:
        out = np.zeros(self.size)
        out[self.slots] = self.lm.factor_errors(state.Xs, state.other)
        return out

    def state(self, values) -> "_BatchState":
        """An estimate of this problem read from ``gtsam.Values`` (every variable of the graph)."""
        from ..batch.graph import matrices_of

        import gtsam

        P = self.lm.problem
        Xs = {name: matrices_of(values, name, b.keys) for name, b in P.blocks.items()}
        other = gtsam.Values()
        if P.other.size():
            other = gtsam.Values(values)
            for b in P.blocks.values():
                for k in b.keys:
                    other.erase(int(k))
        return _BatchState(self.lm, Xs, other)

    def optimize(self, weights: np.ndarray, start: "_BatchState | None" = None, max_iterations: int | None = None):
        weights = np.asarray(weights, dtype=np.float64)
        if np.any(weights[self._left_out] != 0.0):
            raise ValueError("BatchInner: an excluded factor slot has a nonzero weight")
        lm, slots = self._solver_for(weights)
        lm.restart(weights[slots], None if start is None else (start.Xs, start.other))
        with iteration_limit(lm.params, max_iterations):
            res = lm.optimize()
        P = lm.problem
        return _BatchState(self.lm, P.elements(), P.other), int(res.iterations)
