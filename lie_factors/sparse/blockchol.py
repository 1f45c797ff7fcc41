"""A block-sparse Cholesky factorization whose pattern is fixed once: what a small problem's whole
solve (:mod:`lie_factors.batch.small`) factors at every try of λ without leaving compiled code.

Variables are blocks: the one at elimination position p has ``dims[p]`` scalars, at scalar
offset ``soff[p]`` of the permuted system.  Λ = LLᵀ is held lower block by block, in one float
array ``values`` (:class:`Pattern` says where): the diagonal block of p, d_p × d_p row-major, at
``doff[p]`` (its lower triangle read), and the blocks below it, block rows ``rows[colptr[p]:
colptr[p+1]]`` (ascending), each d_r × d_p row-major at ``boff[·]``.  The same layout holds Λ
itself: the solver assembles Λ there, copies it, damps the copy's diagonal and factors the copy
in place (:func:`factor`), so the pattern is computed once per problem (:func:`symbolic`: the
elimination tree and each row's reach in it, Liu's row-subtree characterization of L's pattern,
as Davis' CSparse ``cs_ereach`` computes it, so that every column's rows come out ascending).

:func:`factor` is left-looking by block columns: column p gathers −L_pk·L_pkᵀ and −L_rk·L_pkᵀ
from every earlier column k whose rows hold p (``rowptr``/``rowblk``: block row p of L), factors
its diagonal block densely and solves its blocks below against it.  A pivot is refused by the one
rule of :mod:`lie_factors.sparse.pivots` (the pivot not above ``tolerance`` times the matrix's
diagonal entry given; 0: its sign), and the factorization stops there, naming the scalar column.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ..kernels.jit import dense_kernel, inline_kernel, kernel

__all__ = ["Pattern", "symbolic", "pattern", "factor", "solve", "block_offset", "dense"]


class Pattern(NamedTuple):
    """Where each block of L lives (module docstring); arrays of int64.  ``rowptr``/``rowblk``:
    block row p's blocks left of its diagonal, as indices into ``rows``/``boff``; ``bcol``: each
    block's column; ``size``: the length of ``values``."""

    dims: np.ndarray
    soff: np.ndarray
    colptr: np.ndarray
    rows: np.ndarray
    boff: np.ndarray
    doff: np.ndarray
    rowptr: np.ndarray
    rowblk: np.ndarray
    bcol: np.ndarray
    size: int


@kernel
def _adjacency(P, pairs):
    """For each position, its neighbours at lower positions (CSR: ``ptr`` (P+1,), ``nbr``)."""
    count = np.zeros(P + 1, dtype=np.int64)
    for t in range(pairs.shape[0]):
        a, b = pairs[t, 0], pairs[t, 1]
        if a != b:
            count[max(a, b) + 1] += 1
    for p in range(P):
        count[p + 1] += count[p]
    nbr = np.empty(count[P], dtype=np.int64)
    fill = count[:P].copy()
    for t in range(pairs.shape[0]):
        a, b = pairs[t, 0], pairs[t, 1]
        if a != b:
            hi, lo = max(a, b), min(a, b)
            nbr[fill[hi]] = lo
            fill[hi] += 1
    return count, nbr


