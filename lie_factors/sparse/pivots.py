"""When a pivot of a Cholesky factorization is refused: one rule for every factorization of a
linear system the library solves (CHOLMOD's in :mod:`lie_factors.sparse.cholmod`, the
incremental smoother's dense fronts in :mod:`lie_factors.incremental.fronts`).

Eliminating the columns of Λ (symmetric, positive semidefinite) in some order, the pivot of
column p is the Schur complement left of Λ_pp once the columns before it are eliminated:
1/((Λ_KK)⁻¹)_pp with K the columns up to p, which is at least 1/(Λ⁻¹)_pp (equal when p is
last).  A pivot is refused when it is not above :data:`PIVOT_TOLERANCE` times Λ_pp, the
diagonal entry before elimination:

    pivot_p ≤ 1e-13 · Λ_pp   ⇒   Λ_pp · (Λ⁻¹)_pp ≥ 1e13,

a condition number of at least 1e13 of Λ scaled to a unit diagonal, whatever the order.  The
pivot is a difference of terms of the size of Λ_pp, so rounding (unit roundoff 1.1e-16)
leaves it an error of about 1e-16·Λ_pp: at 1e-13·Λ_pp it has fewer than three correct
digits, and so has the variable's solution.  Such a variable is not determined in double
precision: which side of zero its pivot falls on depends on the rounding of the machine
(an AVX-512 CPU and another round a free gauge's pivot differently).  A scaled condition
number of 1e13 is far from any graph that determines its variables: the pose graphs in
``data/``, at their optimum with a prior on their first pose, stay at least 2·10⁴ times
inside it in any order (``benchmarks/pivots.py``).

A tolerance of 0 is the sign rule (a pivot must be > 0): what Levenberg–Marquardt uses,
whose damping makes the system definite, a failed factorization raising λ as GTSAM's does.

Neither numba nor GTSAM is imported here.
"""

from __future__ import annotations

import numpy as np

__all__ = ["PIVOT_TOLERANCE", "first_refused"]

#: A pivot is refused when it is not above this fraction of its diagonal entry before
#: elimination (module docstring).
PIVOT_TOLERANCE = 1e-13


def first_refused(pivots: np.ndarray, diagonal: np.ndarray, tolerance: float = PIVOT_TOLERANCE) -> int:
    """The first position whose pivot is refused, or −1: ``pivots`` (n,) of a factorization,
    ``diagonal`` (n,) the matrix's diagonal in the same order; a pivot passes when it is finite
    and above ``tolerance`` times its diagonal entry (NaN fails)."""
    ok = (pivots > tolerance * diagonal) & (pivots < np.inf)
    return -1 if ok.all() else int(np.argmin(ok))
