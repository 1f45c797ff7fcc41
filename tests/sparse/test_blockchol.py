"""lie_factors.sparse.blockchol against a factorization from scratch (numpy's dense Cholesky) on
random block graphs: the pattern holds every nonzero of L, the factor and the solve are
numpy's to rounding, and the pivot rule stops at the column a dense elimination in the same
order would refuse."""

from __future__ import annotations

import numpy as np
import pytest

from lie_factors.sparse import blockchol
from lie_factors.sparse.pivots import PIVOT_TOLERANCE


def random_problem(rng, P: int, extra: int):
    dims = rng.choice([1, 2, 3, 6, 9], size=P)
    pairs = [(p, p + 1) for p in range(P - 1)]  # a chain, plus random pairs
    pairs += [tuple(rng.choice(P, 2, replace=False)) for _ in range(extra)]
    pairs = np.array(pairs, dtype=np.int64).reshape(-1, 2)
    soff = np.concatenate([[0], np.cumsum(dims)])
    n = int(soff[-1])
    J = []
    for a, b in pairs:  # a factor on (a, b): random rows
        rows = np.zeros((dims[a] + dims[b], n))
        rows[:, soff[a]:soff[a + 1]] = rng.standard_normal((dims[a] + dims[b], dims[a]))
        rows[:, soff[b]:soff[b + 1]] = rng.standard_normal((dims[a] + dims[b], dims[b]))
        J.append(rows)
    for p in range(P):  # a prior on each, so the matrix is definite
        rows = np.zeros((dims[p], n))
        rows[:, soff[p]:soff[p + 1]] = rng.standard_normal((dims[p], dims[p])) + 3 * np.eye(dims[p])
        J.append(rows)
    J = np.concatenate(J)
    return dims, pairs, J.T @ J


def pack(pat: blockchol.Pattern, H: np.ndarray) -> np.ndarray:
    values = np.zeros(pat.size)
    P = len(pat.dims)
    for p in range(P):
        d, o = pat.dims[p], pat.soff[p]
        values[pat.doff[p]:pat.doff[p] + d * d] = H[o:o + d, o:o + d].ravel()
        for u in range(pat.colptr[p], pat.colptr[p + 1]):
            r = pat.rows[u]
            dr, orow = pat.dims[r], pat.soff[r]
            values[pat.boff[u]:pat.boff[u] + dr * d] = H[orow:orow + dr, o:o + d].ravel()
    return values


@pytest.mark.parametrize("seed", range(8))
def test_factor_and_solve_are_numpys(seed):
    rng = np.random.default_rng(seed)
    dims, pairs, H = random_problem(rng, P=int(rng.integers(2, 40)), extra=int(rng.integers(0, 30)))
    pat = blockchol.pattern(dims, pairs)
    values = pack(pat, H)
    assert blockchol.factor(pat.dims, pat.soff, pat.colptr, pat.rows, pat.boff, pat.doff, pat.rowptr,
                            pat.rowblk, pat.bcol, values, np.diag(H).copy(), PIVOT_TOLERANCE) == -1
    L = blockchol.dense(pat, values)
    reference = np.linalg.cholesky(H)
    np.testing.assert_allclose(L, reference, rtol=0, atol=1e-10 * np.abs(reference).max())
    # the pattern holds every nonzero of the true factor (no entry of L is left out)
    outside = np.abs(reference) * (L == 0) * (np.tril(np.ones_like(H), -1) > 0)
    assert outside.max() < 1e-12 * np.abs(reference).max()
    b = rng.standard_normal(H.shape[0])
    x = b.copy()
    blockchol.solve(pat.dims, pat.soff, pat.colptr, pat.rows, pat.boff, pat.doff, values, x)
    np.testing.assert_allclose(x, np.linalg.solve(H, b), rtol=1e-9, atol=1e-12)


def test_columns_hold_their_rows_ascending_and_block_rows_point_back():
    rng = np.random.default_rng(11)
    dims, pairs, _ = random_problem(rng, 30, 40)
    pat = blockchol.pattern(dims, pairs)
    for p in range(len(dims)):
        rows = pat.rows[pat.colptr[p]:pat.colptr[p + 1]]
        assert np.all(np.diff(rows) > 0) and np.all(rows > p)
        for t in range(pat.rowptr[p], pat.rowptr[p + 1]):
            assert pat.rows[pat.rowblk[t]] == p and pat.bcol[pat.rowblk[t]] < p
    assert len(pat.rows) == pat.rowptr[-1]
    for p in range(len(dims)):
        for u in range(pat.colptr[p], pat.colptr[p + 1]):
            r = pat.rows[u]
            assert blockchol.block_offset(pat.colptr, pat.rows, pat.boff, pat.doff, r, p) == pat.boff[u]
    assert blockchol.block_offset(pat.colptr, pat.rows, pat.boff, pat.doff, 3, 3) == pat.doff[3]


@pytest.mark.parametrize("scale", [1 - 1e-3, 1 + 1e-3])
def test_the_pivot_rule_straddles_its_threshold(scale):
    """A 2×2 block whose second pivot is ``scale`` · 1e-13 of its diagonal entry: refused below,
    taken above (the tolerance of sparse.pivots)."""
    a = 1.0
    eps = scale * PIVOT_TOLERANCE
    # [[a, c], [c, d]] with d − c²/a = eps·d: pivot₂ = eps·d
    d = 1.0
    c = np.sqrt((1 - eps) * a * d)
    H = np.array([[a, c], [c, d]])
    pat = blockchol.pattern(np.array([2]), np.zeros((0, 2), dtype=np.int64))
    values = pack(pat, H)
    got = blockchol.factor(pat.dims, pat.soff, pat.colptr, pat.rows, pat.boff, pat.doff, pat.rowptr,
                           pat.rowblk, pat.bcol, values, np.diag(H).copy(), PIVOT_TOLERANCE)
    assert got == (1 if scale < 1 else -1)


def test_a_singular_column_is_named_and_nan_is_refused():
    H = np.diag([4.0, 0.0, 1.0])
    pat = blockchol.pattern(np.array([1, 1, 1]), np.array([[0, 1], [1, 2]]))
    values = pack(pat, H)
    assert blockchol.factor(pat.dims, pat.soff, pat.colptr, pat.rows, pat.boff, pat.doff, pat.rowptr,
                            pat.rowblk, pat.bcol, values, np.diag(H).copy(), 0.0) == 1
    H = np.diag([4.0, np.nan, 1.0])
    values = pack(pat, H)
    assert blockchol.factor(pat.dims, pat.soff, pat.colptr, pat.rows, pat.boff, pat.doff, pat.rowptr,
                            pat.rowblk, pat.bcol, values, np.ones(3), 0.0) == 1
