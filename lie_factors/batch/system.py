"""The damped normal equations as one block-sparse symmetric matrix, assembled by numba.

For whitened factor rows ``A δ ≈ b`` (``b = −R·e``) the Gauss–Newton system is
``H δ = g`` with ``H = Σ_f w_f A_fᵀA_f`` and ``g = Σ_f w_f A_fᵀb_f``; LM adds
``λ·I`` (or ``λ·clamp(diag H, 1e-6, 1e32)`` with ``diagonalDamping``, GTSAM's
``LevenbergMarquardtParams`` min/max diagonal) to the diagonal.  ``w_f`` is a
per-factor weight (1 unless a robust/GNC scheme sets :attr:`LinearSystem.weights`):
it multiplies the factor's whole whitened contribution, i.e. scales its rows
by √w_f — GTSAM's robust reweighting.

Storage (computed once per graph): the variables that appear in a factor, each a
block of its tangent dimension, numbered in a fill-reducing order
(:func:`lie_factors.batch.cholmod.block_order`) so that CHOLMOD factors the matrix
where it lies; ``H``'s lower triangle in compressed sparse columns (CSC), int32
row indices: in each block column the diagonal block's lower triangle, then the
blocks below it.  In block column b (dimension d, T rows in all) column j holds
T − j entries, so the entry (i, j) of a block stored there is at
``base + j·stride − j(j+1)/2 + i`` with ``stride = T`` (i ≥ j in the diagonal
block).  Each factor keeps ``base``/``stride`` of its blocks (the *scatter map*),
and assembly is a loop of multiply-adds into ``data`` — no search, no allocation.
``g`` and δ stay in the variables' own order (:attr:`Pattern.offsets`);
:attr:`Pattern.scalar_order` maps the matrix's rows to them.
"""

from __future__ import annotations

import time

import numpy as np

from ..kernels.jit import kernel
from .cholmod import block_order

#: Factors per batch of :meth:`LinearSystem.linearize_assemble`: its buffer (8192 SE(3) factors:
#: 5 MB) stays in cache between the linearization and the assembly that reads it.
BATCH = 8192


class Pattern:
    """Sparsity pattern of ``H`` for variables of dimensions ``dims`` and the block pairs used.

    ``pairs`` (K, 2) variable indices (any order, duplicates allowed; the diagonal
    blocks are always included); ``order`` (V,): the position of each block in the
    matrix, position → variable (default: :func:`~lie_factors.batch.cholmod.block_order`
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
        if order is None:
            order = block_order(V, pairs[:, 0], pairs[:, 1])
        self.order = order = np.asarray(order, dtype=np.int64)
        self.position = np.empty(V, dtype=np.int64)
        self.position[order] = np.arange(V)
        pa, pb = self.position[pairs[:, 0]], self.position[pairs[:, 1]]
        diag = np.arange(V, dtype=np.int64)
        # Blocks by (column, row) position, row ≥ column: each column's diagonal block comes first.
        codes = np.unique(np.concatenate([np.minimum(pa, pb) * V + np.maximum(pa, pb), diag * (V + 1)]))
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
            raise ValueError(f"the linear system has {self.nnz} stored entries, more than CHOLMOD's "
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

    def lookup(self, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(base, stride, a_is_row) of the blocks {a, b} (arrays of variable indices)."""
        pa = self.position[np.asarray(a, dtype=np.int64)]
        pb = self.position[np.asarray(b, dtype=np.int64)]
        V = len(self.dims)
        code = np.minimum(pa, pb) * V + np.maximum(pa, pb)
        idx = np.searchsorted(self._codes, code)
        assert np.all(self._codes[np.minimum(idx, len(self._codes) - 1)] == code)
        return self._base[idx], self._stride[idx], (pa >= pb).astype(np.int64)


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

@kernel
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


@kernel
def _add_rhs(A, b, w, o, rhs):
    for i in range(A.shape[1]):
        acc = 0.0
        for r in range(A.shape[0]):
            acc += A[r, i] * b[r]
        rhs[o + i] += w * acc


@kernel
def add_binary(A1, A2, b, w, o1, o2, base11, stride11, base22, stride22, base12, stride12,
               one_is_row, data, rhs):
    """Accumulate w_f·[A1 A2]ᵀ[A1 A2] and w_f·[A1 A2]ᵀb_f of every two-variable factor."""
    for f in range(A1.shape[0]):
        wf = w[f]
        if wf == 0.0:
            continue
        _add_gram(A1[f], A1[f], wf, base11[f], stride11[f], True, data)
        _add_gram(A2[f], A2[f], wf, base22[f], stride22[f], True, data)
        if one_is_row[f]:
            _add_gram(A1[f], A2[f], wf, base12[f], stride12[f], False, data)
        else:
            _add_gram(A2[f], A1[f], wf, base12[f], stride12[f], False, data)
        _add_rhs(A1[f], b[f], wf, o1[f], rhs)
        _add_rhs(A2[f], b[f], wf, o2[f], rhs)


