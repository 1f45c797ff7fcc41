"""Graph searches on index arrays: connected components, reachability, spanning trees, sums along a tree.

Nodes are 0 … n−1, edges the pairs ``u[e]``–``v[e]`` (undirected).  Numpy
only: the g2o check and every initializer use these.
"""

from __future__ import annotations

import numpy as np


def components(n: int, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Connected-component label (smallest member) of nodes 0..n-1 joined by edges u–v.

    Hook-and-compress in numpy: each round hooks the larger root under the
    smaller, then jumps pointers until flat; rounds are few (O(log n)).
    """
    parent = np.arange(n)
    while True:
        pu, pv = parent[u], parent[v]
        if (pu == pv).all():
            return parent
        lo, hi = np.minimum(pu, pv), np.maximum(pu, pv)
        np.minimum.at(parent, hi, lo)
        while True:
            pp = parent[parent]
            if (pp == parent).all():
                break
            parent = pp


def reached(n: int, u: np.ndarray, v: np.ndarray, roots: np.ndarray) -> np.ndarray:
    """(n,) bool: the nodes joined to one of ``roots`` by a path of edges."""
    label = components(n, np.asarray(u, dtype=np.int64), np.asarray(v, dtype=np.int64))
    return np.isin(label, label[np.asarray(roots, dtype=np.int64)])


def bfs_tree(n: int, u: np.ndarray, v: np.ndarray, root: int) -> tuple[np.ndarray, np.ndarray]:
    """Breadth-first spanning tree from ``root``: (parent (n,), edge (n,)), −1 where not reached.

    ``parent[root] = root``.  Each node's neighbours are visited in edge order,
    so the tree is the one a queue over per-node adjacency lists built edge by
    edge finds: each node hangs from the first node that reaches it, through
    the first such edge.  Python loop over CSR lists (one step per edge).
    """
    u = np.asarray(u, dtype=np.int64)
    v = np.asarray(v, dtype=np.int64)
    E = len(u)
    src = np.concatenate([u, v])
    eid = np.concatenate([np.arange(E), np.arange(E)])
    order = np.lexsort((eid, src))  # by node, then edge order
    indptr = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(np.bincount(src, minlength=n), out=indptr[1:])
    nbrs = np.concatenate([v, u])[order].tolist()
    via = eid[order].tolist()
    ptr = indptr.tolist()
    parent = [-1] * n
    edge = [-1] * n
    parent[root] = root
    queue = [root]
    for a in queue:  # grows while iterating
        for k in range(ptr[a], ptr[a + 1]):
            b = nbrs[k]
            if parent[b] < 0:
                parent[b] = a
                edge[b] = via[k]
                queue.append(b)
    return np.array(parent, dtype=np.int64), np.array(edge, dtype=np.int64)


def first_spanning_forest(n: int, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(E,) bool: Kruskal's choice over the edges in order with equal weights.

    An edge is taken when it joins two trees of the edges taken before it
    (union–find, path halving); it stops once n − 1 are taken.
    """
    root = list(range(n))

    def find(a):
        while root[a] != a:
            root[a] = root[root[a]]
            a = root[a]
        return a

    taken = np.zeros(len(u), dtype=bool)
    count = 0
    for e, (a, b) in enumerate(zip(np.asarray(u).tolist(), np.asarray(v).tolist())):
        ra, rb = find(a), find(b)
        if ra != rb:
            root[ra] = rb
            taken[e] = True
            count += 1
            if count == n - 1:
                break
    return taken


def along_tree(parent: np.ndarray, step: np.ndarray, root: int, combine) -> tuple[np.ndarray, np.ndarray]:
    """``step`` combined along every tree path from ``root``: (out (n, ...), reached (n,)).

    ``parent`` (n,): each node's parent, ``parent[root] = root``, −1 off the
    tree.  ``out[v] = combine(… combine(step[a₁], step[a₂]) …, step[v])`` for
    the path root → a₁ → a₂ → … → v (the root's own step is not in it;
    ``out[root] = step[root]``); ``combine(upper, lower)`` acts on stacks and
    must be associative.  Pointer jumping: log₂(depth) vectorized rounds
    instead of a walk per node.  ``out`` is meaningless where ``reached`` is
    False.
    """
    nodes = np.arange(parent.size)
    up = np.where(parent < 0, nodes, parent)
    out = np.array(step, copy=True)
    live = (up != root) & (up[up] != up)
    while live.any():
        idx = np.flatnonzero(live)
        hop = up[idx]
        out[idx] = combine(out[hop], out[idx])
        up[idx] = up[hop]
        live[idx] = (up[idx] != root) & (up[up[idx]] != up[idx])
    return out, up == root
