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

Two ways to H_GG from a sparse Cholesky P·H·Pᵀ = L·D·Lᵀ:

- **On paths.** H_GG = YᵀD⁻¹Y with Y = L⁻¹·P·A_Gᵀ: a column of P·A_Gᵀ is nonzero
  on the variables of two poses only, and L⁻¹ spreads it along their paths to
  the root of L's elimination tree (Gilbert and Peierls, "Sparse partial pivoting
  in time proportional to arithmetic operations", 1988), so each group is solved
  on the union of its poses' paths: hundreds of rows where the system has
  thousands (intel: 150 of 5184 on average).  Every group out of the graph takes
  this way: its ends are far apart, and their block in the factor's pattern
  would bring back the fill its weight 0 keeps out.
- **By selected inversion**, for the groups in the graph: the blocks of H⁻¹ among
  a group's poses lie on L's pattern once the blocks among them are in H's (as
  zeros where no factor joins them), and selected inversion
  (:mod:`lie_factors.sparse.selinv`) gives every block of H⁻¹ on that pattern for
  the products of one sweep over the factor.  Where the graph's separators are
  large (a 3-D grid, a torus), every path crosses them, and one sweep costs less
  than a path per group; on a near-chain the paths are short.  The count of
  multiply-adds of each way decides (:func:`_selected_inverse_is_cheaper`).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import prange

from ..posegraph.graph import PoseGraph
from ..sparse.cholmod import Cholesky, block_order, direct_available, lower_csc
from ..sparse.selinv import diagonal_blocks, invert_in_place
from ..sparse.supernodes import Supernodes
from ..batch.graph import Problem
from ..batch.loops import parallel_kernel
from ..kernels.jit import kernel
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
    lower = factor.lower()
    return _path_gram(lower, _factor_rows(lower[0], pos), o1, o2, A1, A2, groups)


def _factor_rows(perm: np.ndarray, pos: np.ndarray) -> np.ndarray:
    """(n,) the factor's row of each variable scalar: ``pos`` (its matrix row) through the
    factor's permutation ``perm`` (position → matrix row)."""
    where = np.empty(len(perm), dtype=np.int64)
    where[perm] = np.arange(len(perm))
    return where[np.asarray(pos, dtype=np.int64)]


def _path_gram(lower: tuple, at: np.ndarray, o1, o2, A1, A2, groups: list) -> list:
    """:func:`group_gram` from ``lower``, :meth:`~lie_factors.sparse.cholmod.Cholesky.lower`'s arrays,
    with ``at`` (n,) the factor's row of each variable scalar (:func:`_factor_rows`)."""
    _, colptr, rowind, values, d = lower
    n = A1.shape[1]
    sizes = np.array([len(G) for G in groups], dtype=np.int64)
    gptr = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
    hptr = np.concatenate([[0], np.cumsum((n * sizes) ** 2)]).astype(np.int64)
    flat = (np.concatenate([np.asarray(G, dtype=np.int64) for G in groups]) if groups
            else np.zeros(0, dtype=np.int64))
    H = np.empty(int(hptr[-1]))
    if len(groups):
        _group_gram(UnitLower(colptr, rowind, values, d), at, np.ascontiguousarray(o1, dtype=np.int64),
                    np.ascontiguousarray(o2, dtype=np.int64), np.ascontiguousarray(A1),
                    np.ascontiguousarray(A2), gptr, flat, hptr, H)
    return [H[hptr[g]:hptr[g + 1]].reshape(n * sizes[g], n * sizes[g]) for g in range(len(groups))]


@kernel
def _path_entries(colptr, rowind):
    """(N,) the entries of L's columns on the path from each column to the root of the
    elimination tree (a column's parent: its smallest off-diagonal row, always a later column)."""
    N = colptr.shape[0] - 1
    out = np.zeros(N, dtype=np.int64)
    for j in range(N - 1, -1, -1):
        parent = N
        for q in range(colptr[j] + 1, colptr[j + 1]):
            parent = min(parent, rowind[q])
        out[j] = colptr[j + 1] - colptr[j] + (out[parent] if parent < N else 0)
    return out


