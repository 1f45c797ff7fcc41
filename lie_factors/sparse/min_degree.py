"""The minimum-degree ordering of a small graph, in compiled code: the elimination order of a small
problem's whole solve (:mod:`lie_factors.batch.small_kernels`), computed inside that solve.

The rule is the exact one of Tinney and Walker's scheme 2, on Rose's elimination graphs: eliminate
the vertex with the fewest neighbours in the current graph (ties: the lowest index), and join its
neighbours into a clique, the fill its elimination makes.  It is held as a dense adjacency matrix,
O(V² + Σ d²) for V vertices of degree d when eliminated: meant for the few hundred variables of a
small problem, where handing the graph to an approximate minimum degree (AMD) outside compiled
code costs more than ordering it here.  On a forest it eliminates leaves first, so it adds no fill.
"""

from __future__ import annotations

import numpy as np

from ..kernels.jit import kernel

__all__ = ["minimum_degree"]


@kernel
def minimum_degree(V, pairs):
    """Each vertex's elimination position (V,) int64, for the graph on vertices 0 … V−1 whose edges
    are the rows of ``pairs`` (Q, 2) int64 (a vertex paired with itself and repeated pairs add
    nothing)."""
    adj = np.zeros((V, V), dtype=np.bool_)
    degree = np.zeros(V, dtype=np.int64)
    for t in range(pairs.shape[0]):
        a, b = pairs[t, 0], pairs[t, 1]
        if a != b and not adj[a, b]:
            adj[a, b] = adj[b, a] = True
            degree[a] += 1
            degree[b] += 1
    alive = np.ones(V, dtype=np.bool_)
    position = np.empty(V, dtype=np.int64)
    neighbours = np.empty(V, dtype=np.int64)
    for step in range(V):
        v = -1
        for u in range(V):
            if alive[u] and (v < 0 or degree[u] < degree[v]):
                v = u
        position[v] = step
        alive[v] = False
        k = 0
        for u in range(V):
            if alive[u] and adj[v, u]:
                neighbours[k] = u
                k += 1
                degree[u] -= 1
        for i in range(k):
            a = neighbours[i]
            for j in range(i + 1, k):
                b = neighbours[j]
                if not adj[a, b]:
                    adj[a, b] = adj[b, a] = True
                    degree[a] += 1
                    degree[b] += 1
    return position
