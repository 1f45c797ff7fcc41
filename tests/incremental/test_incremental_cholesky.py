"""The incremental block factor against a from-scratch dense Cholesky of the same matrix, same order."""

from __future__ import annotations

import numpy as np
import pytest

import gtsam

from lie_factors.incremental.cholesky import BlockFactor
from lie_factors.incremental.ordering import MAX_SMALL, WORD
from lie_factors.incremental.structures import Pools, Tree
from lie_factors.errors import IndeterminantLinearSystem


def _jacobians(rng, dims, rows, scale=1.0):
    """Random whitened Jacobians [A_1 … A_k | b] (F, rows, D + 1) for factors on variables of ``dims``."""
    D = int(sum(dims))
    return scale * rng.normal(size=(rows, D + 1))


def check_exact(bf: BlockFactor, rtol=1e-10):
    """L from the nodes equals chol(P Λ Pᵀ), y equals L⁻¹ P η, to ``rtol`` relative."""
    H, eta = bf.dense_system()
    perm, L, y = bf.dense_factor()
    ref = np.linalg.cholesky(H[np.ix_(perm, perm)])
    assert np.max(np.abs(L - ref)) <= rtol * np.max(np.abs(ref))
    yref = np.linalg.solve(ref, eta[perm])
    assert np.max(np.abs(y - yref)) <= rtol * max(1.0, np.max(np.abs(yref)))
    return H, eta


def check_solution(bf: BlockFactor, H, eta, rtol=1e-9):
    bf.solve(0.0)
    x = np.linalg.solve(H, eta)
    assert np.max(np.abs(bf.delta[:bf.nscalar] - x)) <= rtol * max(1.0, np.max(np.abs(x)))


class RandomProblem:
    """Poses of mixed dimensions added one per update with odometry, random loop closures,
    landmarks seen from several poses, relinearizations (new Jacobians for old factors)."""

    def __init__(self, seed, dims=(3, 6, 2, 7), keep_update=None, small_pools=False):
        self.rng = np.random.default_rng(seed)
        self.bf = BlockFactor() if keep_update is None else BlockFactor(keep_update)
        if small_pools:  # every update grows or compacts them
            self.bf.pools = Pools(np.zeros(8, dtype=np.int64), np.zeros(64))
        self.dims = []
        self.factors = []  # (vars,)
        self.dim_choices = dims

    def add_pose(self, loops=0):
        rng, bf = self.rng, self.bf
        d = int(rng.choice(self.dim_choices))
        v = bf.nv
        new = []
        if v == 0:
            new.append((np.array([[v]]), _jacobians(rng, [d], d + 1)[None]))
        else:
            prev = v - 1
            dp = bf.tree.dim[prev]
            new.append((np.array([[prev, v]]), _jacobians(rng, [dp, d], d + 2)[None]))
            for _ in range(loops):
                a = int(rng.integers(0, v))
                new.append((np.array([[a, v]]), _jacobians(rng, [bf.tree.dim[a], d], 2)[None]))
        bf.update(new_dims=[d], new_factors=new)
        for fv, _ in new:
            self.factors.append(fv[0])
        return v

    def relinearize(self, count):
        rng, bf = self.rng, self.bf
        vars_ = rng.choice(bf.nv, size=min(count, bf.nv), replace=False)
        fids = [f for f in range(bf.nf) if set(self.factors[f]) & set(vars_.tolist())]
        refreshed = []
        for f in fids:
            vs = self.factors[f]
            r = int(bf.store.frows[f])
            refreshed.append((np.array([f]), _jacobians(rng, bf.tree.dim[vs], r)[None]))
        bf.update(refreshed=refreshed, relinearized=vars_)
        return vars_


@pytest.mark.parametrize("seed,keep_update,small_pools", [(0, None, False), (1, None, True), (2, None, False),
                                                           (3, 0, False), (4, 200, True), (5, 10 ** 9, False)])
def test_random_updates_equal_a_from_scratch_cholesky(seed, keep_update, small_pools):
    # clique members below the last keep no update matrix (0), small ones (200), every one;
    # pools that start small are grown and compacted in place along the way
    p = RandomProblem(seed, keep_update=keep_update, small_pools=small_pools)
    for step in range(60):
        loops = int(p.rng.random() < 0.3) + int(p.rng.random() < 0.1)
        p.add_pose(loops)
        if step % 7 == 6:
            p.relinearize(3)
        if step % 5 == 0 or step > 50:
            H, eta = check_exact(p.bf)
            check_solution(p.bf, H, eta)
    assert p.bf.totals.batch >= 1  # the first updates re-eliminate everything
    if small_pools:
        assert p.bf.compactions > 0
    H, eta = check_exact(p.bf)
    check_solution(p.bf, H, eta)


