"""lie_factors.sparse.cholmod: CHOLMOD called directly (ctypes) and through cvxopt's API, against
dense numpy on random sparse SPD matrices; the fill-reducing block order; the in-place factorization."""

from __future__ import annotations

import ctypes
import re

import numpy as np
import pytest

from lie_factors.errors import InputError, NotPositiveDefinite
from lie_factors.sparse import cholmod


def _random_spd(n, density, seed, dense_rows=0):
    """A random sparse SPD matrix (n, n), dense; optionally with a few dense rows (supernodes)."""
    rng = np.random.default_rng(seed)
    M = np.where(rng.random((n, n)) < density, rng.normal(size=(n, n)), 0.0)
    M[:dense_rows] = rng.normal(size=(dense_rows, n))
    A = M @ M.T + n * np.eye(n)
    return A


def _lower(A):
    n = A.shape[0]
    r, c = np.nonzero(np.tril(A))
    return cholmod.lower_csc(n, r, c, A[r, c])


@pytest.mark.parametrize("natural", [True, False])
@pytest.mark.parametrize("n, density, dense_rows", [(1, 1.0, 0), (40, 0.05, 0), (300, 0.01, 30)])
def test_factor_and_solves_against_dense(cholmod_way, natural, n, density, dense_rows):
    A = _random_spd(n, density, seed=n, dense_rows=dense_rows)
    colptr, rowind, values = _lower(A)
    factor = cholmod.Cholesky(colptr, rowind, natural=natural)
    factor.factorize(values)
    rng = np.random.default_rng(1)
    b = rng.normal(size=n)
    B = rng.normal(size=(n, 3))
    np.testing.assert_allclose(factor.solve(b), np.linalg.solve(A, b), rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(factor.solve(B), np.linalg.solve(A, B), rtol=1e-10, atol=1e-12)
    Z, d = factor.half(B)
    np.testing.assert_allclose((Z * d[:, None]).T @ Z, B.T @ np.linalg.solve(A, B), rtol=1e-9)
    # refactor with other values on the same pattern
    factor.factorize(2.0 * values)
    np.testing.assert_allclose(factor.solve(b), np.linalg.solve(2.0 * A, b), rtol=1e-10, atol=1e-12)
    if cholmod_way == "direct":
        assert factor.factor_entries >= colptr[-1] and factor.flops > 0


@pytest.mark.parametrize("supernodal", [False, True])  # a chain: simplicial LDLᵀ; else supernodal LLᵀ
def test_not_positive_definite_is_refused(cholmod_way, supernodal):
    n = 300
    if supernodal:
        A = _random_spd(n, 0.01, seed=5, dense_rows=30)
    else:
        A = 4.0 * np.eye(n) + np.diag(np.ones(n - 1), 1) + np.diag(np.ones(n - 1), -1)
    A[n - 1, n - 1] = -abs(A[n - 1, n - 1]) - 1e6  # the last pivot is negative
    colptr, rowind, values = _lower(A)
    factor = cholmod.Cholesky(colptr, rowind, natural=True)
    with pytest.raises(NotPositiveDefinite, match="not positive definite") as info:
        factor.factorize(values)
    assert isinstance(info.value, np.linalg.LinAlgError)
    if cholmod_way == "direct":
        assert factor.supernodal == supernodal
        assert info.value.column == n - 1


def test_direct_factor_keeps_the_natural_order_and_factors_in_place():
    """The cause of the speed: with ``natural``, CHOLMOD's factor keeps the order (no permuted
    copy of the matrix at each factorization), and it reads the values where they are."""
    if not cholmod.direct_available():
        pytest.fail("CHOLMOD is not called directly here (LIE_FACTORS_CHOLMOD or an unchecked layout)")
    A = _random_spd(300, 0.01, seed=3, dense_rows=30)
    colptr, rowind, values = _lower(A)
    natural = cholmod.Cholesky(colptr, rowind, natural=True)
    head = natural._L.contents
    assert head.ordering == 0 and head.is_super  # CHOLMOD_NATURAL, supernodal
    perm = np.ctypeslib.as_array(ctypes.cast(head.Perm, ctypes.POINTER(ctypes.c_int32)), shape=(300,))
    assert np.array_equal(perm, np.arange(300))
    natural.factorize(values)
    assert natural._A.x == values.ctypes.data and natural._A.i == natural.rowind.ctypes.data
    ordered = cholmod.Cholesky(colptr, rowind, natural=False)
    assert ordered._L.contents.ordering != 0


def test_factor_is_released(cholmod_way):
    A = _random_spd(40, 0.1, seed=2)
    colptr, rowind, values = _lower(A)
    factor = cholmod.Cholesky(colptr, rowind)
    factor.factorize(values)
    factor.free()
    if cholmod_way == "direct":
        assert not factor._finalizer.alive


def test_values_must_match_the_pattern(cholmod_way):
    colptr, rowind, values = _lower(_random_spd(10, 0.3, seed=1))
    factor = cholmod.Cholesky(colptr, rowind)
    with pytest.raises(InputError, match="contiguous"):
        factor.factorize(values[:-1])
    with pytest.raises(InputError, match="contiguous"):
        factor.factorize(values.astype(np.float32))


def test_block_order_is_a_fill_reducing_permutation(cholmod_way):
    """A grid of blocks: the order is a permutation, and it fills in less than the grid's rows."""
    k = 12
    idx = np.arange(k * k).reshape(k, k)
    rows = np.concatenate([idx[:, :-1].ravel(), idx[:-1, :].ravel()])
    cols = np.concatenate([idx[:, 1:].ravel(), idx[1:, :].ravel()])
    order = cholmod.block_order(k * k, rows, cols)
    assert sorted(order.tolist()) == list(range(k * k))

    def fill(order):
        pos = np.empty(k * k, dtype=np.int64)
        pos[order] = np.arange(k * k)
        A = np.eye(k * k) * 8.0
        A[pos[rows], pos[cols]] = A[pos[cols], pos[rows]] = -1.0
        return np.count_nonzero(np.abs(np.linalg.cholesky(A)) > 1e-12)

    assert fill(order) < fill(np.arange(k * k))


def test_solve_spd_sums_duplicate_triplets(cholmod_way):
    A = _random_spd(50, 0.1, seed=7)
    r, c = np.nonzero(np.tril(A))
    v = A[r, c]
    half = len(r) // 2  # the first half of the entries given twice, halved
    rows = np.concatenate([r, r[:half]])
    cols = np.concatenate([c, c[:half]])
    vals = np.concatenate([np.where(np.arange(len(r)) < half, v / 2, v), v[:half] / 2])
    b = np.arange(50.0)
    np.testing.assert_allclose(cholmod.solve_spd(50, rows, cols, vals, b), np.linalg.solve(A, b), rtol=1e-10)
    with pytest.raises(np.linalg.LinAlgError, match="not positive definite"):
        cholmod.solve_spd(2, np.array([0, 1, 1]), np.array([0, 0, 1]), np.array([1.0, 2.0, 1.0]), np.ones(2))


def test_an_unexpected_library_layout_is_not_called_directly():
    """The defaults cholmod_start must show are checked; a buffer that does not show them fails."""
    lib = cholmod._direct()
    if lib is None:
        pytest.fail("CHOLMOD is not called directly here")
    common = ctypes.create_string_buffer(cholmod._COMMON_BYTES)
    assert lib.cholmod_start(common)
    assert cholmod._check_layout(common)
    lib.cholmod_finish(common)
    assert not cholmod._check_layout(ctypes.create_string_buffer(cholmod._COMMON_BYTES))


def test_supernodal_values_are_ours_and_reused_within_the_scope():
    """A supernodal factor's entries live in an array this module owns; inside
    ``reuse_factor_memory`` the next factor that fits takes the released one (its pages are
    touched once), outside it does not; the solutions are unaffected."""
    if not cholmod.direct_available():
        pytest.fail("CHOLMOD is not called directly here")
    big = _lower(_random_spd(300, 0.01, seed=3, dense_rows=30))
    small = _lower(_random_spd(200, 0.01, seed=4, dense_rows=20))

    def factor(csc):
        f = cholmod.Cholesky(csc[0], csc[1])
        assert f.supernodal and f._L.contents.x == f._x.ctypes.data
        f.factorize(csc[2])
        return f

    first = factor(big)
    address = first._x.ctypes.data
    first.free()
    assert cholmod._Spare.array is None  # outside the scope: freed
    with cholmod.reuse_factor_memory():
        first = factor(big)
        address = first._x.ctypes.data
        first.free()
        second = factor(small)  # fits in the released array
        assert second._x.ctypes.data == address
        n = len(small[0]) - 1
        b = np.arange(1.0, n + 1.0)
        A = np.zeros((n, n))
        cols = np.repeat(np.arange(n), np.diff(small[0]))
        A[small[1], cols] = small[2]
        A = A + np.tril(A, -1).T
        np.testing.assert_allclose(second.solve(b), np.linalg.solve(A, b), rtol=1e-10)
        second.free()
        spare = cholmod._Spare.array.size
        third = factor(_lower(_random_spd(400, 0.01, seed=5, dense_rows=40)))  # too large: a new array
        assert cholmod._Spare.array is None and third._x.size == third._L.contents.xsize > spare
        third.free()
    assert cholmod._Spare.array is None


@pytest.mark.parametrize("natural", [True, False])
@pytest.mark.parametrize("density, dense_rows", [(0.0, 0), (0.05, 0), (0.01, 30)])
def test_lower_is_the_factor_of_the_permuted_matrix(cholmod_way, natural, density, dense_rows):
    # density 0: a chain, where CHOLMOD takes a simplicial L·D·Lᵀ; dense rows make supernodes (L·Lᵀ)
    n = 120
    A = _random_spd(n, density, seed=5, dense_rows=dense_rows)
    for i in range(n - 1):
        A[i + 1, i] = A[i, i + 1] = 0.5
    colptr, rowind, values = _lower(A)
    factor = cholmod.Cholesky(colptr, rowind, natural=natural)
    factor.factorize(values)
    perm, Lp, Li, Lx, d = factor.lower()
    L = np.zeros((n, n))
    for j in range(n):
        assert Li[Lp[j]] == j and Lx[Lp[j]] == 1.0  # unit diagonal, first in its column
        L[Li[Lp[j]:Lp[j + 1]], j] = Lx[Lp[j]:Lp[j + 1]]
    assert np.all(np.tril(L) == L) and np.all(d > 0)
    np.testing.assert_allclose(L @ np.diag(d) @ L.T, A[np.ix_(perm, perm)], atol=1e-10 * n)
    if natural:
        np.testing.assert_array_equal(perm, np.arange(n))
    with pytest.raises(RuntimeError, match="factorize again"):
        factor.solve(np.ones(n))
    factor.factorize(values)  # a new factorization can be solved with again
    np.testing.assert_allclose(factor.solve(np.ones(n)), np.linalg.solve(A, np.ones(n)), rtol=1e-9)


@pytest.mark.parametrize("natural", [True, False])
@pytest.mark.parametrize("supernodal", [False, True])
@pytest.mark.parametrize("w, refused", [(1e-14, True), (1e-12, False)])
def test_a_pivot_not_above_1e_13_of_its_diagonal_entry_is_refused(cholmod_way, natural, supernodal, w, refused):
    """The block [[1 + w, −1], [−1, 1]] at columns 100 and 200 (a scalar of two poses joined by a
    between factor of unit information, the first with a prior of information w) beside a
    definite matrix (a chain: CHOLMOD's simplicial L·D·Lᵀ; dense rows: supernodal L·Lᵀ).
    Whichever of the two columns is eliminated second, its pivot is w/(1 + w) of its diagonal
    entry: (1 + w) − 1 of 1 + w, or 1 − 1/(1 + w) of 1.  Rounding moves that by about 2e-16
    (the spacing of doubles near 1 + w), far from 1e-13 on either side: w = 1e-14 is refused at that column (the matrix's numbering),
    w = 1e-12 is not, and the sign rule (tolerance 0, Levenberg–Marquardt's) takes both."""
    from lie_factors.sparse.pivots import PIVOT_TOLERANCE

    assert PIVOT_TOLERANCE == 1e-13
    n = 300
    A = (_random_spd(n, 0.01, seed=6, dense_rows=30) if supernodal
         else 4.0 * np.eye(n) + np.diag(np.ones(n - 1), 1) + np.diag(np.ones(n - 1), -1))
    A[[100, 200], :] = A[:, [100, 200]] = 0.0
    A[100, 100], A[200, 200], A[100, 200], A[200, 100] = 1.0 + w, 1.0, -1.0, -1.0
    colptr, rowind, values = _lower(A)
    factor = cholmod.Cholesky(colptr, rowind, natural=natural)
    if refused:
        with pytest.raises(NotPositiveDefinite, match="not positive definite to double precision") as info:
            factor.factorize(values)
        assert info.value.column in (100, 200)
        ratio = re.search(r"is (\S+) of its diagonal entry, not above 1e-13", str(info.value)).group(1)
        assert float(ratio) == pytest.approx(w, rel=0.05)  # 1 + w rounds w by 2e-16 / w
    else:
        factor.factorize(values)
        np.testing.assert_allclose(factor.solve(A[:, 100]), np.eye(n)[100], atol=1e-9)
    factor.factorize(values, pivot_tolerance=0.0)
    if cholmod_way == "direct":
        assert factor.supernodal == supernodal