def _selected_inverse_is_cheaper(colptr: np.ndarray, rowind: np.ndarray, at: np.ndarray, offsets: np.ndarray,
                                 n: int, sizes: np.ndarray, ends: list) -> bool:
    """Whether the groups in the graph cost fewer multiply-adds by selected inversion than on paths.

    Paths: each group's d = n·size columns swept over the entries on its ends' paths (their
    sum: an upper bound of the union's).  Selected inversion: Σ_j c_j² over L's columns of c_j
    entries, its products' count (:mod:`lie_factors.sparse.selinv`), the blocks among each
    group's poses not counted.  L: ``colptr``, ``rowind``; ``at`` (n,) the factor's row of
    each variable scalar, ``offsets`` each variable's first scalar.
    """
    on_path = _path_entries(colptr, rowind)
    first_row = at[offsets]  # a variable's first scalar: every other one is on its path
    paths = sum(int(n * size) * int(on_path[first_row[v]].sum()) for size, v in zip(sizes.tolist(), ends))
    counts = np.diff(colptr).astype(np.float64)
    return float(np.dot(counts, counts)) < paths


def leave_out_chi2(graph: PoseGraph, X: np.ndarray, weights: np.ndarray, groups: list) -> np.ndarray:
    """(G,) T_G of each group at the poses ``X`` (P, m, m) in ``graph.keys`` order.

    ``weights`` (E + Q,): each factor's weight (0: left out of the graph, as a
    rejected closure); ``groups``: lists of between-factor indices, all of
    weight 1 (the leave-group-out test) or all of weight 0 (the innovation
    test).  NaN for a group without which the graph would be singular
    (leverage 1: nothing else measures what it measures; :data:`~lie_factors.robust.leverage.SINGULAR`).

    A_G·H⁻¹·A_Gᵀ of a group out of the graph comes from the paths of :func:`group_gram`;
    of the groups in the graph, from the same paths or from the selected inverse of H
    (its poses' blocks added to the pattern), whichever costs fewer multiply-adds
    (:func:`_selected_inverse_is_cheaper`; the module docstring).
    """
    problem = Problem.from_pose_graph(graph, X)
    problem.linearize()
    between = next(g for g in problem.groups if g.kind == "between")
    out = np.full(len(groups), np.nan)
    if not groups:
        return out
    where = np.full(problem.graph_size, -1, dtype=np.int64)
    where[between.fidx] = np.arange(between.fidx.size)
    rows = [where[np.asarray(G, dtype=np.int64)] for G in groups]
    if any(np.any(r < 0) for r in rows):
        raise ValueError("leave_out_chi2: a group holds a factor that is not a between factor")
    w = [weights[between.fidx[r]] for r in rows]
    signs = np.array([-1.0 if np.all(x == 1.0) else 1.0 if np.all(x == 0.0) else np.nan for x in w])
    if np.isnan(signs).any():
        raise ValueError("leave_out_chi2: a group must be all in the graph (weight 1) or all out (0)")
    inside, outside = np.flatnonzero(signs < 0), np.flatnonzero(signs > 0)
    sizes = np.array([len(G) for G in groups], dtype=np.int64)
    colptr, rowind, values, pos = _system_with_blocks(problem, between, weights, [])
    factor = Cholesky(colptr, rowind)
    factor.factorize(values)
    lower = factor.lower()
    at = _factor_rows(lower[0], pos)
    ends = [np.unique(np.concatenate([between.v1[rows[g]], between.v2[rows[g]]])) for g in inside.tolist()]
    by_inverse = inside.size > 0 and _selected_inverse_is_cheaper(
        lower[1], lower[2], at, problem.var_offsets, between.A1.shape[1], sizes[inside], ends)
    on_paths = outside if by_inverse else np.arange(len(groups))
    Hs: list = [None] * len(groups)
    for g, H in zip(on_paths.tolist(), _path_gram(lower, at, between.o1, between.o2, between.A1, between.A2,
                                                  [rows[g] for g in on_paths])):
        Hs[g] = H
    if by_inverse:
        colptr, rowind, values, pos = _system_with_blocks(problem, between, weights, ends)
        factor = Cholesky(colptr, rowind, natural=True, supernodal=True)
        factor.factorize(values)
        inverse = invert_in_place(factor.supernodes() if factor.supernodal and direct_available()
                                  else Supernodes.from_lower(*factor.lower()))
        for g, H in zip(inside.tolist(), _gram_from_inverse(inverse, pos, problem.var_offsets, between,
                                                            [rows[g] for g in inside], ends)):
            Hs[g] = H
    for size in np.unique(sizes).tolist():
        idx = np.flatnonzero(sizes == size)
        b = np.stack([between.b[rows[g]].reshape(-1) for g in idx])
        out[idx] = statistics(np.ascontiguousarray(np.stack([Hs[g] for g in idx])), b, np.ascontiguousarray(signs[idx]))
    return out