def test_large_fronts_take_their_trailing_update_from_blas_and_stay_exact():
    from lie_factors.incremental.fronts import uses_blas

    # dense loop closures: fronts of a hundred scalars and more, whose blocks pass the BLAS
    # threshold; the factor is still the from-scratch Cholesky
    p = RandomProblem(6, dims=(6,))
    for step in range(70):
        p.add_pose(loops=3 if step > 5 else 0)
        if step % 9 == 8:
            p.relinearize(4)
    assert p.bf.work.stats[7] > 0
    H, eta = check_exact(p.bf)
    check_solution(p.bf, H, eta)
    # a chain's fronts are small: no BLAS call
    q = RandomProblem(7, dims=(6,))
    for _ in range(50):
        q.add_pose()
    assert q.bf.work.stats[7] == 0
    assert not uses_blas(6, 200) and not uses_blas(60, 20) and uses_blas(60, 200)


def test_odometry_only_update_refactors_a_constant_number_of_columns():
    p = RandomProblem(1, dims=(6,))
    for step in range(40):
        p.add_pose(loops=1 if step in (10, 20) else 0)
    counts = []
    for _ in range(200):
        p.add_pose(loops=0)
        counts.append(p.bf.last.columns)
    assert max(counts[5:]) <= 3 and not any(p.bf.last.batch for _ in [0])
    check_exact(p.bf)


def test_loop_closure_refactors_the_paths_to_the_root_only():
    p = RandomProblem(2, dims=(3,))
    for _ in range(300):
        p.add_pose()
    bf = p.bf
    # a closure to pose 150: the new column, its neighbours and the path from 150 to the root
    new = [(np.array([[150, bf.nv]]), _jacobians(p.rng, [3, 3], 3)[None]),
           (np.array([[bf.nv - 1, bf.nv]]), _jacobians(p.rng, [3, 3], 3)[None])]
    bf.update(new_dims=[3], new_factors=new)
    assert not bf.last.batch
    assert bf.last.columns < 300 * 0.65
    check_exact(bf)


def test_refused_update_leaves_the_factor_as_it_was():
    p = RandomProblem(3, dims=(3, 6))
    for _ in range(30):
        p.add_pose(loops=int(p.rng.random() < 0.3))
    bf = p.bf
    bf.solve(0.0)
    before = (bf.dense_factor(), bf.delta[:bf.nscalar].copy(), bf.nv, bf.nf)
    # a new variable with a rank-deficient factor: 2 rows for a 3-vector
    with pytest.raises(IndeterminantLinearSystem):
        bf.update(new_dims=[3], new_factors=[(np.array([[bf.nv - 1, bf.nv]]),
                                              _jacobians(p.rng, [bf.tree.dim[bf.nv - 1], 3], 2)[None])])
    after = (bf.dense_factor(), bf.delta[:bf.nscalar].copy(), bf.nv, bf.nf)
    assert after[2:] == before[2:]
    for a, b in zip(after[0], before[0]):
        assert np.array_equal(a, b)
    assert np.array_equal(after[1], before[1])
    p.add_pose(loops=1)
    H, eta = check_exact(bf)
    check_solution(bf, H, eta)


def test_marginal_covariance_is_the_block_of_the_inverse():
    p = RandomProblem(4)
    for _ in range(40):
        p.add_pose(loops=int(p.rng.random() < 0.3))
    bf = p.bf
    H, _ = bf.dense_system()
    Sigma = np.linalg.inv(H)
    for v in (0, 17, bf.nv - 1):
        idx = bf.tree.voff[v] + np.arange(bf.tree.dim[v])
        ref = Sigma[np.ix_(idx, idx)]
        assert np.allclose(bf.marginal_covariance(v), ref, rtol=1e-9, atol=1e-12 * np.abs(ref).max())


def _ancestors(bf, variables):
    """The nodes on the paths from ``variables`` to their roots, from the tree's parents."""
    out = set()
    for v in variables:
        j = int(v)
        while j >= 0:
            out.add(j)
            j = int(bf.tree.parent[j])
    return out


