"""lie_factors.sparse.selinv: the inverse on the factor's pattern, against numpy's dense inverse,
for supernodal and simplicial factors, both ways into CHOLMOD."""

from __future__ import annotations

import numpy as np
import pytest

from lie_factors.sparse import cholmod
from lie_factors.sparse.selinv import diagonal_blocks, invert_in_place
from lie_factors.sparse.supernodes import Supernodes


def _block_spd(blocks: int, d: int, density: float, seed: int, dense_rows: int = 0) -> np.ndarray:
    """A random SPD matrix of ``blocks`` variables of dimension d: dense diagonal blocks, random
    off-diagonal ones, and a few variables coupled to all (large supernodes)."""
    rng = np.random.default_rng(seed)
    n = blocks * d
    mask = rng.random((blocks, blocks)) < density
    mask[:dense_rows] = True
    mask |= np.eye(blocks, dtype=bool)
    M = np.kron(mask, np.ones((d, d))) * rng.normal(size=(n, n))
    return M @ M.T + np.eye(n)


def _factor(A: np.ndarray, supernodal: bool, natural: bool) -> tuple[cholmod.Cholesky, Supernodes]:
    n = A.shape[0]
    r, c = np.nonzero(np.tril(A))
    colptr, rowind, values = cholmod.lower_csc(n, r, c, A[r, c])
    factor = cholmod.Cholesky(colptr, rowind, natural=natural, supernodal=supernodal)
    factor.factorize(values)
    if factor.supernodal and cholmod.direct_available():
        return factor, factor.supernodes()
    return factor, Supernodes.from_lower(*factor.lower())


def _entries(S: Supernodes):
    """(rows, cols, values) of every stored entry of the lower triangle, in the factor's order."""
    out = ([], [], [])
    for t in range(len(S.first) - 1):
        rows = S.rows[S.rowptr[t]:S.rowptr[t + 1]]
        for c, col in enumerate(range(S.first[t], S.first[t + 1])):
            keep = rows >= col
            block = S.values[S.valptr[t] + c * len(rows):S.valptr[t] + (c + 1) * len(rows)]
            out[0].append(rows[keep])
            out[1].append(np.full(keep.sum(), col))
            out[2].append(block[keep])
    return tuple(np.concatenate(a) for a in out)


@pytest.mark.parametrize("supernodal", [True, False])
@pytest.mark.parametrize("natural", [True, False])
@pytest.mark.parametrize("blocks, d, density, dense_rows", [(1, 1, 1.0, 0), (1, 6, 1.0, 0), (60, 3, 0.04, 0),
                                                           (80, 6, 0.02, 2), (200, 1, 0.01, 5)])
def test_every_entry_on_the_pattern_is_the_inverses(cholmod_way, supernodal, natural, blocks, d, density,
                                                     dense_rows):
    A = _block_spd(blocks, d, density, seed=blocks * d, dense_rows=dense_rows)
    factor, S = _factor(A, supernodal, natural)
    L_rows, L_cols, _ = _entries(S)
    inverse = invert_in_place(S)
    rows, cols, values = _entries(inverse)
    np.testing.assert_array_equal(rows, L_rows)
    Ainv = np.linalg.inv(A)[np.ix_(S.perm, S.perm)]  # (P·A·Pᵀ)⁻¹ = P·A⁻¹·Pᵀ
    scale = np.abs(Ainv).max()
    np.testing.assert_allclose(values, Ainv[rows, cols], rtol=0, atol=1e-13 * scale)
    at = np.arange(A.shape[0]).reshape(blocks, d)
    expected = np.stack([np.linalg.inv(A)[np.ix_(r, r)] for r in at])
    np.testing.assert_allclose(diagonal_blocks(inverse, at), expected, rtol=0, atol=1e-13 * scale)


def test_a_block_off_the_pattern_is_refused(cholmod_way):
    A = np.diag([2.0, 3.0, 4.0])
    _, S = _factor(A, True, True)
    with pytest.raises(ValueError, match="off the factor's pattern"):
        diagonal_blocks(invert_in_place(S), np.array([[0, 2]]))


def test_the_inverse_replaces_the_factor_so_it_cannot_solve_again():
    if not cholmod.direct_available():
        pytest.skip("the direct way into CHOLMOD does not load here")
    A = _block_spd(20, 3, 0.1, seed=3)
    factor, S = _factor(A, True, True)
    invert_in_place(S)
    with pytest.raises(RuntimeError, match="factorize again"):
        factor.solve(np.ones(A.shape[0]))
