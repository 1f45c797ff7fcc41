"""The elimination order of a small set of affected variables: minimum degree on bit sets (compiled).

An update's affected set is ordered on the graph of
:func:`~lie_factors.incremental.marking.ordering_graph` (the factors inside the
set and the separators of the subtrees hanging below it), the observed
variables last when some are not.  Large sets go to GTSAM's constrained
COLAMD; a set of at most :data:`MAX_SMALL` variables, most of an online
replay's, is ordered here in one compiled call: each variable's neighbours are
one 64-bit word (so the kernel takes up to :data:`WORD` variables), and the exact minimum degree ordering (the variable with the
fewest remaining neighbours next, its neighbours made a clique) costs a few
word operations per variable and neighbour.  Ties go to the variable earliest
in the order so far (new variables last), which keeps the tree's shape where
the degrees do not decide.  A set of at most :data:`SMALL_SET` variables keeps
its order, the observed variables last, with no graph built.
"""

from __future__ import annotations

import numpy as np

from ..kernels.jit import inline_kernel, kernel
from .marking import marked_among, ordering_graph

#: The largest set the kernel can order: its adjacency rows are single 64-bit words.
WORD = 64
#: The largest set ordered here by default.  Up to 32 variables, minimum degree and CCOLAMD
#: leave trees of about the same later work (``benchmarks/incremental_choices.py``: the dense
#: elimination work Σ D·N² of whole replays at most 5 % above CCOLAMD's); with sets of 33 to 64 as
#: well, later updates re-eliminate more on graphs whose affected sets are large (sphere2500:
#: 1.8 times the work of CCOLAMD's trees, city10000: 1.16 times).
MAX_SMALL = 32
#: Sets this small are ordered as they were, the observed variables last (an odometry step:
#: the previous pose and the new one, perhaps the one before), without building a graph
#: (the choice is not worth the graph).
SMALL_SET = 3


def graph_size(nf: int, nfv: int, orphans: int, separator_entries: int, affected: int) -> tuple:
    """(list pointers, entries) the ordering graph of an affected set may need
    (:func:`~lie_factors.incremental.marking.ordering_graph`): a list for each factor and each
    orphan's separator, one for each affected variable, and one pointer past the end."""
    return nf + orphans + 1 + affected, nfv + separator_entries + 1 + affected


_graph_size = inline_kernel(graph_size)


@inline_kernel
def has_graph_room(nf, nfv, orphans, tree, affected, ptr, lists):
    """Whether ``ptr`` and ``lists`` hold the ordering graph of the ``affected`` variables
    over the ``orphans`` (:func:`graph_size`), ``nf`` factors with ``nfv`` entries so far."""
    entries = 0
    for q in range(orphans.shape[0]):
        entries += tree.sep_len[orphans[q]]
    nptr, nout = _graph_size(nf, nfv, orphans.shape[0], entries, affected.shape[0])
    return nptr <= ptr.shape[0] and nout <= lists.shape[0]

_ONE = np.uint64(1)


@inline_kernel
def _popcount(x):
    """Bits set in the uint64 ``x``."""
    x = x - ((x >> np.uint64(1)) & np.uint64(0x5555555555555555))
    x = (x & np.uint64(0x3333333333333333)) + ((x >> np.uint64(2)) & np.uint64(0x3333333333333333))
    x = (x + (x >> np.uint64(4))) & np.uint64(0x0F0F0F0F0F0F0F0F)
    return (x * np.uint64(0x0101010101010101)) >> np.uint64(56)


@inline_kernel
def _adjacency(K, ptr, lists, n, local, adj):
    """``adj[:K]``: each variable's neighbours in the cliques ``lists`` (CSR ``ptr``, ``n`` of
    them; ``local``: a variable's index in the set), itself included."""
    for a in range(K):
        adj[a] = _ONE << np.uint64(a)
    for t in range(n):
        word = np.uint64(0)
        for q in range(ptr[t], ptr[t + 1]):
            word |= _ONE << np.uint64(local[lists[q]])
        for q in range(ptr[t], ptr[t + 1]):
            adj[local[lists[q]]] |= word


