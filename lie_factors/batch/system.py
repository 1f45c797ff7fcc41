"""The damped normal equations as one block-sparse symmetric matrix, assembled by numba.

For whitened factor rows ``A δ ≈ b`` (``b = −R·e``) the Gauss–Newton system is
``H δ = g`` with ``H = Σ_f w_f A_fᵀA_f`` and ``g = Σ_f w_f A_fᵀb_f``; LM adds
``λ·I`` (or ``λ·clamp(diag H, 1e-6, 1e32)`` with ``diagonalDamping``, GTSAM's
``LevenbergMarquardtParams`` min/max diagonal) to the diagonal.  ``w_f`` is a
per-factor weight (1 unless a robust/GNC scheme sets :attr:`LinearSystem.weights`):
it multiplies the factor's whole whitened contribution, i.e. scales its rows
by √w_f — GTSAM's robust reweighting.

Storage (computed once per graph): the variables that appear in a factor, in
key order, each a block of its tangent dimension; ``H``'s lower block
triangle in compressed sparse columns (CSC), every diagonal block stored in
full (CHOLMOD with ``uplo='L'`` reads only the lower triangle).  All scalar
columns of one block column have the same rows, so the entry (i, j) of block
(row variable a, column variable b) is at ``base[a, b] + j·stride[b] + i``:
each factor keeps ``base``/``stride`` of its blocks (the *scatter map*), and
assembly is a loop of multiply-adds into ``data`` — no search, no allocation.
"""

from __future__ import annotations

import numpy as np

from ..kernels.jit import kernel