@kernel
def add_unary(A1, b, w, o1, base11, stride11, data, rhs):
    """Accumulate w_f·A1ᵀA1 and w_f·A1ᵀb_f of every one-variable factor."""
    for f in range(A1.shape[0]):
        wf = w[f]
        if wf == 0.0:
            continue
        _add_gram(A1[f], A1[f], wf, base11[f], stride11[f], True, data)
        _add_rhs(A1[f], b[f], wf, o1[f], rhs)


@kernel
def add_information(info, info_start, size, key_start, key_local, key_dim, key_offset,
                    pair_start, pair_base, pair_stride, w, data, rhs):
    """Accumulate GTSAM's augmented information [AᵀA Aᵀb; bᵀA bᵀb] of natively linearized factors.

    Factor f: matrix ``info[info_start[f]:...]`` of side ``size[f] + 1``; its
    keys ``key_start[f]:key_start[f+1]`` with local column, dimension and
    global offset; block (p, q) of its keys at ``pair_base/pair_stride[pair_start[f] + p·k + q]``
    (base −1: upper block, skipped; p = q: the diagonal block, its lower triangle).
    """
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
def quadratic_change(colptr, rowind, data, rhs, delta):
    """δᵀg − ½·δᵀHδ: the decrease of ½‖Aδ − b‖² from δ = 0 (H's lower triangle; δ and g in
    the matrix's order)."""
    quad = 0.0
    lin = 0.0
    n = rhs.shape[0]
    for c in range(n):
        dc = delta[c]
        lin += dc * rhs[c]
        for p in range(colptr[c], colptr[c + 1]):
            r = rowind[p]
            if r == c:
                quad += data[p] * dc * dc
            else:
                quad += 2.0 * data[p] * delta[r] * dc
    return lin - 0.5 * quad


@kernel
def _set_diagonal(data, diagpos, diagonal, scale):
    """data's diagonal = ``diagonal`` + ``scale`` (both in δ's order)."""
    for c in range(diagpos.shape[0]):
        data[diagpos[c]] = diagonal[c] + scale[c]


