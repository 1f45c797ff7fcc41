"""The minimum-degree ordering of the small path (lie_factors.sparse.min_degree), against a
from-scratch elimination on Python sets: the same order, tie for tie, and no fill on forests."""

from __future__ import annotations

import numpy as np
import pytest

from lie_factors.sparse.min_degree import minimum_degree


def reference_order(V: int, pairs) -> list[int]:
    """Tinney–Walker scheme 2 on Rose's elimination graphs: the vertices in elimination order."""
    adj = {v: set() for v in range(V)}
    for a, b in pairs:
        if a != b:
            adj[a].add(b)
            adj[b].add(a)
    order = []
    while adj:
        v = min(adj, key=lambda u: (len(adj[u]), u))
        nbrs = adj.pop(v)
        for u in nbrs:
            adj[u].discard(v)
            adj[u] |= nbrs - {u}
        order.append(v)
    return order


def fill(V: int, pairs, order) -> int:
    """Edges elimination in ``order`` adds to the graph."""
    adj = {v: set() for v in range(V)}
    for a, b in pairs:
        if a != b:
            adj[a].add(b)
            adj[b].add(a)
    added = 0
    for v in order:
        nbrs = adj.pop(v)
        for u in nbrs:
            adj[u].discard(v)
            new = nbrs - {u} - adj[u]
            added += len(new)
            adj[u] |= new
    return added // 2


def random_graph(rng, V):
    Q = int(rng.integers(0, 3 * V + 1))
    pairs = rng.integers(0, V, size=(Q, 2))
    return np.concatenate([pairs, pairs[: Q // 4]]).astype(np.int64)  # repeats, and self pairs by chance


@pytest.mark.parametrize("seed", range(12))
def test_the_order_is_the_reference_elimination(seed):
    rng = np.random.default_rng(seed)
    V = int(rng.integers(1, 70))
    pairs = random_graph(rng, V)
    position = minimum_degree(V, pairs)
    assert sorted(position.tolist()) == list(range(V))
    assert np.argsort(position).tolist() == reference_order(V, pairs.tolist())


@pytest.mark.parametrize("seed", range(6))
def test_a_forest_is_ordered_without_fill(seed):
    rng = np.random.default_rng(100 + seed)
    V = int(rng.integers(2, 120))
    parent = [int(rng.integers(0, v)) for v in range(1, V)]
    pairs = np.array([(v, p) for v, p in zip(range(1, V), parent) if rng.random() < 0.9], dtype=np.int64)
    pairs = pairs.reshape(-1, 2)
    order = np.argsort(minimum_degree(V, pairs)).tolist()
    assert fill(V, pairs.tolist(), order) == 0


def test_a_star_keeps_its_hub_last():
    """Eliminating a hub of k leaves first would join them all (k(k−1)/2 fill edges)."""
    pairs = np.array([(0, v) for v in range(1, 9)], dtype=np.int64)
    assert fill(9, pairs.tolist(), list(range(9))) == 28
    position = minimum_degree(9, pairs)
    assert position[0] >= 7 and fill(9, pairs.tolist(), np.argsort(position).tolist()) == 0


def test_no_vertices_and_no_edges():
    assert minimum_degree(0, np.zeros((0, 2), np.int64)).shape == (0,)
    assert minimum_degree(3, np.zeros((0, 2), np.int64)).tolist() == [0, 1, 2]