@kernel
def symbolic(dims, pairs):
    """The :class:`Pattern` arrays of Λ's factor, positions ``0 … P−1`` with ``dims`` (P,) and
    the block pairs ``pairs`` (M, 2) of positions that some factor joins (either order,
    repeats allowed).  Returns (soff, colptr, rows, boff, doff, rowptr, rowblk, bcol, size)."""
    P = dims.shape[0]
    ptr, nbr = _adjacency(P, pairs)
    # the elimination tree (CSparse's cs_etree, by rows of the lower triangle)
    parent = np.full(P, -1, dtype=np.int64)
    ancestor = np.full(P, -1, dtype=np.int64)
    for i in range(P):
        for t in range(ptr[i], ptr[i + 1]):
            k = nbr[t]
            while k != -1 and k < i:
                nxt = ancestor[k]
                ancestor[k] = i
                if nxt == -1:
                    parent[k] = i
                k = nxt
    # each row's reach: the columns k < i with L_ik ≠ 0, walked up the tree from its neighbours
    mark = np.full(P, -1, dtype=np.int64)
    rowcount = np.zeros(P + 1, dtype=np.int64)
    colcount = np.zeros(P + 1, dtype=np.int64)
    for i in range(P):
        mark[i] = i
        for t in range(ptr[i], ptr[i + 1]):
            k = nbr[t]
            while mark[k] != i:
                mark[k] = i
                rowcount[i + 1] += 1
                colcount[k + 1] += 1
                k = parent[k]
    for p in range(P):
        rowcount[p + 1] += rowcount[p]
        colcount[p + 1] += colcount[p]
    nnz = colcount[P]
    rows = np.empty(nnz, dtype=np.int64)
    rowblk = np.empty(nnz, dtype=np.int64)
    cfill = colcount[:P].copy()
    rfill = rowcount[:P].copy()
    for i in range(P):
        mark[i] = -1
    for i in range(P):  # rows in ascending order: every column's rows come out ascending
        mark[i] = i
        for t in range(ptr[i], ptr[i + 1]):
            k = nbr[t]
            while mark[k] != i:
                mark[k] = i
                rows[cfill[k]] = i
                rowblk[rfill[i]] = cfill[k]
                cfill[k] += 1
                rfill[i] += 1
                k = parent[k]
    soff = np.zeros(P + 1, dtype=np.int64)
    for p in range(P):
        soff[p + 1] = soff[p] + dims[p]
    doff = np.empty(P, dtype=np.int64)
    boff = np.empty(nnz, dtype=np.int64)
    bcol = np.empty(nnz, dtype=np.int64)
    at = 0
    for p in range(P):
        doff[p] = at
        at += dims[p] * dims[p]
        for s in range(colcount[p], colcount[p + 1]):
            boff[s] = at
            bcol[s] = p
            at += dims[rows[s]] * dims[p]
    return soff, colcount, rows, boff, doff, rowcount, rowblk, bcol, at


def pattern(dims: np.ndarray, pairs: np.ndarray) -> Pattern:
    """:func:`symbolic` as a :class:`Pattern` (``dims`` in elimination order, ``pairs`` of
    positions)."""
    dims = np.ascontiguousarray(dims, dtype=np.int64)
    pairs = np.ascontiguousarray(np.asarray(pairs, dtype=np.int64).reshape(-1, 2))
    soff, colptr, rows, boff, doff, rowptr, rowblk, bcol, size = symbolic(dims, pairs)
    return Pattern(dims, soff, colptr, rows, boff, doff, rowptr, rowblk, bcol, int(size))


@kernel
def block_offset(colptr, rows, boff, doff, r, p):
    """The offset in ``values`` of block (r, p), r ≥ p (the diagonal block where r = p), or −1
    where L has none."""
    if r == p:
        return doff[p]
    lo, hi = colptr[p], colptr[p + 1]
    while lo < hi:
        mid = (lo + hi) // 2
        if rows[mid] < r:
            lo = mid + 1
        else:
            hi = mid
    if lo < colptr[p + 1] and rows[lo] == r:
        return boff[lo]
    return -1


@inline_kernel
def _view(values, at, rows, cols):
    """The rows × cols row-major block of ``values`` at ``at``, as a 2-D array: its rows are
    contiguous views, whose dot products LLVM vectorizes (flat indexing it does not)."""
    return values[at:at + rows * cols].reshape((rows, cols))


@inline_kernel
def _subtract_products(out, li, Lpk, LpkT, dots, n):
    """out[j] −= li · L_pk[j] for j < n: dot products over L_pk's rows (``dots``), or rank-one
    updates along out from L_pkᵀ's rows (``LpkT``), whichever runs the longer inner loop."""
    if dots:
        for j in range(n):
            lj = Lpk[j]
            acc = 0.0
            for c in range(li.shape[0]):
                acc += li[c] * lj[c]
            out[j] -= acc
    else:
        for c in range(li.shape[0]):
            a = li[c]
            col = LpkT[c]
            for j in range(n):
                out[j] -= a * col[j]