@pytest.mark.parametrize("seed", [5, 6, 7])
def test_projected_and_joint_covariances_are_blocks_of_the_inverse(seed):
    """Bᵀ Λ⁻¹ B from one substitution over the union of the paths, and the joint blocks, equal
    the dense inverse's, for variables of mixed dimensions in any order, B of any width."""
    from lie_factors.incremental.substitution import solve_on_paths

    p = RandomProblem(seed)
    for _ in range(40):
        p.add_pose(loops=int(p.rng.random() < 0.4))
    p.relinearize(6)
    bf = p.bf
    H, _ = bf.dense_system()
    Sigma = np.linalg.inv(H)
    for k, m in ((1, 3), (2, 6), (3, 1), (5, 12)):
        vs = p.rng.choice(bf.nv, size=k, replace=False)
        idx = np.concatenate([bf.tree.voff[v] + np.arange(bf.tree.dim[v]) for v in vs])
        B = p.rng.normal(size=(len(idx), m))
        ref = B.T @ Sigma[np.ix_(idx, idx)] @ B
        assert np.allclose(bf.projected_covariance(vs, B), ref, rtol=1e-9, atol=1e-12 * np.abs(ref).max())
        joint = Sigma[np.ix_(idx, idx)]
        assert np.allclose(bf.joint_covariance(vs), joint, rtol=1e-9, atol=1e-12 * np.abs(joint).max())
        # the cause of its cost: each node of the union once, children before parents
        nodes, Z = solve_on_paths(np.asarray(vs, dtype=np.int64), B, bf.tree, bf.pools)
        assert set(nodes.tolist()) == _ancestors(bf, vs) and len(nodes) == len(set(nodes.tolist()))
        place = {int(j): q for q, j in enumerate(nodes)}
        assert all(place[int(bf.tree.parent[j])] > q for q, j in enumerate(nodes) if bf.tree.parent[j] >= 0)
        assert Z.shape == (int(bf.tree.dim[nodes].sum()), m)


def test_projected_covariance_refuses_blocks_of_the_wrong_height():
    p = RandomProblem(8)
    for _ in range(5):
        p.add_pose()
    with pytest.raises(ValueError, match="rows"):
        p.bf.projected_covariance([0, 1], np.ones((int(p.bf.tree.dim[[0, 1]].sum()) + 1, 2)))


def _pool_layout(data, nv):
    """A random factor's pools: each node's separator, conditional and update matrix (or none)
    placed at shuffled addresses with gaps of freed entries between them."""
    from hypothesis import strategies as st
    from lie_factors.incremental.structures import packed

    dim = np.array(data.draw(st.lists(st.integers(1, 4), min_size=nv, max_size=nv)), dtype=np.int64)
    live = np.array(data.draw(st.lists(st.booleans(), min_size=nv, max_size=nv)))
    sep_len = np.array(data.draw(st.lists(st.integers(0, 3), min_size=nv, max_size=nv)), dtype=np.int64)
    sep_dim = sep_len * 2
    has_update = np.array(data.draw(st.lists(st.booleans(), min_size=nv, max_size=nv)))
    isegs = [(j, int(sep_len[j])) for j in range(nv) if live[j] and sep_len[j] > 0]
    fsegs = [(j, int(dim[j] * (dim[j] + sep_dim[j] + 1))) for j in range(nv) if live[j]]
    fsegs += [(-1 - j, int(packed(sep_dim[j] + 1))) for j in range(nv) if has_update[j]]

    def place(segs):
        order = data.draw(st.permutations(range(len(segs)))) if segs else []
        starts, top = {}, 0
        for k in order:
            top += data.draw(st.integers(0, 5))  # freed entries
            starts[segs[k][0]] = top
            top += segs[k][1]
        return starts, top + data.draw(st.integers(0, 5))

    istarts, itop = place(isegs)
    fstarts, ftop = place(fsegs)
    sep_start = np.array([istarts.get(j, -1) for j in range(nv)], dtype=np.int64)
    cond = np.array([fstarts.get(j, -1) for j in range(nv)], dtype=np.int64)
    ustart = np.array([fstarts.get(-1 - j, -1) for j in range(nv)], dtype=np.int64)
    rng = np.random.default_rng(data.draw(st.integers(0, 2 ** 32 - 1)))
    ipool = rng.integers(0, 10 ** 6, size=itop).astype(np.int64)
    fpool = rng.normal(size=ftop)
    return dim, sep_start, sep_len, sep_dim, cond, ustart, ipool, fpool, dict(isegs), dict(fsegs)


