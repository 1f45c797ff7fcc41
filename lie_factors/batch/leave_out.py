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

One sparse Cholesky P·H·Pᵀ = L·D·Lᵀ; H_GG = Zᵀ D⁻¹ Z with Z = L⁻¹·P·A_Gᵀ, one
triangular sweep per column, in chunks of columns.
"""

from __future__ import annotations

import numpy as np

from ..pose_graph import PoseGraph
from .cholmod import Cholesky
from .graph import Problem
from .system import LinearSystem

__all__ = ["leave_out_chi2", "CHUNK_COLUMNS"]

#: Right-hand-side columns per solve (bounds the dense block: n × CHUNK_COLUMNS doubles).
CHUNK_COLUMNS = 1024


def leave_out_chi2(graph: PoseGraph, X: np.ndarray, weights: np.ndarray, groups: list) -> np.ndarray:
    """(G,) T_G of each group at the poses ``X`` (P, m, m) in ``graph.keys`` order.

    ``weights`` (E + Q,): each factor's weight (0: left out of the graph, as a
    rejected closure); ``groups``: lists of between-factor indices, all of
    weight 1 (the leave-group-out test) or all of weight 0 (the innovation
    test).  NaN for a group without which the graph would be singular
    (leverage 1: nothing else measures what it measures).
    """
    problem = Problem.from_pose_graph(graph, X)
    problem.linearize()
    system = LinearSystem(problem)
    system.weights[:] = weights
    system.assemble()
    p = system.pattern
    factor = Cholesky(p.colptr, p.rowind)
    factor.factorize(system.data)
    between = next(g for g in problem.groups if g.kind == "between")
    where = np.full(problem.graph_size, -1, dtype=np.int64)
    where[between.fidx] = np.arange(between.fidx.size)
    n = between.A1.shape[1]
    out = np.full(len(groups), np.nan)
    sizes = np.array([len(G) for G in groups], dtype=np.int64)
    order = np.argsort(sizes, kind="stable")  # equal sizes side by side: one batched solve per run
    start = 0
    while start < len(order):
        # a chunk of whole groups
        stop, width = start, 0
        while stop < len(order) and (width == 0 or width + n * sizes[order[stop]] <= CHUNK_COLUMNS):
            width += n * sizes[order[stop]]
            stop += 1
        chunk = order[start:stop]
        rows = where[np.concatenate([np.asarray(groups[g], dtype=np.int64) for g in chunk])]
        if np.any(rows < 0):
            raise ValueError("leave_out_chi2: a group holds a factor that is not a between factor")
        inside = weights[between.fidx[rows]]
        B = np.zeros((p.n, width), order="F")
        cols = np.arange(width).reshape(-1, n)
        block = np.arange(n)
        B[(between.o1[rows][:, None] + block)[:, :, None], cols[:, None, :]] = np.swapaxes(between.A1[rows], 1, 2)
        B[(between.o2[rows][:, None] + block)[:, :, None], cols[:, None, :]] = np.swapaxes(between.A2[rows], 1, 2)
        Z, dinv = factor.half(system.in_matrix_order(B))
        Zw = Z * np.sqrt(dinv)[:, None]
        f0 = g0 = 0  # factors and groups of the chunk before this run of one size
        for size in np.unique(sizes[chunk]).tolist():
            k = int(np.count_nonzero(sizes[chunk] == size))
            d = n * size
            Y = np.ascontiguousarray(Zw[:, n * f0:n * f0 + k * d].reshape(p.n, k, d).transpose(1, 2, 0))
            Hgg = Y @ Y.transpose(0, 2, 1)
            w = inside[f0:f0 + k * size].reshape(k, size)
            signs = np.where(np.all(w == 1.0, axis=1), -1.0, np.where(np.all(w == 0.0, axis=1), 1.0, np.nan))
            if np.isnan(signs).any():
                raise ValueError("leave_out_chi2: a group must be all in the graph (weight 1) or all out (0)")
            M = np.eye(d)[None] + signs[:, None, None] * Hgg
            b = between.b[rows[f0:f0 + k * size]].reshape(k, d)
            ok = np.linalg.eigvalsh(M)[:, 0] > 1e-9
            T = np.full(k, np.nan)
            if ok.any():
                T[ok] = np.einsum("ki,ki->k", b[ok], np.linalg.solve(M[ok], b[ok][:, :, None])[:, :, 0])
            out[chunk[g0:g0 + k]] = T
            f0 += k * size
            g0 += k
        start = stop
    return out