class LinearSystem:
    """``H``, ``g`` of a :class:`~lie_factors.batch.graph.Problem`, in :class:`Pattern` storage.

    ``weights`` (one per graph factor, index = position in the
    NonlinearFactorGraph, 1.0 by default) multiply each factor's
    contribution at the next :meth:`assemble`: the hook for robust
    reweighting (IRLS) and GNC.  ``data`` holds H, damped in place by
    :meth:`damp` (the undamped diagonal is kept: :meth:`hessian_diagonal`), which
    is what the linear solvers factor.
    """

    def __init__(self, problem, order: np.ndarray | None = None):
        self.problem = problem
        P = problem
        pairs = [np.stack([g.v1, g.v2], axis=1) for g in P.groups if g.kind == "between"]
        pairs += [P.native_pairs]
        self.pattern = pat = Pattern(P.var_dims, np.concatenate(pairs) if pairs else np.zeros((0, 2)), order)
        self.n = pat.n
        self.data = np.zeros(pat.nnz)
        self.rhs = np.zeros(pat.n)
        self.weights = np.ones(P.graph_size)
        self._diagonal = None  # diag(H) of the last assembly, in δ's order
        self._damped = False
        for g in P.groups:
            g.base11, g.stride11, _ = pat.lookup(g.v1, g.v1)
            if g.kind == "between":
                g.base22, g.stride22, _ = pat.lookup(g.v2, g.v2)
                g.base12, g.stride12, g.one_is_row = pat.lookup(g.v1, g.v2)
        nat = P.native_arrays
        if nat is not None:
            kv = nat.key_var
            # Every ordered key pair (p, q) of each native factor, flattened factor by factor.
            pa, pb = [], []
            for f in range(len(nat.size)):
                ks = kv[nat.key_start[f]:nat.key_start[f + 1]]
                pa.append(np.repeat(ks, len(ks)))
                pb.append(np.tile(ks, len(ks)))
            pa = np.concatenate(pa)
            pb = np.concatenate(pb)
            base, stride, a_is_row = pat.lookup(pa, pb)
            nat.pair_base = np.where(a_is_row.astype(bool), base, -1)
            nat.pair_stride = stride
            nat.key_offset = pat.offsets[kv]

    def assemble(self) -> None:
        """H and g of the current linearization (``problem.linearize`` must have run)."""
        self.data[:] = 0.0
        self.rhs[:] = 0.0
        for g in self.problem.groups:
            self._add(g, 0, g.E, g.A1, g.A2, g.b)
        self._add_native()

    def linearize_assemble(self) -> tuple[float, float, float]:
        """Linearize the problem and assemble H and g, :data:`BATCH` factors at a time through one
        buffer: the graph's Jacobians never exist all at once (``A1``, ``A2``, ``b`` of the
        groups stay unset; ``sq`` is set).  The same numbers as ``problem.linearize()`` then
        :meth:`assemble`.  Returns (the error ½·Σ sq at δ = 0, seconds linearizing, seconds
        assembling)."""
        P = self.problem
        self.data[:] = 0.0
        self.rhs[:] = 0.0
        total = seconds_lin = seconds_asm = 0.0
        for g in P.groups:
            X = P.blocks[g.spec.name].X
            n = g.spec.dim
            size = min(g.E, BATCH)
            A1, b = np.empty((size, n, n)), np.empty((size, n))
            A2 = np.empty((size, n, n)) if g.kind == "between" else None
            for start in range(0, g.E, BATCH):
                stop = min(g.E, start + BATCH)
                k = stop - start
                t0 = time.perf_counter()
                g.linearize_range(X, start, stop, A1[:k], None if A2 is None else A2[:k], b[:k])
                t1 = time.perf_counter()
                self._add(g, start, stop, A1[:k], None if A2 is None else A2[:k], b[:k])
                seconds_lin += t1 - t0
                seconds_asm += time.perf_counter() - t1
            total += 0.5 * float(g.sq.sum())
        t0 = time.perf_counter()
        total += P.linearize_native()
        t1 = time.perf_counter()
        self._add_native()
        return total, seconds_lin + t1 - t0, seconds_asm + time.perf_counter() - t1

    def _add(self, g, start: int, stop: int, A1, A2, b) -> None:
        """Add factors ``start:stop`` of group ``g`` (their blocks ``A1``, ``A2``, ``b``) to H and g."""
        s = slice(start, stop)
        w = self.weights[g.fidx[s]]
        if g.kind == "between":
            add_binary(A1, A2, b, w, g.o1[s], g.o2[s], g.base11[s], g.stride11[s], g.base22[s],
                       g.stride22[s], g.base12[s], g.stride12[s], g.one_is_row[s], self.data, self.rhs)
        else:
            add_unary(A1, b, w, g.o1[s], g.base11[s], g.stride11[s], self.data, self.rhs)

    def _add_native(self) -> None:
        """Add the natively linearized factors, and keep H's undamped diagonal."""
        nat = self.problem.native_arrays
        if nat is not None:
            add_information(nat.info, nat.info_start, nat.size, nat.key_start, nat.key_local,
                            nat.key_dim, nat.key_offset, nat.pair_start, nat.pair_base,
                            nat.pair_stride, self.weights[nat.fidx], self.data, self.rhs)
        self._diagonal = self.data[self.pattern.diagpos]
        self._damped = False

    def hessian_diagonal(self) -> np.ndarray:
        """diag(H), shape (n,), in δ's order (of the last assembly; not to be modified)."""
        if self._diagonal is None:
            return self.data[self.pattern.diagpos]
        return self._diagonal

    def damp(self, scale: np.ndarray | None) -> np.ndarray:
        """``data`` = H + diag(``scale``) (δ's order; None: H itself), in place; returns ``data``."""
        if scale is None:
            if self._damped:
                _set_diagonal(self.data, self.pattern.diagpos, self._diagonal, np.zeros(self.n))
                self._damped = False
        else:
            if self._diagonal is None:
                self._diagonal = self.data[self.pattern.diagpos]
            _set_diagonal(self.data, self.pattern.diagpos, self._diagonal, np.asarray(scale, dtype=np.float64))
            self._damped = True
        return self.data

    def in_matrix_order(self, v: np.ndarray) -> np.ndarray:
        """A vector (n, ...) in δ's order, reordered as the matrix's rows."""
        return v[self.pattern.scalar_order]

    def from_matrix_order(self, x: np.ndarray) -> np.ndarray:
        """A vector (n, ...) in the matrix's row order, reordered as δ."""
        out = np.empty_like(x)
        out[self.pattern.scalar_order] = x
        return out

    def linear_change(self, delta: np.ndarray) -> float:
        """Decrease of the (weighted) linearized error from δ = 0 to ``delta``."""
        p = self.pattern
        self.damp(None)
        return float(quadratic_change(p.colptr, p.rowind, self.data, self.in_matrix_order(self.rhs),
                                      self.in_matrix_order(delta)))

    def to_dense(self, values: np.ndarray | None = None) -> np.ndarray:
        """The full symmetric H (or H with ``values``) as a dense (n, n) array in δ's order, for
        checks on small graphs."""
        p = self.pattern
        if values is None:
            self.damp(None)
            values = self.data
        rows = p.scalar_order[p.rowind]
        cols = p.scalar_order[p.colind()]
        L = np.zeros((p.n, p.n))
        np.add.at(L, (rows, cols), values)
        return L + L.T - np.diag(np.diag(L))
