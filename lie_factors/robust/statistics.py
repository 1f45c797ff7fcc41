"""The χ² and F quantiles the robust pipeline's thresholds come from.

:func:`chi2_inlier_threshold`: GTSAM's GNC inlier threshold (½ of the χ²
quantile, cephes' ``igami`` as GTSAM computes it); :func:`f_quantile`: the F
distribution's quantile, by its regularized incomplete beta function;
:func:`fit_scaled_f`: the scale and degrees of freedom of statistics modelled as
s·n·F(n, ν), by maximum likelihood.
"""

from __future__ import annotations

import numpy as np

_CHI2_CACHE: dict[tuple[int, float], float] = {}


def chi2_inlier_threshold(dim: int, probability: float = 0.99) -> float:
    """GTSAM's GNC inlier threshold for a factor of dimension ``dim``: ½·χ²_dim quantile at ``probability``.

    ``GncOptimizer::setInlierCostThresholdsAtProbability(alpha)`` sets
    ``barcSq = 0.5 * Chi2inv(alpha, dim)`` (½ because a factor's error is
    ½‖R e‖²), with the quantile from cephes' ``igami``.  GTSAM's Python wrapper
    does not expose ``Chi2inv``, so the value is read from a one-factor
    ``GncLMOptimizer`` of that dimension: the same bits GTSAM uses, so every
    backend classifies with identical thresholds (the tests check it against a
    40-digit mpmath quantile).
    """
    key = (int(dim), float(probability))
    if key not in _CHI2_CACHE:
        if dim < 1 or not (0.0 < probability < 1.0):
            raise ValueError(f"need dim >= 1 and 0 < probability < 1, got {dim}, {probability}")
        import gtsam

        graph = gtsam.NonlinearFactorGraph()
        graph.add(gtsam.PriorFactorVector(0, np.zeros(dim), gtsam.noiseModel.Unit.Create(dim)))
        values = gtsam.Values()
        values.insert(0, np.zeros(dim))
        gnc = gtsam.GncLMOptimizer(graph, values, gtsam.GncLMParams())
        gnc.setInlierCostThresholdsAtProbability(float(probability))
        _CHI2_CACHE[key] = float(np.asarray(gnc.getInlierCostThresholds())[0])
    return _CHI2_CACHE[key]


_F_CACHE: dict[tuple[float, float, float], float] = {}


def _regularized_beta(mpmath, a, b, x):
    """I_x(a, b), the regularized incomplete beta function, at mpmath's working precision.

    The continued fraction of DLMF 8.17.22, evaluated by the modified Lentz
    method, where it converges fast (x < (a + 1)/(a + b + 2)); elsewhere through
    I_x(a, b) = 1 − I_{1−x}(b, a).  mpmath's own ``betainc`` sums a
    hypergeometric series that stops converging for large a or b (tens of
    thousands of degrees of freedom), and how far it gets depends on mpmath's
    version.
    """
    if x <= 0:
        return mpmath.mpf(0)
    if x >= 1:
        return mpmath.mpf(1)
    if x > (a + 1) / (a + b + 2):
        return 1 - _regularized_beta(mpmath, b, a, 1 - x)
    tiny = mpmath.mpf(10) ** (-3 * mpmath.mp.dps)
    eps = mpmath.mpf(10) ** (-mpmath.mp.dps)
    c, d = mpmath.mpf(1), 1 - (a + b) * x / (a + 1)
    d = 1 / (d if abs(d) > tiny else tiny)
    h = d
    for m in range(1, 100000):
        for num in (m * (b - m) * x / ((a + 2 * m - 1) * (a + 2 * m)),
                    -(a + m) * (a + b + m) * x / ((a + 2 * m) * (a + 2 * m + 1))):
            d = 1 + num * d
            d = 1 / (d if abs(d) > tiny else tiny)
            c = 1 + num / c
            c = c if abs(c) > tiny else tiny
            h *= c * d
        if abs(c * d - 1) < eps:
            break
    else:
        raise ArithmeticError(f"the incomplete beta continued fraction did not converge at a={a}, b={b}, x={x}")
    log_front = a * mpmath.log(x) + b * mpmath.log1p(-x) - mpmath.log(a) - mpmath.log(mpmath.beta(a, b))
    return mpmath.exp(log_front) * h


