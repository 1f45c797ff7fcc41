"""A robust smoother's closure statistic from its factor, in one compiled call.

T = bᵀ (I + s·A Σ Aᵀ)⁻¹ b (:mod:`lie_factors.robust.leverage`) of a group of between
factors at the smoother's estimate: their residuals and Jacobians at θ ⊕ δ of their
ends, and A Σ Aᵀ from one forward substitution over the union of the ends' paths
to their roots (:func:`~lie_factors.incremental.substitution.solve_on_paths`), so
its cost is those paths' nodes and separators, not the graph's size.
"""

from __future__ import annotations

import numpy as np

from ..batch.loops import Factors, factor_range
from ..kernels.jit import direct, kernel
from ..kernels.retraction import retract_range
from ..robust.leverage import quadratic
from .substitution import solve_on_paths

__all__ = ["group_statistic"]


@kernel
def _on_paths(g, Xg, velem, voff, delta, variables, where, C, R, sign, tree, pools):
    """T of between factors ``where`` (g, 2: places in ``variables``) with M⁻¹ ``C`` and whitening
    ``R``, at the estimates θ ⊕ δ of their ends ``variables`` (θ of variable v: ``Xg[velem[v]]``,
    δ_v at ``voff[v]`` in ``delta``)."""
    K, m = variables.shape[0], Xg.shape[1]
    X0 = np.empty((K, m, m))
    offsets = np.empty(K, dtype=np.int64)
    off = np.empty(K + 1, dtype=np.int64)  # each end's first row in Aᵀ
    off[0] = 0
    for e in range(K):
        X0[e] = Xg[velem[variables[e]]]
        offsets[e] = voff[variables[e]]
        off[e + 1] = off[e] + tree.dim[variables[e]]
    X = np.empty((K, m, m))
    retract_range(g, X0, delta, offsets, X, 0, K)
    G, n = where.shape[0], R.shape[1]
    A1, A2, b, sq = np.empty((G, n, n)), np.empty((G, n, n)), np.empty((G, n)), np.empty(G)
    fs = Factors(where[:, 0].copy(), where[:, 1].copy(), C, R, np.arange(G))
    factor_range(g, X, fs, A1, A2, b, sq, 0, G, True)
    At = np.zeros((off[K], G * n))  # Aᵀ by the ends' blocks of rows
    for t in range(G):
        r1, r2 = off[where[t, 0]], off[where[t, 1]]
        for i in range(n):
            for j in range(n):
                At[r1 + i, t * n + j] += A1[t, j, i]
                At[r2 + i, t * n + j] += A2[t, j, i]
    _, Z = solve_on_paths(variables, At, tree, pools)
    return quadratic(np.dot(Z.T, Z), b.reshape(G * n), sign)


_entries: dict = {}  # group tag (each a numba type of its own) -> _on_paths compiled for it


def group_statistic(smoother, el, variables, where, C, R, sign: float) -> float:
    """T of one group of between factors of ``smoother`` (an incremental
    :class:`~lie_factors.incremental.Smoother`), all of group ``el`` (one of its ``elements``):
    ``variables`` (e,) int64 the distinct ends' variables, ``where`` (g, 2) int64 each factor's
    two ends as places in ``variables``, ``C`` (g, m, m) the measurements' inverses and ``R``
    (g, n, n) their whitening, C-ordered.  The residuals and Jacobians at the smoother's estimate;
    H = A Σ Aᵀ from one forward substitution over the union of the ends' paths to their roots
    (:func:`~lie_factors.incremental.substitution.solve_on_paths`)."""
    entry = _entries.get(el.loops.g)
    if entry is None:
        entry = _entries[el.loops.g] = direct(_on_paths)
    smoother._solve()
    delta = smoother.step
    return float(entry(el.loops.g, el.X, smoother.velem, smoother.bf.tree.voff, delta, variables, where, C, R,
                       float(sign), smoother.bf.tree, smoother.bf.pools))
