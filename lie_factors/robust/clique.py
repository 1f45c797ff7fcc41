"""Maximum clique of a consistency graph, through a minimum vertex cover of its complement.

Pairwise consistency maximization keeps the largest set of loop closures that
are pairwise consistent: a maximum clique of the graph whose edges are the
consistent pairs.  That graph is dense (most pairs of true closures agree, and
pairs too far apart to be tested count as consistent), while its complement —
the *inconsistent* pairs — is sparse and local.  A set is a clique of the first
exactly when it is an independent set of the second, and the largest
independent set is the complement of a minimum vertex cover.  So this module
solves minimum vertex cover on the inconsistency graph:

* reductions that keep optimality: an isolated vertex is never in the cover; a
  vertex of degree one puts its neighbour in the cover (some minimum cover
  does); a vertex whose neighbourhood is all in the cover is dropped;
* the graph splits into connected components, each solved alone;
* branch and bound on a vertex v of maximum degree: either v is in the cover,
  or all of N(v) is; the bound is the size of a greedy maximal matching (every
  cover takes one end of each matched edge).

Each component has a budget of branch nodes; one that exceeds it returns the
best cover found so far (still a cover, so what is kept is still a clique, just
possibly not the largest), and the result says the solve was not exact.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["CoverResult", "minimum_vertex_cover", "maximum_clique_complement"]

#: Branch nodes per component before the best cover so far is returned.
NODE_BUDGET = 20_000

#: Deepest branching before the search gives up on a component (Python's stack).
MAX_DEPTH = 300


@dataclass
class CoverResult:
    """``cover`` (sorted int64): the vertices removed; ``exact``: every component was solved to
    optimality; ``nodes``: branch nodes visited."""

    cover: np.ndarray
    exact: bool
    nodes: int


def _reduce(adj: dict[int, set], cover: set) -> None:
    """Apply the degree-0 and degree-1 rules until none applies (in place)."""
    stack = [v for v, nb in adj.items() if len(nb) <= 1]
    while stack:
        v = stack.pop()
        nb = adj.get(v)
        if nb is None:
            continue
        if len(nb) == 0:
            del adj[v]
        elif len(nb) == 1:
            (u,) = nb
            cover.add(u)
            for w in adj.pop(u):
                adj[w].discard(u)
                if len(adj[w]) <= 1:
                    stack.append(w)
            adj.pop(v, None)


def _remove(adj: dict[int, set], vertices) -> dict[int, set]:
    """A copy of ``adj`` without ``vertices``."""
    gone = set(vertices)
    return {v: nb - gone for v, nb in adj.items() if v not in gone}


def _components(adj: dict[int, set]) -> list[dict[int, set]]:
    seen: set = set()
    out = []
    for s in adj:
        if s in seen:
            continue
        comp = [s]
        seen.add(s)
        i = 0
        while i < len(comp):
            for w in adj[comp[i]]:
                if w not in seen:
                    seen.add(w)
                    comp.append(w)
            i += 1
        out.append({v: adj[v] for v in comp})
    return out


def _matching_bound(adj: dict[int, set]) -> int:
    used: set = set()
    size = 0
    for v, nb in adj.items():
        if v in used:
            continue
        for u in nb:
            if u not in used:
                used.add(u)
                used.add(v)
                size += 1
                break
    return size


def _greedy(adj: dict[int, set]) -> set:
    """A cover: repeatedly take a vertex of maximum degree (after the exact reductions)."""
    adj = {v: set(nb) for v, nb in adj.items()}
    cover: set = set()
    while True:
        _reduce(adj, cover)
        if not adj:
            return cover
        v = max(adj, key=lambda x: len(adj[x]))
        cover.add(v)
        for w in adj.pop(v):
            adj[w].discard(v)


class _Search:
    def __init__(self, budget: int):
        self.budget = budget
        self.nodes = 0
        self.exhausted = False

    def solve(self, adj: dict[int, set], upper: int, depth: int = 0) -> set | None:
        """A minimum cover of ``adj`` if one smaller than ``upper`` exists, else None."""
        self.nodes += 1
        if self.nodes > self.budget or depth > MAX_DEPTH:
            self.exhausted = True
            return None
        adj = {v: set(nb) for v, nb in adj.items()}
        forced: set = set()
        _reduce(adj, forced)
        if len(forced) >= upper:
            return None
        if not adj:
            return forced
        best = None
        budget = upper - len(forced)
        total: set = set()
        comps = _components(adj)
        # Components are independent: solve each to optimality, the bound shared by what is left.
        lower = [_matching_bound(c) for c in comps]
        rest = sum(lower)
        if rest >= budget:
            return None
        for c, lb in zip(comps, lower):
            rest -= lb
            sub = self._branch(c, budget - len(total) - rest, depth)
            if sub is None:
                return None
            total |= sub
        best = forced | total
        return best if len(best) < upper else None

    def _branch(self, adj: dict[int, set], upper: int, depth: int) -> set | None:
        if _matching_bound(adj) >= upper:
            return None
        v = max(adj, key=lambda x: (len(adj[x]), -x))
        best = None
        # v in the cover
        with_v = self.solve(_remove(adj, [v]), upper - 1, depth + 1)
        if with_v is not None:
            best = with_v | {v}
            upper = len(best)
        if self.exhausted:
            return best
        # v out of the cover: all its neighbours in
        nb = adj[v]
        if len(nb) < upper:
            without = self.solve(_remove(adj, nb | {v}), upper - len(nb), depth + 1)
            if without is not None:
                best = without | nb
        return best


def minimum_vertex_cover(n: int, edges: np.ndarray, budget: int = NODE_BUDGET) -> CoverResult:
    """A minimum vertex cover of the graph on vertices 0..n−1 with ``edges`` (K, 2) int.

    Exact per connected component within ``budget`` branch nodes (and
    :data:`MAX_DEPTH` levels); a component over budget gets the better of the search's best and the greedy cover.
    """
    edges = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    if edges.size and (edges.min() < 0 or edges.max() >= n):
        raise ValueError(f"edges must join vertices 0..{n - 1}")
    adj: dict[int, set] = {}
    for i, j in edges.tolist():
        if i == j:
            raise ValueError(f"edge ({i}, {j}) is a self-loop")
        adj.setdefault(i, set()).add(j)
        adj.setdefault(j, set()).add(i)
    cover: set = set()
    _reduce(adj, cover)
    exact = True
    nodes = 0
    for comp in _components(adj):
        greedy = _greedy(comp)
        search = _Search(budget)
        found = search.solve(comp, len(greedy))
        nodes += search.nodes
        if search.exhausted:
            exact = False
        cover |= found if found is not None and len(found) < len(greedy) else greedy
    return CoverResult(np.array(sorted(cover), dtype=np.int64), exact, nodes)


def maximum_clique_complement(n: int, inconsistent: np.ndarray, budget: int = NODE_BUDGET):
    """The largest set of vertices 0..n−1 with no pair in ``inconsistent`` (K, 2): a maximum
    clique of the consistency graph.  Returns (kept (sorted int64), :class:`CoverResult`)."""
    res = minimum_vertex_cover(n, inconsistent, budget)
    keep = np.ones(n, dtype=bool)
    keep[res.cover] = False
    return np.flatnonzero(keep), res