def f_quantile(d1: float, d2: float, probability: float) -> float:
    """The quantile of Fisher's F distribution with (``d1``, ``d2``) degrees of freedom at ``probability``.

    F(d1, d2) is (χ²_d1/d1)/(χ²_d2/d2); d1·F(d1, d2) is the squared Mahalanobis
    norm of a d1-dimensional Student-t vector with d2 degrees of freedom (as
    d2 → ∞, χ²_d1).  With y = d1·x/(d1·x + d2), P(F > x) = I_{1−y}(d2/2, d1/2)
    (the regularized incomplete beta function by its continued fraction, at 25
    digits, the upper tail taken directly so that probabilities near 1 keep their digits); the
    quantile solves it for y by bisection to a bracket, then Newton's method with
    the beta density, and x = d2·y/(d1·(1 − y)).
    """
    key = (float(d1), float(d2), float(probability))
    if key not in _F_CACHE:
        if not (d1 > 0 and d2 > 0 and 0.0 < probability < 1.0):
            raise ValueError(f"need d1 > 0, d2 > 0 and 0 < probability < 1, got {d1}, {d2}, {probability}")
        import mpmath

        with mpmath.workdps(25):
            a, b = mpmath.mpf(d1) / 2, mpmath.mpf(d2) / 2
            q = 1 - mpmath.mpf(probability)
            beta = mpmath.beta(a, b)

            def upper(y):  # P(F > x(y)) = I_{1-y}(b, a), decreasing in y
                return _regularized_beta(mpmath, b, a, 1 - y)

            lo, hi = mpmath.mpf(0), mpmath.mpf(1)
            for _ in range(12):
                mid = (lo + hi) / 2
                if upper(mid) > q:
                    lo = mid
                else:
                    hi = mid
            y = (lo + hi) / 2
            for _ in range(60):
                f = upper(y) - q
                if f > 0:
                    lo = y
                else:
                    hi = y
                step = f / (y ** (a - 1) * (1 - y) ** (b - 1) / beta)
                nxt = y + step
                if not lo < nxt < hi:
                    nxt = (lo + hi) / 2
                if abs(nxt - y) <= mpmath.mpf(10) ** -20 * min(y, 1 - y):
                    y = nxt
                    break
                y = nxt
            _F_CACHE[key] = float(mpmath.mpf(d2) * y / (mpmath.mpf(d1) * (1 - y)))
    return _F_CACHE[key]


#: The degrees of freedom :func:`fit_scaled_f` searches: above 2, where F(n, ν) has a mean (a group's
#: threshold adds the means of its other members), up to where s·n·F(n, ν) is χ²_n to 10⁻⁵.
DOF_RANGE = (2.04, 1e6)


def _scaled_f_nll(params, T, n, log_T_sum, cut):
    """−log-likelihood of the statistics ``T`` (all ≤ ``cut``) under s·n·F(n, ν) truncated at
    ``cut``; params = (log s, 1/ν)."""
    from scipy.special import fdtr, gammaln

    log_s, u = params
    nu = 1.0 / u
    a, b = 0.5 * n, 0.5 * nu
    log_ns = log_s + np.log(n)
    x = T * np.exp(-log_ns)  # the F variates
    # log f_F(x) = a·log(n/ν) + (a − 1)·log x − (a + b)·log(1 + n·x/ν) − log B(a, b), and T = n·s·x
    log_beta = gammaln(a) + gammaln(b) - gammaln(a + b)
    log_density = (T.size * (a * np.log(n / nu) - log_beta - log_ns) + (a - 1.0) * (log_T_sum - T.size * log_ns)
                   - (a + b) * np.sum(np.log1p(n * x / nu)))
    kept = float(fdtr(n, nu, cut * np.exp(-log_ns))) if np.isfinite(cut) else 1.0
    return -(log_density - T.size * np.log(max(kept, 1e-300)))


def _fit_below(T, n: float, cut: float) -> tuple[float, float]:
    """The maximum-likelihood (s, ν) of the statistics ``T`` ≤ ``cut``, truncated there."""
    from scipy.optimize import minimize

    T = T[T <= cut]
    log_T_sum = float(np.sum(np.log(T)))
    lo, hi = 1.0 / DOF_RANGE[1], 1.0 / DOF_RANGE[0]
    s0 = float(np.log(np.median(T) / n))
    best = min((minimize(_scaled_f_nll, np.array([s0, u0]), args=(T, float(n), log_T_sum, float(cut)),
                         method="L-BFGS-B", bounds=[(None, None), (lo, hi)]) for u0 in (lo, 0.5 * hi)),
               key=lambda r: r.fun)
    return float(np.exp(best.x[0])), float(1.0 / best.x[1])


def fit_scaled_f(T, n: int, probability: float) -> tuple[float, float]:
    """(s, ν): the scale and degrees of freedom of statistics ``T`` (K,) modelled as s·n·F(n, ν),
    the squared norm of an n-dimensional Student-t residual (ν → ∞: s·χ²_n, a noise model off by
    the factor s), by maximum likelihood over the statistics the model itself passes.

    Statistics above the fitted model's ``probability`` quantile are what a test at that
    quantile calls outliers, so they do not shape the model: the likelihood is truncated there,
    starting from χ²_n scaled to the median, and refitted until the statistics below the cut
    stay the same (a forward search: a few outliers cannot fatten the tail that would let
    them in).  ν is searched in :data:`DOF_RANGE`; only finite, positive statistics count.
    ``ValueError`` with fewer than two of them.
    """
    T = np.asarray(T, dtype=np.float64)
    T = np.sort(T[np.isfinite(T) & (T > 0)])
    if T.size < 2:
        raise ValueError(f"fitting s·n·F(n, ν) needs two or more positive statistics, got {T.size}")
    s, nu = float(np.median(T)) / (n * f_quantile(n, DOF_RANGE[1], 0.5)), DOF_RANGE[1]
    cut = s * n * f_quantile(n, nu, probability)
    kept = int(np.searchsorted(T, cut, side="right"))
    for _ in range(T.size):
        if kept < 2:
            break
        s, nu = _fit_below(T, n, cut)
        cut = s * n * f_quantile(n, nu, probability)
        now = int(np.searchsorted(T, cut, side="right"))
        if now == kept:
            break
        kept = now
    return s, nu
