"""Selected inversion: the entries of A⁻¹ on the pattern of A's Cholesky factor, from the factor
alone, in place (Takahashi, Fagan and Chen, "Formation of a sparse bus impedance matrix and
its application to short circuit study", PICA 1973), by supernodes as in Lin, Yang, Meza, Lu,
Ying and E, "SelInv — an algorithm for selected inversion of a sparse symmetric matrix", ACM
TOMS 37(4), 2011.

With P·A·Pᵀ = L·Lᵀ and Z = (L·Lᵀ)⁻¹, split L at a supernode J (its columns) into the dense
diagonal block L_JJ and the rows below it, L_BJ (B: the supernode's rows past its
columns).  Then, with Y = L_BJ·L_JJ⁻¹,

    Z_BJ = −Z_BB·Y,        Z_JJ = L_JJ⁻ᵀ·L_JJ⁻¹ − Yᵀ·Z_BJ,

and Z_BB lies on the factor's pattern of later supernodes (the rows of a column's
structure stay in the structure of each of them: the elimination fill), so sweeping the
supernodes from the last to the first computes Z on L's whole pattern, each block over
the factor's entries once they are no longer needed.  The work is that of the
factorization.
"""

from __future__ import annotations

import numpy as np

from ..kernels.jit import kernel
from .supernodes import Supernodes

__all__ = ["invert_in_place", "diagonal_blocks"]


@kernel
def _lower_inverse(L):
    """L⁻¹ of a lower-triangular (k, k) L, by columns of the identity."""
    k = L.shape[0]
    out = np.zeros((k, k))
    for j in range(k):
        out[j, j] = 1.0 / L[j, j]
        for i in range(j + 1, k):
            s = 0.0
            for q in range(j, i):
                s += L[i, q] * out[q, j]
            out[i, j] = -s / L[i, i]
    return out


@kernel
def _product(A, B, transpose_a):
    """A·B, or Aᵀ·B: loops, not BLAS, whose threads cost more than these small blocks."""
    n, k = (A.shape[1], A.shape[0]) if transpose_a else (A.shape[0], A.shape[1])
    out = np.zeros((n, B.shape[1]))
    for i in range(n):
        for q in range(k):
            a = A[q, i] if transpose_a else A[i, q]
            if a != 0.0:
                for j in range(B.shape[1]):
                    out[i, j] += a * B[q, j]
    return out


@kernel
def _gather(first, rowptr, valptr, rows, x, owner, where, B):
    """Z_BB (m, m) for the rows ``B`` (ascending), from the supernodes inverted already: entry
    (r, c), r ≥ c, lies in c's supernode, in c's column, at r's place in its rows."""
    m = B.shape[0]
    Z = np.empty((m, m))
    a = 0
    while a < m:
        t = owner[B[a]]
        r0, nr = rowptr[t], rowptr[t + 1] - rowptr[t]
        for q in range(r0, r0 + nr):
            where[rows[q]] = q - r0
        end = a
        while end < m and owner[B[end]] == t:
            end += 1
        for b in range(a, end):
            col = valptr[t] + (B[b] - first[t]) * nr
            for r in range(b, m):
                p = where[B[r]]
                if p < 0:
                    raise ValueError("selected inversion: a row outside its supernode's structure")
                Z[r, b] = x[col + p]
                Z[b, r] = Z[r, b]
        for q in range(r0, r0 + nr):
            where[rows[q]] = -1
        a = end
    return Z


@kernel
def _invert(first, rowptr, valptr, rows, x, owner):
    n = first[first.shape[0] - 1]
    where = np.full(n, -1, dtype=np.int64)
    for J in range(first.shape[0] - 2, -1, -1):
        nc = first[J + 1] - first[J]
        nr = rowptr[J + 1] - rowptr[J]
        m = nr - nc
        base = valptr[J]
        Ljj = np.zeros((nc, nc))
        for c in range(nc):
            for r in range(c, nc):
                Ljj[r, c] = x[base + c * nr + r]
        Linv = _lower_inverse(Ljj)
        Zjj = _product(Linv, Linv, True)
        if m:
            Lbj = np.empty((m, nc))
            for c in range(nc):
                for r in range(m):
                    Lbj[r, c] = x[base + c * nr + nc + r]
            Y = _product(Lbj, Linv, False)
            Zbj = -_product(_gather(first, rowptr, valptr, rows, x, owner, where, rows[rowptr[J] + nc:rowptr[J + 1]]),
                            Y, False)
            Zjj -= _product(Y, Zbj, True)
            for c in range(nc):
                for r in range(m):
                    x[base + c * nr + nc + r] = Zbj[r, c]
        for c in range(nc):
            for r in range(nc):
                x[base + c * nr + r] = Zjj[r, c]


@kernel
def _blocks(first, rowptr, valptr, rows, x, owner, at):
    """(V, d, d): Z's entries among the factor rows ``at`` (V, d) of each variable."""
    V, d = at.shape
    out = np.empty((V, d, d))
    for v in range(V):
        for a in range(d):
            for b in range(a, d):
                r, c = max(at[v, a], at[v, b]), min(at[v, a], at[v, b])
                t = owner[c]
                r0, nr = rowptr[t], rowptr[t + 1] - rowptr[t]
                p = r - first[t]  # a row among the supernode's own columns sits at its column's place
                if r >= first[t + 1]:
                    p = -1
                    for q in range(r0 + first[t + 1] - first[t], r0 + nr):
                        if rows[q] == r:
                            p = q - r0
                            break
                    if p < 0:
                        raise ValueError("selected inversion: the entry is off the factor's pattern")
                out[v, a, b] = out[v, b, a] = x[valptr[t] + (c - first[t]) * nr + p]
    return out


def _owner(first: np.ndarray) -> np.ndarray:
    return np.repeat(np.arange(len(first) - 1, dtype=np.int64), np.diff(first))


def invert_in_place(factor: Supernodes) -> Supernodes:
    """Overwrite the factor's values with Z = (L·Lᵀ)⁻¹ on its pattern (module docstring); returns it.
    The factor must be one (``first[-1]`` = n)."""
    first, rowptr, valptr, rows = (np.ascontiguousarray(a, dtype=np.int64) for a in factor[1:5])
    _invert(first, rowptr, valptr, rows, factor.values, _owner(first))
    return factor


def diagonal_blocks(inverse: Supernodes, rows: np.ndarray) -> np.ndarray:
    """(V, d, d): the blocks of A⁻¹ among ``rows`` (V, d), row indices of A (before the factor's
    permutation), from :func:`invert_in_place`'s result."""
    where = np.empty(len(inverse.perm), dtype=np.int64)
    where[inverse.perm] = np.arange(len(inverse.perm))
    first, rowptr, valptr, srows = (np.ascontiguousarray(a, dtype=np.int64) for a in inverse[1:5])
    at = where[np.asarray(rows, dtype=np.int64)]
    return _blocks(first, rowptr, valptr, srows, inverse.values, _owner(first), np.ascontiguousarray(at))
