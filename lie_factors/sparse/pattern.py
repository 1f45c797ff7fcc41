"""A block-sparse symmetric matrix: its pattern, stored as CHOLMOD reads it, and its assembly.

Storage (computed once per pattern): the variables, each a block of its
tangent dimension, numbered in a fill-reducing order
(:func:`lie_factors.sparse.cholmod.block_order`) so that CHOLMOD factors the
matrix where it lies; the lower triangle in compressed sparse columns (CSC),
int32 row indices: in each block column the diagonal block's lower triangle,
then the blocks below it.  In block column b (dimension d, T rows in all)
column j holds T − j entries, so the entry (i, j) of a block stored there is at
``base + j·stride − j(j+1)/2 + i`` with ``stride = T`` (i ≥ j in the diagonal
block).  Each factor keeps ``base``/``stride`` of its blocks (the *scatter
map*), and assembly is a loop of multiply-adds into ``data``: no search, no
allocation.  Vectors stay in the variables' own order (:attr:`Pattern.offsets`);
:attr:`Pattern.scalar_order` maps the matrix's rows to them.

The batch solver's normal equations (:mod:`lie_factors.batch.system`) and the
chordal initializer's (:mod:`lie_factors.initialization.sparse`) are stored so.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..errors import InputError
from ..kernels.jit import helper_kernel, kernel
from ..util.arrays import sorted_unique
from .cholmod import order_blocks


class Pattern:
    """Sparsity pattern of ``H`` for variables of dimensions ``dims`` and the block pairs used.

    ``pairs`` (K, 2) variable indices (any order, duplicates allowed; the diagonal
    blocks are always included); ``order`` (V,): the position of each block in the
    matrix, position → variable (default: :func:`~lie_factors.sparse.cholmod.block_order`
    of the pairs).  Attributes: ``n`` (scalar size), ``offsets`` (V,) each variable's
    offset in δ and g; ``order`` and ``position`` (V,) its inverse; ``colptr`` (n+1,)
    and ``rowind`` (nnz,) int32, the lower triangle in the matrix's order;
    ``scalar_order`` (n,): the δ index of each matrix row; ``diagpos`` (n,): where
    the diagonal entry of each δ index is in ``data``.  :meth:`lookup` gives the
    (base, stride) of block pairs.
    """

    def __init__(self, dims: np.ndarray, pairs: np.ndarray, order: np.ndarray | None = None):
        dims = np.asarray(dims, dtype=np.int64)
        V = len(dims)
        self.dims = dims
        self.offsets = np.zeros(V, dtype=np.int64)
        np.cumsum(dims[:-1], out=self.offsets[1:]) if V > 1 else None
        self.n = int(dims.sum())
        pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
        # The block pattern's lower triangle, by (column, row) variable; then by position.
        lo, hi = np.minimum(pairs[:, 0], pairs[:, 1]), np.maximum(pairs[:, 0], pairs[:, 1])
        codes = sorted_unique(np.concatenate([lo * V + hi, np.arange(V, dtype=np.int64) * (V + 1)]))
        bcol, brow = np.divmod(codes, V)
        if order is None:
            colptr = np.zeros(V + 1, dtype=np.int64)
            np.cumsum(np.bincount(bcol, minlength=V), out=colptr[1:])
            order = order_blocks(colptr, brow)
        self.order = order = np.asarray(order, dtype=np.int64)
        self.position = np.empty(V, dtype=np.int64)
        self.position[order] = np.arange(V)
        pa, pb = self.position[bcol], self.position[brow]
        # Blocks by (column, row) position, row ≥ column: each column's diagonal block comes first.
        codes = np.sort(np.minimum(pa, pb) * V + np.maximum(pa, pb))
        self._codes = codes
        bcol, brow = np.divmod(codes, V)
        first = np.searchsorted(bcol, np.arange(V + 1))
        pdims = dims[order]
        rdim = pdims[brow]
        csum = np.cumsum(rdim) - rdim
        rowoff = csum - csum[first[bcol]]
        T = np.add.reduceat(rdim, first[:-1]) if V else np.zeros(0, np.int64)
        colstart = np.zeros(V + 1, dtype=np.int64)
        np.cumsum(pdims * T - pdims * (pdims - 1) // 2, out=colstart[1:])
        self.nnz = int(colstart[-1])
        if self.nnz > np.iinfo(np.int32).max:
            raise InputError(f"the linear system has {self.nnz} stored entries, more than CHOLMOD's "
                             "int32 interface holds")
        self._base = colstart[bcol] + rowoff
        self._stride = T[bcol]
        poffsets = np.zeros(V, dtype=np.int64)
        np.cumsum(pdims[:-1], out=poffsets[1:]) if V > 1 else None
        self.colptr, self.rowind = _csc(pdims, poffsets, first, brow, T, colstart)
        within = np.arange(self.n, dtype=np.int64) - np.repeat(poffsets, pdims)
        self.scalar_order = np.repeat(self.offsets[order], pdims) + within
        self.diagpos = np.empty(self.n, dtype=np.int64)
        self.diagpos[self.scalar_order] = self.colptr[:-1]

    def colind(self) -> np.ndarray:
        """The column of every stored entry (nnz,): with ``rowind``, the pattern as triplets."""
        return np.repeat(np.arange(self.n, dtype=np.int64), np.diff(self.colptr))

    def scatter(self, v1: np.ndarray, v2: np.ndarray | None = None) -> "Scatter":
        """Where the blocks of factors on the variables ``v1`` (and ``v2``) go: a :class:`Scatter`
        (of one-variable factors when ``v2`` is None: its second variable's arrays empty)."""
        v1 = np.asarray(v1, dtype=np.int64)
        base11, stride11, _ = self.lookup(v1, v1)
        if v2 is None:
            none = np.zeros(0, dtype=np.int64)
            return Scatter(self.offsets[v1], none, base11, stride11, none, none, none, none, none)
        v2 = np.asarray(v2, dtype=np.int64)
        base22, stride22, _ = self.lookup(v2, v2)
        base12, stride12, one_is_row = self.lookup(v1, v2)
        return Scatter(self.offsets[v1], self.offsets[v2], base11, stride11, base22, stride22,
                       base12, stride12, one_is_row)

    def lookup(self, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(base, stride, a_is_row) of the blocks {a, b} (arrays of variable indices)."""
        pa = self.position[np.asarray(a, dtype=np.int64)]
        pb = self.position[np.asarray(b, dtype=np.int64)]
        V = len(self.dims)
        code = np.minimum(pa, pb) * V + np.maximum(pa, pb)
        idx = np.searchsorted(self._codes, code)
        assert np.all(self._codes[np.minimum(idx, len(self._codes) - 1)] == code)
        return self._base[idx], self._stride[idx], (pa >= pb).astype(np.int64)


class Scatter(NamedTuple):
    """Where each factor's blocks go (:meth:`Pattern.scatter`): ``o1``, ``o2`` its variables'
    offsets in the right-hand side; (base, stride) of its blocks (1, 1), (2, 2) and (1, 2) in
    ``data``; ``one_is_row``: the (1, 2) block is stored as A1ᵀA2 (variable 1 the row), else as
    A2ᵀA1.  Of one-variable factors, every array of the second variable is empty."""

    o1: np.ndarray
    o2: np.ndarray
    base11: np.ndarray
    stride11: np.ndarray
    base22: np.ndarray
    stride22: np.ndarray
    base12: np.ndarray
    stride12: np.ndarray
    one_is_row: np.ndarray

    def part(self, rows: slice) -> "Scatter":
        """The scatter of the factors ``rows``."""
        return Scatter(*(a[rows] for a in self))


class NativeBlocks(NamedTuple):
    """Augmented information matrices [AᵀA Aᵀb; bᵀA bᵀb] of factors GTSAM linearized, and
    where their blocks go (:func:`add_information`).

    Factor f: matrix ``info[info_start[f]:...]`` of side ``size[f] + 1``; its keys
    ``key_start[f]:key_start[f+1]`` with local column ``key_local``, dimension ``key_dim``
    and offset ``key_offset`` in the right-hand side; block (p, q) of its keys at
    ``pair_base``/``pair_stride`` ``[pair_start[f] + p·k + q]`` (base −1: an upper block,
    skipped; p = q: the diagonal block, its lower triangle).
    """

    info: np.ndarray
    info_start: np.ndarray
    size: np.ndarray
    key_start: np.ndarray
    key_local: np.ndarray
    key_dim: np.ndarray
    key_offset: np.ndarray
    pair_start: np.ndarray
    pair_base: np.ndarray
    pair_stride: np.ndarray


@kernel
def _csc(pdims, poffsets, first, brow, T, colstart):
    """colptr (n+1,) and rowind (nnz,) int32 of the lower triangle, blocks in position order."""
    V = pdims.shape[0]
    n = 0
    for v in range(V):
        n += pdims[v]
    colptr = np.empty(n + 1, dtype=np.int32)
    rowind = np.empty(colstart[V], dtype=np.int32)
    for b in range(V):
        d = pdims[b]
        for j in range(d):
            c = poffsets[b] + j
            p = colstart[b] + j * T[b] - j * (j - 1) // 2
            colptr[c] = p
            for i in range(j, d):  # the diagonal block's lower triangle: the diagonal first
                rowind[p] = poffsets[b] + i
                p += 1
            for q in range(first[b] + 1, first[b + 1]):
                a = brow[q]
                for i in range(pdims[a]):
                    rowind[p] = poffsets[a] + i
                    p += 1
    colptr[n] = colstart[V]
    return colptr, rowind


# --------------------------------------------------------------------------- #
# Assembly kernels (values only; the pattern and scatter map are fixed)
# --------------------------------------------------------------------------- #

@helper_kernel
def _add_gram(A, B, w, base, stride, lower, data):
    """data[base + j·stride − j(j+1)/2 + i] += w·Σ_r A[r, i]·B[r, j] (one block of AᵀB; with
    ``lower``, a diagonal block, only its lower triangle i ≥ j)."""
    for j in range(B.shape[1]):
        p = base + j * stride - j * (j + 1) // 2
        for i in range(j if lower else 0, A.shape[1]):
            acc = 0.0
            for r in range(A.shape[0]):
                acc += A[r, i] * B[r, j]
            data[p + i] += w * acc


@helper_kernel
def _add_rhs(A, b, w, o, rhs):
    for i in range(A.shape[1]):
        acc = 0.0
        for r in range(A.shape[0]):
            acc += A[r, i] * b[r]
        rhs[o + i] += w * acc


@kernel
def add_factors(A1, A2, b, w, at, data, rhs):
    """Accumulate w_f·[A1 A2]ᵀ[A1 A2] and w_f·[A1 A2]ᵀb_f of every factor (``at``: their
    :class:`Scatter`); of one-variable factors (``A2`` with no rows) w_f·A1ᵀA1 and w_f·A1ᵀb_f."""
    unary = A2.shape[0] == 0
    for f in range(A1.shape[0]):
        wf = w[f]
        if wf == 0.0:
            continue
        _add_gram(A1[f], A1[f], wf, at.base11[f], at.stride11[f], True, data)
        if unary:
            _add_rhs(A1[f], b[f], wf, at.o1[f], rhs)
            continue
        _add_gram(A2[f], A2[f], wf, at.base22[f], at.stride22[f], True, data)
        if at.one_is_row[f]:
            _add_gram(A1[f], A2[f], wf, at.base12[f], at.stride12[f], False, data)
        else:
            _add_gram(A2[f], A1[f], wf, at.base12[f], at.stride12[f], False, data)
        _add_rhs(A1[f], b[f], wf, at.o1[f], rhs)
        _add_rhs(A2[f], b[f], wf, at.o2[f], rhs)


@kernel
def add_blocks(A, b, w, col, dim, o, base, stride, row, data, rhs):
    """Accumulate w_f·A_fᵀA_f and w_f·A_fᵀb_f of factors on k variables each: A (F, m, Σd),
    variable p's columns ``col[p]:col[p] + dim[p]``; ``o`` (F, k) its offset in the right-hand
    side; block (p, q), p ≤ q, at ``base[f, p, q]``/``stride[f, p, q]`` of ``data``, stored as
    A_pᵀA_q where ``row[f, p, q]`` (variable p the row), else as A_qᵀA_p."""
    k = col.shape[0]
    for f in range(A.shape[0]):
        wf = w[f]
        if wf == 0.0:
            continue
        for p in range(k):
            Ap = A[f, :, col[p]:col[p] + dim[p]]
            _add_gram(Ap, Ap, wf, base[f, p, p], stride[f, p, p], True, data)
            _add_rhs(Ap, b[f], wf, o[f, p], rhs)
            for q in range(p + 1, k):
                Aq = A[f, :, col[q]:col[q] + dim[q]]
                if row[f, p, q]:
                    _add_gram(Ap, Aq, wf, base[f, p, q], stride[f, p, q], False, data)
                else:
                    _add_gram(Aq, Ap, wf, base[f, p, q], stride[f, p, q], False, data)


@kernel
def add_information(nat, w, data, rhs):
    """Accumulate GTSAM's augmented information [AᵀA Aᵀb; bᵀA bᵀb] of natively linearized factors
    (``nat``: a :class:`NativeBlocks`), factor f weighted by ``w[f]``."""
    info, info_start, size, key_start = nat.info, nat.info_start, nat.size, nat.key_start
    key_local, key_dim, key_offset = nat.key_local, nat.key_dim, nat.key_offset
    pair_start, pair_base, pair_stride = nat.pair_start, nat.pair_base, nat.pair_stride
    for f in range(size.shape[0]):
        wf = w[f]
        if wf == 0.0:
            continue
        D1 = size[f] + 1
        s = info_start[f]
        k0 = key_start[f]
        k = key_start[f + 1] - k0
        for p in range(k):
            lp = key_local[k0 + p]
            dp = key_dim[k0 + p]
            for i in range(dp):
                rhs[key_offset[k0 + p] + i] += wf * info[s + (lp + i) * D1 + size[f]]
            for q in range(k):
                pos = pair_start[f] + p * k + q
                base = pair_base[pos]
                if base < 0:
                    continue
                st = pair_stride[pos]
                lq = key_local[k0 + q]
                for j in range(key_dim[k0 + q]):
                    at = base + j * st - j * (j + 1) // 2
                    for i in range(j if p == q else 0, dp):
                        data[at + i] += wf * info[s + (lp + i) * D1 + lq + j]


@kernel
def quadratic_form(colptr, rowind, data, x):
    """xᵀHx from H's lower triangle (x in the matrix's order)."""
    quad = 0.0
    for c in range(x.shape[0]):
        xc = x[c]
        for p in range(colptr[c], colptr[c + 1]):
            r = rowind[p]
            if r == c:
                quad += data[p] * xc * xc
            else:
                quad += 2.0 * data[p] * x[r] * xc
    return quad


@kernel
def quadratic_change(colptr, rowind, data, rhs, delta):
    """δᵀg − ½·δᵀHδ: the decrease of ½‖Aδ − b‖² from δ = 0 (H's lower triangle; δ and g in
    the matrix's order)."""
    lin = 0.0
    for c in range(rhs.shape[0]):
        lin += delta[c] * rhs[c]
    return lin - 0.5 * quadratic_form(colptr, rowind, data, delta)


def set_diagonal(data, diagpos, diagonal, scale) -> None:
    """data's diagonal = ``diagonal`` + ``scale`` (both in δ's order)."""
    data[diagpos] = diagonal + scale