@dense_kernel
def factor(dims, soff, colptr, rows, boff, doff, rowptr, rowblk, bcol, values, reference, tolerance):
    """Λ = LLᵀ in place in ``values`` (Λ's lower blocks in, L's out; module docstring).
    ``reference`` (n,): the diagonal each pivot is compared with, in elimination order.
    Returns −1, or the scalar column (in elimination order) whose pivot was refused."""
    P = dims.shape[0]
    where = np.empty(P, dtype=np.int64)  # block row r → its block's offset in the current column
    widest = 0
    for p in range(P):
        widest = max(widest, dims[p])
    scratch = np.empty(widest * widest)
    for p in range(P):
        dp = dims[p]
        D = _view(values, doff[p], dp, dp)
        for u in range(colptr[p], colptr[p + 1]):
            where[rows[u]] = boff[u]
        # updates from the earlier columns k with L_pk ≠ 0: dot products over k's columns where
        # they are at least as many as p's, else rank-one updates along p's rows (LpkT: L_pkᵀ)
        for t in range(rowptr[p], rowptr[p + 1]):
            s = rowblk[t]  # block (p, k) sits at rows[s] == p in column k
            k = bcol[s]
            dk = dims[k]
            Lpk = _view(values, boff[s], dp, dk)
            dots = dk >= dp
            LpkT = scratch[:dk * dp].reshape((dk, dp))
            if not dots:
                for i in range(dp):
                    for c in range(dk):
                        LpkT[c, i] = Lpk[i, c]
            for i in range(dp):
                _subtract_products(D[i], Lpk[i], Lpk, LpkT, dots, i + 1)
            for u in range(s + 1, colptr[k + 1]):
                r = rows[u]
                Lrk = _view(values, boff[u], dims[r], dk)
                Lrp = _view(values, where[r], dims[r], dp)
                for i in range(dims[r]):
                    _subtract_products(Lrp[i], Lrk[i], Lpk, LpkT, dots, dp)
        # the diagonal block, densely, column by column
        base = soff[p]
        for j in range(dp):
            dj = D[j]
            v = dj[j]
            for c in range(j):
                v -= dj[c] * dj[c]
            if not (v > tolerance * reference[base + j]) or not (v < math.inf):
                return base + j
            ljj = math.sqrt(v)
            dj[j] = ljj
            for i in range(j + 1, dp):
                di = D[i]
                w = di[j]
                for c in range(j):
                    w -= di[c] * dj[c]
                di[j] = w / ljj
        # the blocks below: L_rp ← L_rp·L_ppᵀ⁻¹ (each row a forward substitution)
        for u in range(colptr[p], colptr[p + 1]):
            B = _view(values, boff[u], dims[rows[u]], dp)
            for i in range(B.shape[0]):
                bi = B[i]
                for j in range(dp):
                    dj = D[j]
                    w = bi[j]
                    for c in range(j):
                        w -= bi[c] * dj[c]
                    bi[j] = w / dj[j]
    return -1


@dense_kernel
def solve(dims, soff, colptr, rows, boff, doff, values, x):
    """x ← (LLᵀ)⁻¹x in place, ``x`` (n,) in elimination order."""
    P = dims.shape[0]
    for p in range(P):  # L y = x
        dp, o = dims[p], soff[p]
        D = _view(values, doff[p], dp, dp)
        for j in range(dp):
            dj = D[j]
            w = x[o + j]
            for c in range(j):
                w -= dj[c] * x[o + c]
            x[o + j] = w / dj[j]
        for u in range(colptr[p], colptr[p + 1]):
            r = rows[u]
            B = _view(values, boff[u], dims[r], dp)
            orow = soff[r]
            for i in range(B.shape[0]):
                bi = B[i]
                acc = 0.0
                for j in range(dp):
                    acc += bi[j] * x[o + j]
                x[orow + i] -= acc
    for p in range(P - 1, -1, -1):  # Lᵀ x = y
        dp, o = dims[p], soff[p]
        D = _view(values, doff[p], dp, dp)
        for u in range(colptr[p], colptr[p + 1]):
            r = rows[u]
            B = _view(values, boff[u], dims[r], dp)
            orow = soff[r]
            for i in range(B.shape[0]):
                bi = B[i]
                xi = x[orow + i]
                for j in range(dp):
                    x[o + j] -= bi[j] * xi
        for j in range(dp - 1, -1, -1):
            w = x[o + j]
            for c in range(j + 1, dp):
                w -= D[c, j] * x[o + c]
            x[o + j] = w / D[j, j]


def dense(pat: Pattern, values: np.ndarray) -> np.ndarray:
    """The (n, n) lower-triangular matrix held in ``values`` (for tests and inspection)."""
    n = int(pat.soff[-1])
    out = np.zeros((n, n))
    for p in range(len(pat.dims)):
        d, o = int(pat.dims[p]), int(pat.soff[p])
        out[o:o + d, o:o + d] = np.tril(values[pat.doff[p]:pat.doff[p] + d * d].reshape(d, d))
        for u in range(pat.colptr[p], pat.colptr[p + 1]):
            r = int(pat.rows[u])
            dr, orow = int(pat.dims[r]), int(pat.soff[r])
            out[orow:orow + dr, o:o + d] = values[pat.boff[u]:pat.boff[u] + dr * d].reshape(dr, d)
    return out
