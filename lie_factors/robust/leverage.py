"""The closure tests' quadratic form, compiled: T = bᵀ (I + s·H)⁻¹ b.

For a group G of between factors with whitened residual b (dim d) and Jacobian A
on their ends, H = A Σ Aᵀ with Σ the ends' joint marginal covariance.  s = +1
gives the innovation statistic of a group the graph does not hold, s = −1 the
leave-group-out statistic of one it holds (:mod:`lie_factors.robust.leave_out`,
:mod:`lie_factors.robust.online`).  I − H is singular when the group alone
measures what it measures (leverage 1): T is then NaN.

One implementation of the form and of that floor serves the batch check
(:func:`statistics`, over many groups) and the online one
(:func:`lie_factors.incremental.group_statistic.group_statistic`, one group from
the smoother's factor).
"""

from __future__ import annotations

import numpy as np

from ..kernels.jit import inline_kernel, kernel

__all__ = ["SINGULAR", "statistics", "quadratic"]

#: I + s·H is taken as singular (T NaN) when its smallest eigenvalue is at most this: leverage
#: within 1e-9 of 1, where a group's leave-out residual is its own noise divided by ~0.
SINGULAR = 1e-9


@inline_kernel
def quadratic(H, b, sign):
    """bᵀ (I + sign·H)⁻¹ b with H symmetrized; NaN when I + sign·H has an eigenvalue ≤ SINGULAR."""
    d = b.shape[0]
    M = np.empty((d, d))
    for i in range(d):
        for j in range(d):
            M[i, j] = sign * 0.5 * (H[i, j] + H[j, i])
        M[i, i] += 1.0
    if np.linalg.eigvalsh(M)[0] <= SINGULAR:
        return np.nan
    x = np.linalg.solve(M, b)
    acc = 0.0
    for i in range(d):
        acc += b[i] * x[i]
    return acc


@kernel
def statistics(H, b, signs):
    """(K,) T_k = b_kᵀ (I + signs_k·H_k)⁻¹ b_k for H (K, d, d), b (K, d), signs (K,); NaN at
    leverage 1 (:data:`SINGULAR`)."""
    K = b.shape[0]
    out = np.empty(K)
    for k in range(K):
        out[k] = quadratic(H[k], b[k], signs[k])
    return out