def _system_with_blocks(problem: Problem, between, weights: np.ndarray, sets: list):
    """H of the weighted factors, ordered and stored with every block among the variables of each
    of ``sets`` (arrays of variable indices) in its pattern (as zeros where H has none):
    (colptr, rowind, values, pos), the lower triangle in compressed columns and ``pos``
    (n,) the matrix row of each variable scalar."""
    # What weighs 0 (a rejected closure between far-apart poses) stays out of the fill-reducing
    # order and of the factor's structure: its blocks of H are 0, and would only add fill to L.
    live = weights[between.fidx] != 0.0
    # each end's own block too: H can hold exact zeros there (a grid's quarter-turn headings with
    # isotropic translation information: no x–y term), which would leave it off the factor's pattern
    among = [np.stack(np.triu_indices(len(v))) for v in sets]
    qa = np.concatenate([v[i[0]] for v, i in zip(sets, among)]) if sets else np.zeros(0, dtype=np.int64)
    qb = np.concatenate([v[i[1]] for v, i in zip(sets, among)]) if sets else np.zeros(0, dtype=np.int64)
    pairs = np.concatenate([np.stack([between.v1[live], between.v2[live]], axis=1), problem.native_pairs,
                            np.stack([qa, qb], axis=1).astype(np.int64)])
    system = LinearSystem(problem, block_order(len(problem.var_dims), pairs[:, 0], pairs[:, 1]))
    system.weights[:] = weights
    system.assemble()
    p = system.pattern
    pos = np.empty(p.n, dtype=np.int64)
    pos[p.scalar_order] = np.arange(p.n)
    keep = system.data != 0.0
    keep[p.colptr[:-1]] = True  # the diagonal (first in each column)
    if not sets:
        colptr = np.concatenate([[0], np.cumsum(np.add.reduceat(keep, p.colptr[:-1]))]).astype(np.int64) \
            if p.n else np.zeros(1, dtype=np.int64)
        return colptr, p.rowind[keep], np.ascontiguousarray(system.data[keep]), pos
    col = np.repeat(np.arange(p.n, dtype=np.int64), np.diff(p.colptr))
    n = between.A1.shape[1]
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")  # every scalar pair of a block
    ra = pos[problem.var_offsets[qa][:, None, None] + i].reshape(-1)
    rb = pos[problem.var_offsets[qb][:, None, None] + j].reshape(-1)
    colptr, rowind, values = lower_csc(p.n, np.concatenate([p.rowind[keep], np.maximum(ra, rb)]),
                                       np.concatenate([col[keep], np.minimum(ra, rb)]),
                                       np.concatenate([system.data[keep], np.zeros(ra.size)]))
    return colptr, rowind, np.ascontiguousarray(values), pos


def _gram_from_inverse(inverse: Supernodes, pos: np.ndarray, offsets: np.ndarray, between, groups: list,
                       ends: list) -> list:
    """A_G·H⁻¹·A_Gᵀ (d × d, d = n·len(G)) of each group of between factors (indices into the
    ``between`` block's factors) from ``inverse`` (:func:`~lie_factors.sparse.selinv.invert_in_place`),
    whose pattern holds every block among the group's variables ``ends`` (ascending)."""
    n = between.A1.shape[1]
    out: list = [None] * len(groups)
    shape = np.array([[len(G), len(v)] for G, v in zip(groups, ends)], dtype=np.int64).reshape(-1, 2)
    for s, k in np.unique(shape, axis=0).tolist():
        idx = np.flatnonzero((shape[:, 0] == s) & (shape[:, 1] == k))
        V = np.stack([ends[g] for g in idx])
        R = np.stack([groups[g] for g in idx])
        Z = diagonal_blocks(inverse, pos[offsets[V][:, :, None] + np.arange(n)].reshape(idx.size, k * n))
        A = np.zeros((idx.size, s, n, k, n))
        m = np.arange(idx.size)
        for t in range(s):
            f = R[:, t]
            A[m, t, :, np.argmax(V == between.v1[f][:, None], axis=1), :] += between.A1[f]
            A[m, t, :, np.argmax(V == between.v2[f][:, None], axis=1), :] += between.A2[f]
        A = A.reshape(idx.size, s * n, k * n)
        for g, H in zip(idx.tolist(), A @ Z @ A.transpose(0, 2, 1)):
            out[g] = H
    return out