class Pattern:
    """Sparsity pattern of ``H`` for variables of dimensions ``dims`` and the block pairs used.

    ``pairs`` (P, 2) variable indices (any order, duplicates allowed; the
    diagonal blocks are always included).  Attributes: ``n`` (scalar size),
    ``offsets`` (V,), ``colptr`` (n+1,), ``rowind`` (nnz,), ``diagpos`` (n,)
    position of every diagonal entry in ``data``.  :meth:`lookup` gives the
    (base, stride) of block pairs.
    """

    def __init__(self, dims: np.ndarray, pairs: np.ndarray):
        dims = np.asarray(dims, dtype=np.int64)
        V = len(dims)
        self.dims = dims
        self.offsets = np.zeros(V, dtype=np.int64)
        np.cumsum(dims[:-1], out=self.offsets[1:]) if V > 1 else None
        self.n = int(dims.sum())
        pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
        rows = np.concatenate([np.maximum(pairs[:, 0], pairs[:, 1]), np.arange(V)])
        cols = np.concatenate([np.minimum(pairs[:, 0], pairs[:, 1]), np.arange(V)])
        codes = np.unique(cols * V + rows)  # sorted by column, then row
        self._codes = codes
        bcol, brow = codes // V, codes % V
        # Rows of block column b: brow[first[b]:first[b+1]]; offsets of each block in its column.
        first = np.searchsorted(bcol, np.arange(V + 1))
        rdim = dims[brow]
        csum = np.cumsum(rdim) - rdim
        rowoff = csum - csum[first[bcol]]
        L = np.add.reduceat(rdim, first[:-1]) if V else np.zeros(0, np.int64)
        colstart = np.zeros(V + 1, dtype=np.int64)
        np.cumsum(dims * L, out=colstart[1:])
        self.nnz = int(colstart[-1])
        self._base = colstart[bcol] + rowoff
        self._stride = L[bcol]
        self.stride_of_column = L
        self.colptr, self.rowind, self.diagpos = _csc(dims, self.offsets, first, brow, L, colstart)

    def colind(self) -> np.ndarray:
        """The column of every stored entry (nnz,): with ``rowind``, the pattern as triplets."""
        return np.repeat(np.arange(self.n, dtype=np.int64), np.diff(self.colptr))

    def lookup(self, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(base, stride, a_is_row) of the blocks {a, b} (arrays of variable indices)."""
        a = np.asarray(a, dtype=np.int64)
        b = np.asarray(b, dtype=np.int64)
        V = len(self.dims)
        row, col = np.maximum(a, b), np.minimum(a, b)
        idx = np.searchsorted(self._codes, col * V + row)
        assert np.all(self._codes[np.minimum(idx, len(self._codes) - 1)] == col * V + row)
        return self._base[idx], self._stride[idx], (a >= b).astype(np.int64)


@kernel
def _csc(dims, offsets, first, brow, L, colstart):
    V = dims.shape[0]
    n = 0
    for v in range(V):
        n += dims[v]
    colptr = np.empty(n + 1, dtype=np.int64)
    rowind = np.empty(colstart[V], dtype=np.int64)
    diagpos = np.empty(n, dtype=np.int64)
    for b in range(V):
        for j in range(dims[b]):
            c = offsets[b] + j
            p = colstart[b] + j * L[b]
            colptr[c] = p
            for q in range(first[b], first[b + 1]):
                a = brow[q]
                for i in range(dims[a]):
                    rowind[p] = offsets[a] + i
                    if a == b and i == j:
                        diagpos[c] = p
                    p += 1
    colptr[n] = colstart[V]
    return colptr, rowind, diagpos


# --------------------------------------------------------------------------- #
# Assembly kernels (values only; the pattern and scatter map are fixed)
# --------------------------------------------------------------------------- #

@kernel
def _add_gram(A, B, w, base, stride, data):
    """data[base + j·stride + i] += w·Σ_r A[r, i]·B[r, j] (one block of AᵀB)."""
    for j in range(B.shape[1]):
        p = base + j * stride
        for i in range(A.shape[1]):
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
        _add_gram(A1[f], A1[f], wf, base11[f], stride11[f], data)
        _add_gram(A2[f], A2[f], wf, base22[f], stride22[f], data)
        if one_is_row[f]:
            _add_gram(A1[f], A2[f], wf, base12[f], stride12[f], data)
        else:
            _add_gram(A2[f], A1[f], wf, base12[f], stride12[f], data)
        _add_rhs(A1[f], b[f], wf, o1[f], rhs)
        _add_rhs(A2[f], b[f], wf, o2[f], rhs)


@kernel
def add_unary(A1, b, w, o1, base11, stride11, data, rhs):
    """Accumulate w_f·A1ᵀA1 and w_f·A1ᵀb_f of every one-variable factor."""
    for f in range(A1.shape[0]):
        wf = w[f]
        if wf == 0.0:
            continue
        _add_gram(A1[f], A1[f], wf, base11[f], stride11[f], data)
        _add_rhs(A1[f], b[f], wf, o1[f], rhs)


@kernel
def add_information(info, info_start, size, key_start, key_local, key_dim, key_offset,
                    pair_start, pair_base, pair_stride, w, data, rhs):
    """Accumulate GTSAM's augmented information [AᵀA Aᵀb; bᵀA bᵀb] of natively linearized factors.

    Factor f: matrix ``info[info_start[f]:...]`` of side ``size[f] + 1``; its
    keys ``key_start[f]:key_start[f+1]`` with local column, dimension and
    global offset; block (p, q) of its keys at ``pair_base/pair_stride[pair_start[f] + p·k + q]``
    (base −1: upper block, skipped).
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
                    for i in range(dp):
                        data[base + j * st + i] += wf * info[s + (lp + i) * D1 + lq + j]


@kernel
def quadratic_change(colptr, rowind, data, rhs, delta):
    """δᵀg − ½·δᵀHδ: the decrease of ½‖Aδ − b‖² from δ = 0 (H lower triangle + full diagonal blocks)."""
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
            elif r > c:
                quad += 2.0 * data[p] * delta[r] * dc
    return lin - 0.5 * quad


@kernel
def damp(data, diagpos, scale, out):
    """out = data with scale added on the diagonal."""
    out[:] = data
    for c in range(diagpos.shape[0]):
        out[diagpos[c]] += scale[c]


class LinearSystem:
    """``H``, ``g`` of a :class:`~lie_factors.batch.graph.Problem`, in :class:`Pattern` storage.

    ``weights`` (one per graph factor, index = position in the
    NonlinearFactorGraph, 1.0 by default) multiply each factor's
    contribution at the next :meth:`assemble`: the hook for robust
    reweighting (IRLS) and GNC.
    """

    def __init__(self, problem):
        self.problem = problem
        P = problem
        pairs = [np.stack([g.v1, g.v2], axis=1) for g in P.groups if g.kind == "between"]
        pairs += [P.native_pairs]
        self.pattern = pat = Pattern(P.var_dims, np.concatenate(pairs) if pairs else np.zeros((0, 2)))
        self.n = pat.n
        self.data = np.zeros(pat.nnz)
        self.rhs = np.zeros(pat.n)
        self.weights = np.ones(P.graph_size)
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
        data, rhs, w = self.data, self.rhs, self.weights
        data[:] = 0.0
        rhs[:] = 0.0
        for g in self.problem.groups:
            wg = w[g.fidx]
            if g.kind == "between":
                add_binary(g.A1, g.A2, g.b, wg, g.o1, g.o2, g.base11, g.stride11, g.base22,
                           g.stride22, g.base12, g.stride12, g.one_is_row, data, rhs)
            else:
                add_unary(g.A1, g.b, wg, g.o1, g.base11, g.stride11, data, rhs)
        nat = self.problem.native_arrays
        if nat is not None:
            add_information(nat.info, nat.info_start, nat.size, nat.key_start, nat.key_local,
                            nat.key_dim, nat.key_offset, nat.pair_start, nat.pair_base,
                            nat.pair_stride, w[nat.fidx], data, rhs)

    def hessian_diagonal(self) -> np.ndarray:
        """diag(H), shape (n,)."""
        return self.data[self.pattern.diagpos]

    def linear_change(self, delta: np.ndarray) -> float:
        """Decrease of the (weighted) linearized error from δ = 0 to ``delta``."""
        p = self.pattern
        return float(quadratic_change(p.colptr, p.rowind, self.data, self.rhs, delta))

    def damped(self, scale: np.ndarray | None, out: np.ndarray) -> np.ndarray:
        """``out`` = values of H + diag(scale) (``scale`` None: H itself)."""
        if scale is None:
            out[:] = self.data
        else:
            damp(self.data, self.pattern.diagpos, scale, out)
        return out

    def to_dense(self, values: np.ndarray | None = None) -> np.ndarray:
        """The full symmetric H (or H with ``values``) as a dense (n, n) array, for checks on small graphs."""
        p = self.pattern
        v = self.data if values is None else values
        cols = p.colind()
        keep = p.rowind >= cols
        L = np.zeros((p.n, p.n))
        np.add.at(L, (p.rowind[keep], cols[keep]), v[keep])
        return L + np.tril(L, -1).T
