"""The closure tests' compiled quadratic form (lie_factors.robust.leverage) against numpy's dense
solve, its leverage-1 floor straddled, and the online rejection's neighbour search against a
brute-force one."""

from __future__ import annotations

import numpy as np
import pytest

from lie_factors.robust import online
from lie_factors.robust.leverage import SINGULAR, statistics
from lie_factors.robust.tail import GROUP_MAX, GROUP_WINDOW


def _spd(rng, d, top):
    """A symmetric (d, d) matrix with eigenvalues in (0, top], the largest exactly ``top``."""
    Q, _ = np.linalg.qr(rng.normal(size=(d, d)))
    lam = rng.uniform(0.05, 0.9, size=d) * top
    lam[0] = top
    return (Q * lam) @ Q.T


@pytest.mark.parametrize("d", [3, 6, 18])
def test_the_form_is_numpys_dense_solve(d):
    rng = np.random.default_rng(d)
    H = np.stack([_spd(rng, d, 0.7) for _ in range(5)])
    b = rng.normal(size=(5, d))
    signs = np.array([1.0, -1.0, 1.0, -1.0, -1.0])
    T = statistics(H, b, signs)
    for k in range(5):
        ref = b[k] @ np.linalg.solve(np.eye(d) + signs[k] * H[k], b[k])
        assert T[k] == pytest.approx(ref, rel=1e-12)


def test_leverage_one_is_nan_on_the_floors_side_only():
    """I − H with its smallest eigenvalue just above SINGULAR gives a finite T, just at or
    below it NaN (the group alone measures what it measures)."""
    rng = np.random.default_rng(0)
    d = 6
    b = rng.normal(size=(2, d))
    H = np.stack([_spd(rng, d, 1.0 - 2.0 * SINGULAR), _spd(rng, d, 1.0 - 0.5 * SINGULAR)])
    T = statistics(H, b, np.array([-1.0, -1.0]))
    assert np.isfinite(T[0]) and T[0] > 0
    assert np.isnan(T[1])
    # the innovation side (I + H) is never singular
    assert np.all(np.isfinite(statistics(H, b, np.array([1.0, 1.0]))))


def _nearest_brute(keys, among, c):
    lo, hi = keys.min(axis=1), keys.max(axis=1)
    near = []
    for pos, x in enumerate(among):
        if x == c:
            continue
        d = max(abs(lo[x] - lo[c]), abs(hi[x] - hi[c]))
        if d <= GROUP_WINDOW:
            near.append((d, pos, x))
    near.sort()  # by distance, ties in among's order
    return [c] + [x for _, _, x in near][:GROUP_MAX - 1]


@pytest.mark.parametrize("seed", range(6))
def test_nearest_closures_are_a_brute_force_search(seed):
    rng = np.random.default_rng(seed)
    K = 60
    a = rng.integers(0, 40, size=K)
    keys = np.stack([a, a + rng.integers(30, 60, size=K)], axis=1)
    flip = rng.random(K) < 0.5
    keys[flip] = keys[flip][:, ::-1]  # ends in either order
    keys = np.ascontiguousarray(keys, dtype=np.int64)
    among = rng.permutation(K)[:45].astype(np.int64)
    for c in range(K):
        got = online._nearest(keys, among, c, GROUP_WINDOW, GROUP_MAX).tolist()
        assert got == _nearest_brute(keys, among.tolist(), c)