def test_compact_pools_keeps_every_live_segment_and_packs_them_in_address_order():
    """Pool compaction against its definition: every live separator, conditional and update
    matrix keeps its entries, the node points at them, they are contiguous from 0 in their
    former address order, and the tops are their total sizes."""
    from hypothesis import given, settings
    from hypothesis import strategies as st
    from lie_factors.incremental.storage import compact_pools

    @settings(max_examples=200, deadline=None)
    @given(data=st.data(), nv=st.integers(1, 12))
    def check(data, nv):
        dim, sep_start, sep_len, sep_dim, cond, ustart, ipool, fpool, isizes, fsizes = _pool_layout(data, nv)
        ibefore = {j: ipool[sep_start[j]:sep_start[j] + n].copy() for j, n in isizes.items()}
        fstart = lambda j: cond[j] if j >= 0 else ustart[-1 - j]
        fbefore = {j: fpool[fstart(j):fstart(j) + n].copy() for j, n in fsizes.items()}
        iorder = sorted(isizes, key=lambda j: sep_start[j])
        forder = sorted(fsizes, key=fstart)
        zeros = np.zeros(len(dim), dtype=np.int64)
        tree = Tree(dim, zeros, zeros, zeros, zeros, zeros, zeros, sep_start, sep_len, sep_dim, cond, ustart,
                    np.full(1, -1, dtype=np.int64))
        itop, ftop = compact_pools(len(dim), tree, Pools(ipool, fpool))
        assert (itop, ftop) == (sum(isizes.values()), sum(fsizes.values()))
        at = 0
        for j in iorder:
            assert sep_start[j] == at
            np.testing.assert_array_equal(ipool[at:at + isizes[j]], ibefore[j])
            at += isizes[j]
        at = 0
        for j in forder:
            assert fstart(j) == at
            np.testing.assert_array_equal(fpool[at:at + fsizes[j]], fbefore[j])
            at += fsizes[j]

    check()


def test_many_compactions_keep_the_factor_exact():
    """Pools that start small and a relinearization every third pose: the pools are compacted
    dozens of times, and the factor equals a from-scratch Cholesky after each."""
    p = RandomProblem(11, small_pools=True)
    checked = 0
    for step in range(180):
        p.add_pose(int(p.rng.random() < 0.3))
        if step % 3 == 2:
            p.relinearize(8)
        if p.bf.compactions > checked:
            checked = p.bf.compactions
            check_exact(p.bf)
    assert p.bf.compactions >= 20
    H, eta = check_exact(p.bf)
    check_solution(p.bf, H, eta)


# minimum degree on small affected sets: a valid constrained order, the expected one on known
# graphs, no GTSAM call
def _chain_with_hub(bf: BlockFactor, n: int, rng):
    """n variables of dimension 2: a chain, and variable 0 tied to every other (a hub)."""
    dims = [2] * n
    factors = [(np.array([[0]]), rng.normal(size=(1, 3, 3)))]
    factors += [(np.array([[i - 1, i]]), rng.normal(size=(1, 4, 5))) for i in range(1, n)]
    factors += [(np.array([[0, i]]), rng.normal(size=(1, 2, 5))) for i in range(2, n)]
    bf.update(new_dims=dims, new_factors=factors)


def test_minimum_degree_eliminates_the_hub_last_and_the_observed_after_the_rest():
    rng = np.random.default_rng(0)
    bf = BlockFactor()
    _chain_with_hub(bf, 8, rng)  # everything new: all observed, ordered without constraint
    order = bf.ordering().tolist()
    assert sorted(order) == list(range(8))
    # the hub meets every variable: minimum degree takes it last, or with the last two
    # (once the rest are gone every remaining variable has the same degree)
    assert order.index(0) >= 5
    H, eta = check_exact(bf)
    check_solution(bf, H, eta)


def test_observed_variables_come_last_in_a_small_set():
    rng = np.random.default_rng(1)
    bf = BlockFactor()
    n = 40
    bf.update(new_dims=[3] * n, new_factors=[(np.array([[0]]), rng.normal(size=(1, 4, 4)))] +
              [(np.array([[i - 1, i]]), rng.normal(size=(1, 6, 7))) for i in range(1, n)])
    # a new variable tied to 35 and 39: the affected set (their paths to the root and the new
    # variable) is ordered with the three observed variables last
    bf.update(new_dims=[3], new_factors=[(np.array([[35, n], [n - 1, n]]), rng.normal(size=(2, 3, 7)))])
    assert 3 < bf.last.columns <= MAX_SMALL and not bf.last.batch
    assert set(bf.ordering()[-3:].tolist()) == {35, n - 1, n}
    H, eta = check_exact(bf)
    check_solution(bf, H, eta)


