"""Graduated non-convexity (GNC) with GTSAM 4.3's ``GncOptimizer`` semantics, over any inner solver.

Yang, Antonante, Tzoumas, Carlone, "Graduated Non-Convexity for Robust Spatial
Perception", RA-L 2020, as GTSAM implements it (``GncOptimizer.h``,
``GncSettings.h``, the graduated weights of ``LossFunctions.cpp``):

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
   (:func:`gnc_weights`), re-solves from the initial values (from the last
   solution with ``warm_start``, ours only), and stops when
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

The inner solver is anything with the small interface of :class:`InnerSolver`
(GTSAM's LM or the batch solver: :mod:`lie_factors.robust.inner`, with GTSAM's own
``GncLMOptimizer`` as the reference).  An outlier is a factor whose final weight is
below ½ (for TLS the weights end within ``weightsTol`` of 0 or 1).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import IntEnum
from typing import Any, Callable, Protocol, Sequence

import numpy as np

from ..kernels.jit import kernel
from ..util.timing import Stopwatch
from .statistics import chi2_inlier_threshold

__all__ = ["GncSettings", "GncResult", "InnerSolver", "gnc_optimize", "gnc_weights", "GncLoss", "Scheduler",
           "TLS", "GM", "LINEAR", "SUPERLINEAR", "DECLINED"]


class GncLoss(IntEnum):
    """GNC's loss: truncated least squares or Geman–McClure (``"tls"``/``"gm"`` at the API)."""

    TLS = 0
    GM = 1


class Scheduler(IntEnum):
    """How TLS's control parameter grows: GTSAM's ``Linear`` (Yang's) or ``SuperLinear`` (Peng's)."""

    LINEAR = 0
    SUPERLINEAR = 1


TLS, GM = GncLoss.TLS, GncLoss.GM
LINEAR, SUPERLINEAR = Scheduler.LINEAR, Scheduler.SUPERLINEAR

# factor types of GncOptimizer (``GncFactorType``)
_NORMAL, _INLIER, _OUTLIER = 0, 1, 2

#: :attr:`GncResult.stop` where ``proceed`` declined the run after its first solve.
DECLINED = "declined after the first solve"


@dataclass
class GncSettings:
    """GTSAM's ``GncSettings`` (defaults as in GTSAM 4.3).

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
    #: Each solve after the first starts from the last solution (a continuation in μ), not from the
    #: initial values as GTSAM's does.  Ours only: ``to_gtsam`` refuses it.
    warm_start: bool = False

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
        if self.warm_start:
            raise ValueError("GTSAM's GncOptimizer has no warm_start: it restarts every solve")

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
    ``optimize(weights, start=None, max_iterations=None)``: LM on the graph with
    every factor's information scaled by ``weights[k]``, started from ``start``
    (values it returned before) or else ``initial``, for at most ``max_iterations``
    iterations where given (asked for by ``first_iterations`` only); returns
    ``(values, iterations)``.
    ``values`` are opaque to the loop.
    """

    size: int
    dims: np.ndarray
    initial: object

    def factor_errors(self, values) -> np.ndarray: ...

    def optimize(self, weights: np.ndarray, start=None, max_iterations: int | None = None) -> tuple[object, int]: ...


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

    values: Any
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


def _update_lambda(loss: int, scheduler: int, lam: float, p: GncSettings) -> float:
    if loss == GM:
        return max(1.0, lam / p.lambda_step)
    if scheduler == SUPERLINEAR:
        if lam < 1:
            return min(math.sqrt(lam) * p.lambda_step, p.lambda_max)
        return min(lam * p.lambda_step, p.lambda_max)
    return lam * p.lambda_step


def thresholds_for(dims: np.ndarray, params: GncSettings) -> np.ndarray:
    """Per-factor inlier thresholds c̄ (GTSAM's default: ½·χ²_dim at probability 0.99)."""
    F = len(dims)
    if params.inlier_thresholds is not None:
        th = np.broadcast_to(np.asarray(params.inlier_thresholds, dtype=np.float64), (F,)).copy()
        if not np.all(np.isfinite(th)) or np.any(th <= 0):
            raise ValueError("GNC inlier thresholds must be positive and finite")
        return th
    return np.array([chi2_inlier_threshold(int(d), params.inlier_probability) for d in dims])


def factor_types(size: int, params: GncSettings) -> np.ndarray:
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


def gnc_optimize(inner: InnerSolver, params: GncSettings | None = None,
                 progress: Callable[[int, float, float, int], None] | None = None,
                 proceed: Callable[[Any], bool] | None = None,
                 first_iterations: int | None = None) -> GncResult:
    """GTSAM's ``GncOptimizer::optimize`` over ``inner``; see the module docstring.

    ``progress(outer_iteration, lambda, cost, inner_iterations)`` after each
    outer iteration.  Ours only: ``proceed(values)``, asked after the first solve, False ends the
    run there (stop :data:`DECLINED`, no outer iteration), so that a caller deciding whether a
    start is worth a GNC run on its first solve does not solve it twice; ``first_iterations``:
    the first solve's LM iterations at most (``inner.optimize``'s ``max_iterations``).
    """
    clock = Stopwatch()  # numba compilation is not optimization time
    p = params if params is not None else GncSettings()
    loss, sched = GncLoss[p.loss.upper()], Scheduler[p.scheduler.upper()]
    F = int(inner.size)
    dims = np.asarray(inner.dims)
    thresholds = thresholds_for(dims, p)
    types = factor_types(F, p)

    weights = np.ones(F)
    weights[types == _OUTLIER] = 0.0
    if p.first_solve_known_inliers:
        weights[types == _NORMAL] = 0.0
    result, inner_its = (inner.optimize(weights) if first_iterations is None
                         else inner.optimize(weights, None, first_iterations))
    prev_cost = float(np.dot(weights, inner.factor_errors(result)))
    history = []
    if proceed is not None and not proceed(result):
        return GncResult(result, weights, thresholds, prev_cost, 0, inner_its, None, DECLINED, clock.seconds(), history)
    lam = _initialize_lambda(loss, inner.factor_errors(inner.initial), thresholds)
    cost = 0.0
    n_unknown = int(np.count_nonzero(types == _NORMAL))
    if lam <= 0 or n_unknown == 0:
        stop = "no factor above threshold at the initial values" if lam <= 0 else "no unknown factors"
        return GncResult(result, weights, thresholds, prev_cost, 0, inner_its, lam, stop,
                         clock.seconds(), history)

    stop = "maxIterations"
    new_w = np.empty(F)
    for it in range(p.max_iterations):
        gnc_weights(int(loss), int(sched), lam, inner.factor_errors(result), thresholds, types, new_w)
        weights = new_w.copy()
        result, n = inner.optimize(weights, result if p.warm_start else None)
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
