"""The block factor's pools: room left after a shortage, and what compactions cost.

The model (:func:`lie_factors.incremental.structures.pool_plan`): after a re-elimination finds
a pool short, the pool holds at least ``room`` × (what is live + what was asked).  The next
shortage then comes only after (room − 1) × live more entries are written, so the entries
compactions move are at most 1 / (room − 1) per entry written, plus the first pool's size.
"""

from __future__ import annotations

import numpy as np
import pytest

from lie_factors.g2o import read_pose_graph
from lie_factors.incremental.replay import replay_arrays
from lie_factors.incremental.smoother import Smoother
from lie_factors.incremental.structures import POOL_ROOM, Pools, pool_plan


@pytest.mark.parametrize("seed", range(4))
def test_a_shortage_leaves_room_for_what_is_asked_and_more(seed):
    rng = np.random.default_rng(seed)
    for _ in range(2000):
        capacity = int(rng.integers(1, 10 ** 6))
        top = int(rng.integers(0, capacity + 1))
        freed = int(rng.integers(0, top + 1))
        size = int(rng.integers(capacity + 1, 3 * capacity + 2))  # what a shortage asks: more than there is
        compact, grown = pool_plan(top, freed, capacity, size)
        assert compact == (freed > top - freed)
        live = top - freed if compact else top
        wanted = live + size - top
        assert grown >= capacity and grown >= wanted  # the retry fits, nothing shrinks
        if grown > capacity:
            assert POOL_ROOM * wanted <= grown < POOL_ROOM * wanted + 1
        else:
            assert capacity >= POOL_ROOM * wanted


def _within_the_model(bf, initial):
    for k, name in enumerate(("ints", "floats")):
        bound = bf.pool_written[k] / (bf.pool_room - 1) + initial[k]
        assert bf.pool_moved[k] <= bound, (name, bf.pool_moved[k], bound)
    # a shortage met without a compaction grows its pool past room × its size (what is asked
    # is more than the pool holds), so those shortages are logarithmic in the pools' growth
    growths = sum(np.log(max(final / first, 1.0)) / np.log(bf.pool_room)
                  for final, first in zip((bf.pools.ipool.shape[0], bf.pools.fpool.shape[0]), initial))
    assert bf.pool_requests <= bf.compactions + growths + 2, (bf.pool_requests, bf.compactions, growths)


@pytest.mark.parametrize("path", ["data/smallGrid3D.g2o", "data/intel.g2o"])
def test_compactions_move_at_most_two_entries_per_entry_written(path):
    s = Smoother()
    initial = (s.bf.pools.ipool.shape[0], s.bf.pools.fpool.shape[0])
    replay_arrays(read_pose_graph(path), s)
    assert s.bf.pool_written.min() > 0
    _within_the_model(s.bf, initial)


def test_pools_that_start_tiny_grow_geometrically():
    s = Smoother()
    s.bf.pools = Pools(np.zeros(8, dtype=np.int64), np.zeros(64))
    replay_arrays(read_pose_graph("data/smallGrid3D.g2o"), s)
    assert s.bf.pools.fpool.shape[0] > 64 * POOL_ROOM ** 10
    _within_the_model(s.bf, (8, 64))