def test_small_sets_are_ordered_without_gtsam(monkeypatch):
    def refuse(*args, **kwargs):
        raise AssertionError("GTSAM's COLAMD was called for a small set")

    p = RandomProblem(8, dims=(6,))
    for _ in range(12):
        p.add_pose()
    monkeypatch.setattr(gtsam.Ordering, "ColamdConstrainedLastSymbolicFactorGraph", refuse)
    monkeypatch.setattr(gtsam.Ordering, "ColamdSymbolicFactorGraph", refuse)
    sizes = []
    for step in range(30):
        p.add_pose(loops=int(step % 4 == 0))
        sizes.append(p.bf.last.columns)
    assert max(sizes) > 3  # some sets needed an ordering
    H, eta = check_exact(p.bf)
    check_solution(p.bf, H, eta)


@pytest.mark.parametrize("max_small", [3, MAX_SMALL, WORD])
def test_both_orderings_keep_the_factor_exact(max_small):
    p = RandomProblem(9)
    p.bf.max_small = max_small
    for step in range(50):
        p.add_pose(loops=int(p.rng.random() < 0.4))
        if step % 6 == 5:
            p.relinearize(3)
    H, eta = check_exact(p.bf)
    check_solution(p.bf, H, eta)


@pytest.mark.parametrize("N,o,D", [(150, 0, 12), (200, 3, 70), (97, 10, 64), (130, 0, 100)])
def test_blas_trailing_update_equals_the_compiled_loops(N, o, D):
    from lie_factors.incremental.fronts import BLAS_TILE, eliminate_columns

    # whole tiles, a partial last tile, and blocks wide enough that the tiles shrink below
    # BLAS_TILE: the same [R | T | d] and update matrix as the row-by-row loops
    rng = np.random.default_rng(N + D)
    A = rng.normal(size=(N + 5, N))
    Phi = np.triu(A.T @ A)
    Phi[N - 1, :N - 1] = np.diag(Phi)[:N - 1]
    if o:  # the first o scalars eliminated already, as in a clique's later member
        eliminate_columns(Phi, 0, o, False, np.empty(2 * N * N), np.empty(BLAS_TILE ** 2))
    loops, blas = Phi.copy(), Phi.copy()
    assert eliminate_columns(loops, o, D, False, np.empty(2 * N * N), np.empty(BLAS_TILE ** 2)) == -1
    assert eliminate_columns(blas, o, D, True, np.empty(2 * N * N), np.empty(BLAS_TILE ** 2)) == -1
    upper = np.triu_indices(N)
    scale = np.max(np.abs(loops[upper]))
    assert np.max(np.abs(blas[upper] - loops[upper])) <= 1e-12 * scale


@pytest.mark.parametrize("w, refused", [(1e-14, True), (1e-12, False)])
def test_a_pivot_is_compared_with_the_diagonal_of_lambda_not_with_the_fronts(w, refused):
    """Scalars a, c, b (eliminated in that order) with factors a − b and c − b of one unit row
    each and a prior √w·a: Λ = [[1 + w, 0, −1], [0, 1, −1], [−1, −1, 2]].  b's front holds only
    what its children pass up, (1 − 1/(1 + w)) + (1 − 1) = w/(1 + w): its pivot is all of
    that, but only w/(2(1 + w)) of Λ_bb = 2, the diagonal before elimination.  The pivot rule
    compares with Λ_bb, as CHOLMOD's does: w = 1e-14 is refused (20 times past 1e-13), w =
    1e-12 is not (5 times inside), rounding (about 2e-16) deciding neither."""
    bf = BlockFactor()
    between = (np.array([[0, 2], [1, 2]]), np.array([[[1.0, -1.0, 0.0]], [[1.0, -1.0, 0.0]]]))
    prior = (np.array([[0]]), np.array([[[np.sqrt(w), 0.0]]]))
    update = lambda: bf.update(new_dims=[1, 1, 1], new_factors=[between, prior])  # noqa: E731
    if refused:
        with pytest.raises(IndeterminantLinearSystem) as info:
            update()
        assert info.value.variable == 2 and bf.nv == 0
        return
    update()
    assert bf.ordering().tolist() == [0, 1, 2]
    assert bf.tree.parent[:3].tolist() == [2, 2, -1] and bf.tree.nchild[2] == 2  # b: a front of its own
    H, eta = check_exact(bf)
    np.testing.assert_allclose(H, [[1 + w, 0, -1], [0, 1, -1], [-1, -1, 2]], rtol=1e-15, atol=1e-15)
