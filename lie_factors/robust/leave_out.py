"""How well a group of factors agrees with the rest of the graph: the leave-group-out χ² test,
and its mirror for a group outside the graph.

At a least-squares solution with whitened Jacobian A, residual b and
H = AᵀA, take a group G of factors (their rows A_G, b_G).  Their residual
predicted by the solution *without* them, and its covariance, give the
statistic (Cook & Weisberg, "Residuals and Influence in Regression", 1982,
§2.2; Baarda's data snooping for one observation)

    T_G = b_Gᵀ (I − H_GG)⁻¹ b_G,     H_GG = A_G H⁻¹ A_Gᵀ,

χ²-distributed with dim(b_G) degrees of freedom when the group is right.  T_G
is the drop in the minimum of the cost if G were left out (twice it, in
½‖·‖² units), so it sees what a factor's own residual hides: a false loop
closure that bent the map to fit has a small residual, but a leverage H_GG near
I.  A group, not one factor at a time, because closures that agree with one
another (perceptual aliasing) each keep the others' residuals small.

For a group *not* in the graph (its factors weigh 0 in H), the same question
is the innovation test: with the residual b_G at the solution without it,

    T_G = b_Gᵀ (I + H_GG)⁻¹ b_G,

χ² with dim(b_G) degrees of freedom if the group is right — the test that
re-admits closures set aside earlier, as a group, where one at a time each
would look wrong (a stretch of true closures that only agree with the map
once all of them are in).

One sparse Cholesky P·H·Pᵀ = L·D·Lᵀ; H_GG = YᵀD⁻¹Y with Y = L⁻¹·P·A_Gᵀ.  A column
of P·A_Gᵀ is nonzero on the variables of two poses only, and L⁻¹ spreads it
along their paths to the root of L's elimination tree (Gilbert and Peierls,
"Sparse partial pivoting in time proportional to arithmetic operations",
1988), so each group is solved on the union of its poses' paths: hundreds of
rows where the system has thousands (intel: 150 of 5184 on average).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import prange

from ..posegraph.graph import PoseGraph
from ..sparse.cholmod import Cholesky, block_order
from ..batch.graph import Problem
from ..batch.loops import parallel_kernel
from ..kernels.sort import sort
from ..batch.system import LinearSystem
from .leverage import statistics

__all__ = ["leave_out_chi2", "group_gram", "UnitLower"]

#: Groups per parallel chunk (each chunk allocates two work arrays of the system's size).
GROUP_CHUNK = 64


class UnitLower(NamedTuple):
    """A factor L·D·Lᵀ: L unit lower triangular in CSC (each column's diagonal first), D (N,)."""

    colptr: np.ndarray
    rowind: np.ndarray
    values: np.ndarray
    d: np.ndarray


@parallel_kernel
def _group_gram(L, pos, o1, o2, A1, A2, gptr, rows, hptr, H):
    """H[hptr[g]:…] = Y_gᵀ·D⁻¹·Y_g (d × d, row-major, d = n·size) for each group g of factors
    ``rows[gptr[g]:gptr[g+1]]`` (indices into o1, o2, A1, A2), Y_g = L⁻¹·P·A_gᵀ on the union of
    the elimination-tree paths from the group's variables (see the module docstring); ``L`` a
    :class:`UnitLower`."""
    colptr, rowind, values, d = L.colptr, L.rowind, L.values, L.d
    N = colptr.shape[0] - 1
    G = gptr.shape[0] - 1
    n = A1.shape[1]
    for ch in prange((G + GROUP_CHUNK - 1) // GROUP_CHUNK):
        loc = np.full(N, -1, dtype=np.int64)
        nodes = np.empty(N, dtype=np.int64)
        for g in range(ch * GROUP_CHUNK, min(G, (ch + 1) * GROUP_CHUNK)):
            count = 0
            for t in range(gptr[g], gptr[g + 1]):
                r = rows[t]
                for side in range(2):
                    base = o1[r] if side == 0 else o2[r]
                    for i in range(n):
                        j = pos[base + i]
                        # up the elimination tree (a column's parent is its smallest off-diagonal
                        # row) until a node already on the reach
                        while j >= 0 and loc[j] == -1:
                            loc[j] = 0
                            nodes[count] = j
                            count += 1
                            parent = N
                            for q in range(colptr[j] + 1, colptr[j + 1]):
                                parent = min(parent, rowind[q])
                            j = parent if parent < N else -1
            reach = nodes[:count].copy()
            sort(reach)  # a child precedes its parent: the order of the sweep
            for k in range(count):
                loc[reach[k]] = k
            dg = n * (gptr[g + 1] - gptr[g])
            Y = np.zeros((count, dg))
            for t in range(gptr[g], gptr[g + 1]):
                r = rows[t]
                col0 = n * (t - gptr[g])
                for c in range(n):
                    for i in range(n):
                        Y[loc[pos[o1[r] + i]], col0 + c] += A1[r, c, i]
                        Y[loc[pos[o2[r] + i]], col0 + c] += A2[r, c, i]
            for k in range(count):
                j = reach[k]
                for q in range(colptr[j] + 1, colptr[j + 1]):
                    li = loc[rowind[q]]
                    v = values[q]
                    for c in range(dg):
                        Y[li, c] -= v * Y[k, c]
            h = hptr[g]
            for a in range(dg):
                for b in range(a, dg):
                    acc = 0.0
                    for k in range(count):
                        acc += Y[k, a] * Y[k, b] / d[reach[k]]
                    H[h + a * dg + b] = acc
                    H[h + b * dg + a] = acc
            for k in range(count):
                loc[reach[k]] = -1


def group_gram(factor: Cholesky, pos: np.ndarray, o1: np.ndarray, o2: np.ndarray, A1: np.ndarray,
               A2: np.ndarray, groups: list) -> list:
    """A_G·H⁻¹·A_Gᵀ for each group of two-variable factors, with ``factor`` a numeric factor of H
    (handed over: see :meth:`~lie_factors.sparse.cholmod.Cholesky.lower`) and ``pos`` (n,) the
    matrix row of each variable scalar.

    Factor f has the (n, n) Jacobian blocks ``A1[f]``, ``A2[f]`` on the variable
    scalars ``o1[f]:o1[f]+n`` and ``o2[f]:o2[f]+n``; ``groups``: sequences of factor
    indices.  Returns one (d, d) array per group, d = n·len(group).
    """
    perm, colptr, rowind, values, d = factor.lower()
    where = np.empty(len(perm), dtype=np.int64)
    where[perm] = np.arange(len(perm))
    pos = where[np.asarray(pos, dtype=np.int64)]
    n = A1.shape[1]
    sizes = np.array([len(G) for G in groups], dtype=np.int64)
    gptr = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
    hptr = np.concatenate([[0], np.cumsum((n * sizes) ** 2)]).astype(np.int64)
    flat = (np.concatenate([np.asarray(G, dtype=np.int64) for G in groups]) if groups
            else np.zeros(0, dtype=np.int64))
    H = np.empty(int(hptr[-1]))
    if len(groups):
        _group_gram(UnitLower(colptr, rowind, values, d), pos, np.ascontiguousarray(o1, dtype=np.int64),
                    np.ascontiguousarray(o2, dtype=np.int64), np.ascontiguousarray(A1),
                    np.ascontiguousarray(A2), gptr, flat, hptr, H)
    return [H[hptr[g]:hptr[g + 1]].reshape(n * sizes[g], n * sizes[g]) for g in range(len(groups))]


def leave_out_chi2(graph: PoseGraph, X: np.ndarray, weights: np.ndarray, groups: list) -> np.ndarray:
    """(G,) T_G of each group at the poses ``X`` (P, m, m) in ``graph.keys`` order.

    ``weights`` (E + Q,): each factor's weight (0: left out of the graph, as a
    rejected closure); ``groups``: lists of between-factor indices, all of
    weight 1 (the leave-group-out test) or all of weight 0 (the innovation
    test).  NaN for a group without which the graph would be singular
    (leverage 1: nothing else measures what it measures; :data:`~lie_factors.robust.leverage.SINGULAR`).
    """
    problem = Problem.from_pose_graph(graph, X)
    problem.linearize()
    between = next(g for g in problem.groups if g.kind == "between")
    # What weighs 0 (a rejected closure between far-apart poses) stays out of the fill-reducing
    # order and of the factor's structure: its blocks of H are 0, and would only add fill to L.
    live = weights[between.fidx] != 0.0
    pairs = np.concatenate([np.stack([between.v1[live], between.v2[live]], axis=1), problem.native_pairs])
    system = LinearSystem(problem, block_order(len(problem.var_dims), pairs[:, 0], pairs[:, 1]))
    system.weights[:] = weights
    system.assemble()
    p = system.pattern
    keep = system.data != 0.0
    keep[p.colptr[:-1]] = True  # the diagonal (first in each column)
    colptr = np.concatenate([[0], np.cumsum(np.add.reduceat(keep, p.colptr[:-1]))]).astype(np.int64) \
        if p.n else np.zeros(1, dtype=np.int64)
    factor = Cholesky(colptr, p.rowind[keep])
    factor.factorize(np.ascontiguousarray(system.data[keep]))
    pos = np.empty(p.n, dtype=np.int64)
    pos[p.scalar_order] = np.arange(p.n)
    where = np.full(problem.graph_size, -1, dtype=np.int64)
    where[between.fidx] = np.arange(between.fidx.size)
    out = np.full(len(groups), np.nan)
    if not groups:
        return out
    rows = [where[np.asarray(G, dtype=np.int64)] for G in groups]
    if any(np.any(r < 0) for r in rows):
        raise ValueError("leave_out_chi2: a group holds a factor that is not a between factor")
    Hs = group_gram(factor, pos, between.o1, between.o2, between.A1, between.A2, rows)
    sizes = np.array([len(G) for G in groups], dtype=np.int64)
    for size in np.unique(sizes).tolist():
        idx = np.flatnonzero(sizes == size)
        Hgg = np.stack([Hs[g] for g in idx])
        w = np.stack([weights[between.fidx[rows[g]]] for g in idx])
        signs = np.where(np.all(w == 1.0, axis=1), -1.0, np.where(np.all(w == 0.0, axis=1), 1.0, np.nan))
        if np.isnan(signs).any():
            raise ValueError("leave_out_chi2: a group must be all in the graph (weight 1) or all out (0)")
        b = np.stack([between.b[rows[g]].reshape(-1) for g in idx])
        out[idx] = statistics(np.ascontiguousarray(Hgg), b, np.ascontiguousarray(signs))
    return out
