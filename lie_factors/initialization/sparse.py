"""The relaxations' sparse normal equations: block triplets, per-node sums, and their solve.

A symmetric matrix is given by the triplets (row, column, value) of its lower
triangle, duplicates summed; :func:`solve` hands it to CHOLMOD
(:func:`lie_factors.sparse.cholmod.solve_spd`).  :func:`solve_edges` takes the
rows of an edge list instead and assembles them into the batch solver's block
pattern, which CHOLMOD factors in place (the large relaxations).
"""

from __future__ import annotations

import numpy as np

from ..sparse import cholmod
from ..errors import InitializationError


def solve_edges(count: int, ii: np.ndarray, jj: np.ndarray, A1: np.ndarray, A2: np.ndarray,
                diagonal: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """x (count·d, m) with (Σ_e [A1_e A2_e]ᵀ[A1_e A2_e] + diag(``diagonal``)) x = ``rhs``.

    Edge e joins blocks ``ii[e]`` and ``jj[e]`` (of ``count`` blocks of dimension d) with rows
    A1_e (r, d) on the first and A2_e (r, d) on the second; ``diagonal`` (count·d,) adds
    to the diagonal (priors); ``rhs`` (count·d, m).  Assembled by the batch solver's kernel
    into its block pattern (:class:`lie_factors.sparse.pattern.Pattern`, a fill-reducing
    order) and factored there by CHOLMOD.  :class:`InitializationError` if the matrix is
    not positive definite.
    """
    from ..sparse.pattern import Pattern, add_factors  # numba: LAGO's and GTSAM's paths stay without it

    d = A1.shape[2]
    E = len(ii)
    pattern = Pattern(np.full(count, d), np.stack([ii, jj], axis=1))
    data, g = np.zeros(pattern.nnz), np.zeros(pattern.n)
    add_factors(np.ascontiguousarray(A1, dtype=np.float64), np.ascontiguousarray(A2, dtype=np.float64),
               np.zeros((E, A1.shape[1])), np.ones(E), pattern.scatter(ii, jj), data, g)
    data[pattern.diagpos] += diagonal
    try:
        factor = cholmod.Cholesky(pattern.colptr, pattern.rowind)
        factor.factorize(data)
        x = factor.solve(np.asarray(rhs, dtype=np.float64)[pattern.scalar_order])
    except np.linalg.LinAlgError as exc:
        raise InitializationError(str(exc)) from None
    out = np.empty_like(x)
    out[pattern.scalar_order] = x
    if not np.all(np.isfinite(out)):
        raise InitializationError("the linear system is singular (non-finite solution)")
    return out


def solve(n: int, rows: np.ndarray, cols: np.ndarray, vals: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """:func:`lie_factors.sparse.cholmod.solve_spd`, its failure an :class:`InitializationError`."""
    try:
        return cholmod.solve_spd(n, rows, cols, vals, rhs)
    except np.linalg.LinAlgError as exc:
        raise InitializationError(str(exc)) from None


def block_triplets(r: np.ndarray, c: np.ndarray, blocks: np.ndarray, d: int):
    """Triplets of the d×d ``blocks`` (K, d, d) at block rows ``r`` and columns ``c`` (K,)."""
    a = np.arange(d)
    rows = (r[:, None, None] * d + a[None, :, None]) + np.zeros((1, 1, d), dtype=np.int64)
    cols = (c[:, None, None] * d + a[None, None, :]) + np.zeros((1, d, 1), dtype=np.int64)
    return rows.ravel(), cols.ravel(), blocks.ravel()


def scatter_add(index: np.ndarray, values: np.ndarray, N: int) -> np.ndarray:
    """out[k] = Σ values[e] over e with index[e] = k: (E, ...) → (N, ...) (bincount per entry; np.add.at is slow)."""
    flat = values.reshape(values.shape[0], -1)
    out = np.empty((N, flat.shape[1]))
    for c in range(flat.shape[1]):
        out[:, c] = np.bincount(index, weights=flat[:, c], minlength=N)
    return out.reshape((N,) + values.shape[1:])


def lower_block_triplets(i, j, Hij, d):
    """Lower-triangle triplets of off-diagonal blocks H[i, j] = Hij (and H[j, i] = Hijᵀ)."""
    swap = i < j  # store (max, min): the block at (j, i) is Hijᵀ
    r = np.where(swap, j, i)
    c = np.where(swap, i, j)
    B = np.where(swap[:, None, None], np.swapaxes(Hij, 1, 2), Hij)
    return block_triplets(r, c, B, d)


def diag_lower_triplets(D: np.ndarray, d: int):
    """Lower-triangle triplets of the diagonal blocks D (n, d, d)."""
    n = D.shape[0]
    a, b = np.tril_indices(d)
    base = np.arange(n)[:, None] * d
    return (base + a).ravel(), (base + b).ravel(), D[:, a, b].ravel()