@inline_kernel
def _eliminate_in_turn(candidates, remaining, adj, rank, K, out, done):
    """Take the ``candidates`` (a bit set) one by one, the fewest remaining neighbours first
    (ties: the lowest ``rank``), writing their indices to ``out`` from ``done``; returns
    (remaining, done)."""
    while candidates != np.uint64(0):
        best = -1
        best_degree = K + 1
        for a in range(K):
            if (candidates >> np.uint64(a)) & _ONE:
                d = _popcount(adj[a] & remaining)
                if d < best_degree or (d == best_degree and rank[a] < rank[best]):
                    best_degree = d
                    best = a
        bit = _ONE << np.uint64(best)
        nbrs = adj[best] & remaining & ~bit
        for a in range(K):
            if (nbrs >> np.uint64(a)) & _ONE:
                adj[a] |= nbrs
        remaining &= ~bit
        candidates &= ~bit
        out[done] = best
        done += 1
    return remaining, done


@inline_kernel
def _as_they_were(affected, observed, pos, flag, out):
    """``affected`` not in ``observed`` by their positions so far (stable), then those in it,
    in the order of ``affected`` (:func:`~lie_factors.incremental.marking.marked_among`).
    ``flag`` zero on entry and return."""
    last = marked_among(affected, observed, flag)
    rest = np.empty(affected.shape[0] - last.shape[0], dtype=np.int64)
    keys = np.empty_like(rest)
    n = 0
    for q in range(affected.shape[0]):
        if not (last == affected[q]).any():
            rest[n] = affected[q]
            keys[n] = pos[affected[q]]
            n += 1
    for at, q in enumerate(np.argsort(keys, kind="mergesort")):
        out[at] = rest[q]
    for q in range(last.shape[0]):  # (a loop: a slice assignment compiles numba's shape-mismatch message)
        out[n + q] = last[q]


@kernel
def order_small(affected, orphans, observed, store, tree, ipool, flag, stamp, ptr, lists, local, out):
    """The affected variables (at most :data:`WORD`) in elimination order, written to
    ``out``: minimum degree on the graph of :func:`ordering_graph` (scratch ``ptr``/``lists``
    sized as :func:`graph_size` says, ``stamp`` a new factor stamp), the variables in
    ``observed`` (repeats allowed) last when some are not observed; up to :data:`SMALL_SET`,
    as they were (by position) with the observed ones last.  ``flag`` (V,) zero on entry and
    return; ``local`` (V,) scratch."""
    K = affected.shape[0]
    if K <= SMALL_SET:
        _as_they_were(affected, observed, tree.pos, flag, out)
        return
    n, m = ordering_graph(affected, orphans, store, tree, ipool, flag, stamp, ptr, lists)
    for a in range(K):
        local[affected[a]] = a
    adj = np.empty(K, dtype=np.uint64)
    _adjacency(K, ptr, lists, n, local, adj)
    for q in range(observed.shape[0]):
        flag[observed[q]] = 1
    last = np.uint64(0)
    for a in range(K):
        if flag[affected[a]] == 1:
            last |= _ONE << np.uint64(a)
    for q in range(observed.shape[0]):
        flag[observed[q]] = 0
    everything = ~np.uint64(0) if K == 64 else (_ONE << np.uint64(K)) - _ONE
    if last == everything:
        last = np.uint64(0)
    order = np.empty(K, dtype=np.int64)
    rank = np.empty(K, dtype=np.int64)
    pos = tree.pos
    for a in range(K):
        rank[a] = pos[affected[a]]
    remaining, done = _eliminate_in_turn(everything & ~last, everything, adj, rank, K, order, 0)
    _eliminate_in_turn(last, remaining, adj, rank, K, order, done)
    for a in range(K):
        out[a] = affected[order[a]]
