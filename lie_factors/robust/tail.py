"""The final check's model of a loop closure's statistic and its bounds, shared by the batch
rejection (:mod:`lie_factors.robust.rejection`) and the online one (:mod:`lie_factors.robust.online`):
the same thresholds, groups and rounds in both."""

from __future__ import annotations

import numpy as np

from .statistics import DOF_RANGE, f_quantile, fit_scaled_f

__all__ = ["TailModel", "TAIL_DOF", "GROUP_WINDOW", "GROUP_MAX", "MAX_ROUNDS"]

#: Rounds of the final check (each one re-solve).
MAX_ROUNDS = 8

#: The heaviest tail the final check allows (Student-t degrees of freedom): F(3, 5) puts its 0.999
#: quantile at 37× its median, as the true closures of intel, CSAIL and manhattan do (30–38×).  The
#: fit to a graph's own statistics takes over where its tail is lighter (synthetic and 3-D graphs).
TAIL_DOF = 5.0

#: Closures whose corresponding ends are at most this many poses apart are tested as one group.
GROUP_WINDOW = 10

#: At most this many closures per group (clusters of aliased closures are 3–10 long).
GROUP_MAX = 10


class TailModel:
    """The final check's model of a closure's statistic T: s·n·F(n, ν) (n the pose dimension),
    the squared norm of an n-dimensional Student-t residual; ν → ∞ is s·χ²_n, a noise model
    off by the factor s.

    ``singles`` (K,): the statistics of accepted single closures.  (s, ν) is their maximum-
    likelihood fit over the statistics it passes (:func:`~lie_factors.robust.statistics.fit_scaled_f`),
    where that fit's tail is no heavier than ν = ``dof`` (default :data:`TAIL_DOF`); otherwise ν
    is ``dof`` and s = median/(n·median F(n, ν)).  With one finite statistic, or ``fit`` False,
    ν = ``dof`` and s from the median; with none, the noise models' own scale, s = 1.  :meth:`threshold` of a group of g closures, at
    ``probability`` p, is that of g independent closures:

    * g = 1: the quantile s·n·F⁻¹_{n,ν}(p);
    * g > 1: the larger of one large term plus the others' mean ("one big jump":
      P(T₁ + … + T_g > x) ≈ g·P(T₁ > x) far in a heavy tail),
      s·(n·F⁻¹_{n,ν}(1 − (1 − p)/g) + (g − 1)·n·ν/(ν − 2)), and the sum's light-tail limit, s times
      χ²_gn's quantile, where one big jump is too low (a scale mixture of χ²_n is more spread than
      χ²_n, so the sum's upper quantiles are not below it).
    """

    def __init__(self, n: int, singles: np.ndarray, probability: float, dof: float | None = None,
                 fit: bool = True):
        dof = TAIL_DOF if dof is None else float(dof)
        if not dof > 2.0:
            raise ValueError(f"the tail model needs more than 2 degrees of freedom (a finite mean), got {dof}")
        singles = np.asarray(singles, dtype=np.float64)
        finite = singles[np.isfinite(singles) & (singles > 0)]
        self.n, self.probability = int(n), float(probability)
        self.scale, self.dof = 1.0, dof
        if fit and finite.size >= 2:
            s, nu = fit_scaled_f(finite, self.n, self.probability)
            if nu > dof:
                self.scale, self.dof = s, nu
                return
        if finite.size:
            self.scale = float(np.median(finite)) / (n * f_quantile(n, dof, 0.5))

    def threshold(self, g: int = 1) -> float:
        """The largest statistic a group of ``g`` true closures passes with."""
        n, nu, p = self.n, self.dof, self.probability
        if g == 1:
            return self.scale * n * f_quantile(n, nu, p)
        one_big_jump = n * f_quantile(n, nu, 1.0 - (1.0 - p) / g) + (g - 1) * n * nu / (nu - 2.0)
        light = g * n * f_quantile(g * n, DOF_RANGE[1], p)  # χ²_gn to 10⁻⁵
        return self.scale * max(one_big_jump, light)
