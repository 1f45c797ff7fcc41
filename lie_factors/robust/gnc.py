"""Graduated non-convexity (GNC) with GTSAM 4.3's ``GncOptimizer`` semantics, over any inner solver.

Yang, Antonante, Tzoumas, Carlone, "Graduated Non-Convexity for Robust Spatial
Perception", RA-L 2020, as GTSAM implements it (``GncOptimizer.h``,
``GncParams.h``, the graduated weights of ``LossFunctions.cpp``):

1. weights ``w`` start at 1 (0 for known outliers); the inner solver minimizes
   the weighted least squares ``Σ w_k · f_k(x)`` from the *initial* values,
   ``f_k = ½‖R_k e_k‖²`` the factor's Gaussian error (robust noise models are
   replaced by their Gaussian part);
2. the graduation parameter λ starts (``initializeLambda``, Remark 5) at
   ``max_k 2 f_k(x₀)/c̄_k`` for GM and ``min_k c̄_k/(2 f_k(x₀) − c̄_k)`` over
   factors with ``2 f_k(x₀) > c̄_k`` for TLS (floored at 1e-6; −1 — i.e. no
   GNC at all — if no factor qualifies), ``x₀`` the initial values and ``c̄_k``
   the inlier threshold, by default ``½·χ²_{dim_k}(0.99)``;
3. each outer iteration recomputes the weights of the factors that are neither
   known inliers nor known outliers from ``f_k`` at the last solution
   (:func:`gnc_weights`), re-solves from the initial values, and stops when
   ``|cost − prev|/max(prev, 1e-7) < relativeCostTol``, or (TLS) every weight
   is within ``weightsTol`` of 0 or 1, or (GM) λ = 1; otherwise λ ← λ·step
   (TLS; ``SuperLinear``: √λ·step below 1, capped at λ_max) or
   λ ← max(1, λ/step) (GM).

The graduated weights (normalized μ: ``μ = λ/(1 + λ)`` for TLS, ``min(1, 1/λ)``
for GM):

* TLS, ``Linear`` (Yang's Eq. 14): 1 if ``f ≤ μc̄``, 0 if ``f ≥ c̄/μ``, else
  ``(√(μc̄/f) − μ)/(1 − μ)``;
* TLS, ``SuperLinear`` (Peng et al. 2023): 1 if ``f ≤ c̄``, 0 if ``f ≥ c̄/μ²``,
  else ``(√(c̄/f) − μ)/(1 − μ)``;
* GM (Eq. 12): ``(c̄/μ)²/(c̄/μ + f)²``.

The inner solver is anything with the small interface of :class:`InnerSolver`;
:class:`GtsamInner` runs GTSAM's own ``LevenbergMarquardtOptimizer`` on
re-weighted copies of the graph (GTSAM's ``makeWeightedGraph``);
:class:`BatchInner` runs the batch LM on one graph read once, with the weights
as per-factor scales of its normal equations and a restart from the initial
values per solve (the sparsity pattern and CHOLMOD's symbolic analysis are
reused across all of GNC's solves); :func:`gtsam_gnc` is GTSAM's
``GncLMOptimizer`` itself, the reference.  An outlier is a factor whose final weight is
below ½ (for TLS the weights end within ``weightsTol`` of 0 or 1).
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field
from typing import Callable, Protocol, Sequence

import numpy as np

from ..util import stack
from ..kernels.jit import kernel
from ..util.timing import Stopwatch
from .statistics import chi2_inlier_threshold
from .weighted import WeightedLevenbergMarquardt

__all__ = [
    "GncParams", "GncResult", "InnerSolver", "GtsamInner", "BatchInner", "gnc_optimize", "gnc_weights",
    "gtsam_gnc",
    "TLS", "GM", "LINEAR", "SUPERLINEAR",
]

TLS = 0
GM = 1
LINEAR = 0
SUPERLINEAR = 1

# factor types of GncOptimizer (``GncFactorType``)
_NORMAL, _INLIER, _OUTLIER = 0, 1, 2


@dataclass
class GncParams:
    """GTSAM's ``GncParams`` (defaults as in GTSAM 4.3).

    ``loss``: "tls" or "gm"; ``scheduler``: "linear" or "superlinear" (TLS only);
    ``known_inliers`` / ``known_outliers``: factor slots (graph indices);
    ``inlier_probability``: thresholds ``½·χ²_dim(p)`` per factor, unless
    ``inlier_thresholds`` gives them (a scalar or one per factor).
    ``lm_params`` are the inner Levenberg–Marquardt parameters.
    """

    loss: str = "tls"
    max_iterations: int = 100
    lambda_step: float = 1.4
    relative_cost_tol: float = 1e-5
    weights_tol: float = 1e-4
    lambda_max: float = 1e16
    scheduler: str = "linear"
    known_inliers: Sequence[int] = ()
    known_outliers: Sequence[int] = ()
    inlier_probability: float = 0.99
    inlier_thresholds: object = None
    lm_params: object = None
    #: The first solve uses the known inliers only (GTSAM's weighs every factor 1), so that it
    #: starts from a map no unknown factor has bent.  Ours only: ``to_gtsam`` refuses it.
    first_solve_known_inliers: bool = False

    def __post_init__(self):
        self.loss = self.loss.lower()
        self.scheduler = self.scheduler.lower()
        if self.loss not in ("tls", "gm"):
            raise ValueError(f"GNC loss must be 'tls' or 'gm', got {self.loss!r}")
        if self.scheduler not in ("linear", "superlinear"):
            raise ValueError(f"GNC scheduler must be 'linear' or 'superlinear', got {self.scheduler!r}")
        if self.loss == "gm" and self.scheduler != "linear":
            # GncOptimizer::validateLossSchedulerCombination
            raise ValueError("GNC: the scheduler must be 'linear' for the GM loss")
        if not (self.lambda_step > 1.0):
            raise ValueError(f"GNC lambda_step must be > 1, got {self.lambda_step}")

    def to_gtsam(self):
        """The equivalent ``gtsam.GncLMParams`` (thresholds are set on the optimizer, not here)."""
        import gtsam

        if self.first_solve_known_inliers:
            raise ValueError("GTSAM's GncOptimizer has no first_solve_known_inliers")

        lm = self.lm_params if self.lm_params is not None else gtsam.LevenbergMarquardtParams()
        p = gtsam.GncLMParams(lm)
        p.setLossType(gtsam.GncLossType.TLS if self.loss == "tls" else gtsam.GncLossType.GM)
        p.setScheduler(gtsam.GncScheduler.Linear if self.scheduler == "linear"
                       else gtsam.GncScheduler.SuperLinear)
        p.maxIterations = int(self.max_iterations)  # setMaxIterations prints a warning
        p.setLambdaStep(float(self.lambda_step))
        p.setRelativeCostTol(float(self.relative_cost_tol))
        p.setWeightsTol(float(self.weights_tol))
        p.lambdaMax = float(self.lambda_max)
        if len(self.known_inliers):
            p.setKnownInliers([int(i) for i in self.known_inliers])
        if len(self.known_outliers):
            p.setKnownOutliers([int(i) for i in self.known_outliers])
        return p


class InnerSolver(Protocol):
    """What the GNC outer loop needs from a (weighted) least-squares solver.

    ``size``: number of factor slots; ``dims``: (size,) factor dimensions;
    ``factor_errors(values)``: (size,) Gaussian errors ``½‖R_k e_k‖²`` (robust
    losses removed) at ``values``; ``initial``: the initial values;
    ``optimize(weights)``: LM on the graph with every factor's information
    scaled by ``weights[k]``, started from ``initial``; returns
    ``(values, iterations)``.  ``values`` are opaque to the loop.
    """

    size: int
    dims: np.ndarray
    initial: object

    def factor_errors(self, values) -> np.ndarray: ...

    def optimize(self, weights: np.ndarray) -> tuple[object, int]: ...


@dataclass
class GncResult:
    """Outcome of :func:`gnc_optimize`.

    ``weights`` (size,) final GNC weights; ``outliers``: slots with weight < ½
    (sorted); ``thresholds`` (size,) inlier thresholds c̄; ``cost``: the final
    weighted cost ``Σ w_k f_k`` (GTSAM's ``graph_iter.error(result)``);
    ``iterations``: GNC outer iterations run (after the initial solve);
    ``inner_iterations``: LM iterations summed over every inner solve (None
    where unknown: GTSAM's GncLMOptimizer does not report them);
    ``stop``: why GNC stopped.
    """

    values: object
    weights: np.ndarray
    thresholds: np.ndarray
    cost: float
    iterations: int
    inner_iterations: int | None
    lambda_: float | None
    stop: str
    seconds: float
    history: list = field(default_factory=list)

    @property
    def outliers(self) -> np.ndarray:
        return np.flatnonzero(self.weights < 0.5)

    @property
    def inliers(self) -> np.ndarray:
        return np.flatnonzero(self.weights >= 0.5)


# --------------------------------------------------------------------------- #
# Weights (GTSAM LossFunctions.cpp: TruncatedLeastSquares / GemanMcClure::GraduatedWeight)
# --------------------------------------------------------------------------- #

@kernel
def _tls_linear(u2, c2, m):
    if m <= 0.0:
        return 1.0
    if m >= 1.0:
        return 1.0 if u2 <= c2 else 0.0
    if u2 <= m * c2:
        return 1.0
    if u2 >= c2 / m:
        return 0.0
    return (math.sqrt(m * c2 / u2) - m) / (1.0 - m)


@kernel
def _tls_superlinear(u2, c2, m):
    if m >= 1.0:
        return 1.0 if u2 <= c2 else 0.0
    if u2 <= c2:
        return 1.0
    if m <= 0.0:
        return math.sqrt(c2 / u2)
    if u2 >= c2 / (m * m):
        return 0.0
    return (math.sqrt(c2 / u2) - m) / (1.0 - m)


@kernel
def _gm(u2, c2, m):
    if m <= 0.0:
        return 1.0
    c2m = c2 / m
    c4 = c2m * c2m
    s = c2m + u2
    return c4 / (s * s)


@kernel
def gnc_weights(loss, scheduler, lam, errors, thresholds, types, out):
    """GNC weights at graduation parameter ``lam`` (``GncOptimizer::calculateWeights``).

    ``errors`` (F,) factor errors f_k, ``thresholds`` (F,) c̄_k, ``types`` (F,)
    0 normal / 1 known inlier / 2 known outlier; writes ``out`` (F,): known
    inliers 1, known outliers 0, the others the graduated weight.
    """
    if loss == 0:  # TLS: μ = λ/(1 + λ)
        mu = lam / (1.0 + lam)
    else:          # GM: μ = 1/λ, λ saturates at 1
        mu = min(1.0, 1.0 / lam)
    m = min(max(mu, 0.0), 1.0)
    for k in range(errors.shape[0]):
        t = types[k]
        if t == 1:
            out[k] = 1.0
        elif t == 2:
            out[k] = 0.0
        elif loss == 0:
            if scheduler == 0:
                out[k] = _tls_linear(errors[k], thresholds[k], m)
            else:
                out[k] = _tls_superlinear(errors[k], thresholds[k], m)
        else:
            out[k] = _gm(errors[k], thresholds[k], m)


def _initialize_lambda(loss: int, errors0: np.ndarray, thresholds: np.ndarray) -> float:
    """GncOptimizer::initializeLambda (Remark 5), over every factor with a noise model."""
    if loss == GM:
        return float(max(0.0, np.max(2.0 * errors0 / thresholds))) if errors0.size else 0.0
    lam = math.inf
    for rk, c in zip(errors0.tolist(), thresholds.tolist()):
        if 2 * rk - c > 0:
            lam = min(lam, c / (2 * rk - c))
    if 0 <= lam < 1e-6:
        lam = 1e-6
    return lam if (lam > 0 and not math.isinf(lam)) else -1.0


def _update_lambda(loss: int, scheduler: int, lam: float, p: GncParams) -> float:
    if loss == GM:
        return max(1.0, lam / p.lambda_step)
    if scheduler == SUPERLINEAR:
        if lam < 1:
            return min(math.sqrt(lam) * p.lambda_step, p.lambda_max)
        return min(lam * p.lambda_step, p.lambda_max)
    return lam * p.lambda_step


def thresholds_for(dims: np.ndarray, params: GncParams) -> np.ndarray:
    """Per-factor inlier thresholds c̄ (GTSAM's default: ½·χ²_dim at probability 0.99)."""
    F = len(dims)
    if params.inlier_thresholds is not None:
        th = np.broadcast_to(np.asarray(params.inlier_thresholds, dtype=np.float64), (F,)).copy()
        if not np.all(np.isfinite(th)) or np.any(th <= 0):
            raise ValueError("GNC inlier thresholds must be positive and finite")
        return th
    return np.array([chi2_inlier_threshold(int(d), params.inlier_probability) for d in dims])


def factor_types(size: int, params: GncParams) -> np.ndarray:
    """0 normal / 1 known inlier / 2 known outlier per slot; ValueError as GTSAM's constructor."""
    types = np.zeros(size, dtype=np.int64)
    inl = sorted({int(i) for i in params.known_inliers})
    out = sorted({int(i) for i in params.known_outliers})
    for i in inl + out:
        if not 0 <= i < size:
            raise ValueError(f"GNC: known inlier/outlier {i} is not a factor slot (0..{size - 1})")
    if set(inl) & set(out):
        raise ValueError("GNC: a factor is both a known inlier and a known outlier")
    types[inl] = _INLIER
    types[out] = _OUTLIER
    return types


def gnc_optimize(inner: InnerSolver, params: GncParams | None = None,
                 progress: Callable[[int, float, float, int], None] | None = None) -> GncResult:
    """GTSAM's ``GncOptimizer::optimize`` over ``inner``; see the module docstring.

    ``progress(outer_iteration, lambda, cost, inner_iterations)`` after each
    outer iteration.
    """
    clock = Stopwatch()  # numba compilation is not optimization time
    p = params if params is not None else GncParams()
    loss = TLS if p.loss == "tls" else GM
    sched = LINEAR if p.scheduler == "linear" else SUPERLINEAR
    F = int(inner.size)
    dims = np.asarray(inner.dims)
    thresholds = thresholds_for(dims, p)
    types = factor_types(F, p)

    weights = np.ones(F)
    weights[types == _OUTLIER] = 0.0
    if p.first_solve_known_inliers:
        weights[types == _NORMAL] = 0.0
    result, inner_its = inner.optimize(weights)
    lam = _initialize_lambda(loss, inner.factor_errors(inner.initial), thresholds)
    prev_cost = float(np.dot(weights, inner.factor_errors(result)))
    cost = 0.0
    history = []
    n_unknown = int(np.count_nonzero(types == _NORMAL))
    if lam <= 0 or n_unknown == 0:
        stop = "no factor above threshold at the initial values" if lam <= 0 else "no unknown factors"
        return GncResult(result, weights, thresholds, prev_cost, 0, inner_its, lam, stop,
                         clock.seconds(), history)

    stop = "maxIterations"
    new_w = np.empty(F)
    for it in range(p.max_iterations):
        gnc_weights(loss, sched, lam, inner.factor_errors(result), thresholds, types, new_w)
        weights = new_w.copy()
        result, n = inner.optimize(weights)
        inner_its += n
        cost = float(np.dot(weights, inner.factor_errors(result)))
        history.append((it, lam, cost, n))
        if progress is not None:
            progress(it, lam, cost, n)
        # GncOptimizer::checkConvergence: cost, weights (TLS), λ (GM)
        if abs(cost - prev_cost) / max(prev_cost, 1e-7) < p.relative_cost_tol:
            stop = "relative cost change"
            break
        if loss == TLS and np.all(np.abs(weights - np.round(weights)) <= p.weights_tol):
            stop = "binary weights"
            break
        if loss == GM and abs(lam - 1.0) < 1e-9:
            stop = "lambda reached 1"
            break
        lam = _update_lambda(loss, sched, lam, p)
        prev_cost = cost
    return GncResult(result, weights, thresholds, cost, len(history), inner_its, lam, stop,
                     clock.seconds(), history)


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

    def optimize(self, weights: np.ndarray):
        opt = self.gtsam.LevenbergMarquardtOptimizer(self.weighted_graph(weights), self.initial,
                                                     self.lm_params)
        values = stack.call(opt.optimize)  # GTSAM's elimination recurses: a large stack for long chains
        return values, int(opt.iterations())


def _native_iterations(summary: str, max_iterations: int) -> int:
    """Outer iterations from GncOptimizer's SUMMARY output (``final iterations: i``, the loop index)."""
    for line in summary.splitlines():
        if line.startswith("final iterations:"):
            return min(int(line.split(":")[1]) + 1, int(max_iterations))
    return 0  # GNC returned before its loop (λ ≤ 0 or no unknown factors)


def gtsam_gnc(graph, initial, params: GncParams | None = None) -> GncResult:
    """GTSAM's own ``GncLMOptimizer`` on ``graph`` (the reference), reported as a :class:`GncResult`.

    Thresholds are set as ``params`` says (default: ``½·χ²_dim(0.99)``,
    GTSAM's default too); the number of outer iterations is read from GTSAM's
    SUMMARY output; ``cost`` is ``Σ w_k f_k`` at the result, as GTSAM's
    convergence test computes it.  GTSAM's ``CustomFactor`` cannot be cloned,
    which ``GncOptimizer`` needs, so this takes native factors only.
    """
    import gtsam

    t0 = time.perf_counter()
    p = params if params is not None else GncParams()
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
    Cholesky factor of every solve (city10000 with 20 % random false closures:
    20× the time of an iteration).  A slot whose variables no other factor
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
        order: the arrays become the batch problem directly, with no factor object."""
        import gtsam

        from ..batch.graph import Problem

        E, Q = len(pg.edge_keys), len(pg.prior_keys)
        size = E + Q
        excluded = {int(k) for k in exclude}
        if any(not 0 <= k < size for k in excluded):
            raise ValueError(f"BatchInner: excluded slots must be factor slots (0..{size - 1})")
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
        self = cls.__new__(cls)
        self.lm = _GncLevenbergMarquardt(Problem.from_pose_graph(kept, X), None, lm_params,
                                         linear_solver=linear_solver)
        self.size = size
        self.slots = np.concatenate([edges, E + priors_in]).astype(np.int64)
        self._left_out = np.setdiff1d(np.arange(size), self.slots)
        self.dims = np.full(size, pg.info.dim, dtype=np.int64)
        P = self.lm.problem
        self.initial = _BatchState(self.lm, {n: b.X0 for n, b in P.blocks.items()}, gtsam.Values())
        return self

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

    def optimize(self, weights: np.ndarray):
        weights = np.asarray(weights, dtype=np.float64)
        if np.any(weights[self._left_out] != 0.0):
            raise ValueError("BatchInner: an excluded factor slot has a nonzero weight")
        self.lm.restart(weights[self.slots])
        res = self.lm.optimize()
        P = self.lm.problem
        return _BatchState(self.lm, P.elements(), P.other), int(res.iterations)
