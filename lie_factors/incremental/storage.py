"""Storing variables and factors in the block factor, and compacting its pools (compiled kernels).

Structures: :mod:`lie_factors.incremental.structures`.
"""

from __future__ import annotations

import numpy as np

from ..kernels.jit import inline_kernel, kernel
from ..kernels.sort import argsort
from .structures import packed


@kernel
def init_variables(nv0, dims, ns0, tree, ahead, delta):
    """Variables nv0, nv0 + 1, … of dimensions ``dims``: no node yet, no factor (``ahead``),
    δ = 0, scalar offsets from ``ns0``; returns the new scalar count."""
    cond = tree.cond
    dim = tree.dim
    first = tree.first
    nchild = tree.nchild
    nxt = tree.nxt
    parent = tree.parent
    sep_dim = tree.sep_dim
    sep_len = tree.sep_len
    ustart = tree.ustart
    voff = tree.voff
    o = ns0
    for q in range(dims.shape[0]):
        j = nv0 + q
        dim[j] = dims[q]
        voff[j] = o
        for i in range(dims[q]):
            delta[o + i] = 0.0
        o += dims[q]
        parent[j] = -1
        first[j] = -1
        nxt[j] = -1
        nchild[j] = 0
        sep_len[j] = 0
        sep_dim[j] = 0
        cond[j] = -1
        ustart[j] = -1
        ahead[j] = -1
    return o


@kernel
def append_factors(fv, J, fids, counts, store):
    """Factors ``fids`` (F,) on the variables ``fv`` (F, k) with Jacobians ``J`` (F, r, D + 1),
    stored from entry ``counts`` = (nfv, njac) of ``store.fvars`` and ``store.jac``."""
    fcols = store.fcols
    fjstart = store.fjstart
    fnv = store.fnv
    frows = store.frows
    fstamp = store.fstamp
    fvars = store.fvars
    fvstart = store.fvstart
    jac = store.jac
    nfv, njac = counts
    F, k = fv.shape
    r, D1 = J.shape[1], J.shape[2]
    for q in range(F):
        f = fids[q]
        fnv[f] = k
        fvstart[f] = nfv + q * k
        for t in range(k):
            fvars[nfv + q * k + t] = fv[q, t]
        frows[f] = r
        fcols[f] = D1
        fjstart[f] = njac + q * r * D1
        for a in range(r):
            for b in range(D1):
                jac[njac + q * r * D1 + a * D1 + b] = J[q, a, b]
        fstamp[f] = 0


@kernel
def link_adjacency(store, f0, f1):
    """Prepend factors f0..f1-1 to their variables' adjacency lists (entry t of ``fvars`` is entry t)."""
    afac = store.afac
    ahead = store.ahead
    anext = store.anext
    fnv = store.fnv
    fvars = store.fvars
    fvstart = store.fvstart
    for f in range(f0, f1):
        for t in range(fvstart[f], fvstart[f] + fnv[f]):
            v = fvars[t]
            afac[t] = f
            anext[t] = ahead[v]
            ahead[v] = t


@kernel
def unlink_factors(fids, store, slots, old):
    """Take the factors ``fids`` out of their variables' adjacency lists (the lists keep their
    order).  Each entry taken out changes one slot: ``ahead[v]`` (recorded as −1 − v) or
    ``anext[p]`` of the entry before it (recorded as p); ``slots``/``old`` (Σ fnv,) receive the
    slots and their old values in the order changed, for :func:`relink`.  Returns the count."""
    ahead = store.ahead
    anext = store.anext
    fnv = store.fnv
    fvars = store.fvars
    fvstart = store.fvstart
    n = 0
    for q in range(fids.shape[0]):
        f = fids[q]
        for t in range(fvstart[f], fvstart[f] + fnv[f]):
            v = fvars[t]
            if ahead[v] == t:
                slots[n] = -1 - v
                ahead[v] = anext[t]
            else:
                p = ahead[v]
                while anext[p] != t:
                    p = anext[p]
                slots[n] = p
                anext[p] = anext[t]
            old[n] = t
            n += 1
    return n


@kernel
def relink(slots, old, n, store):
    """Undo :func:`unlink_factors`: its ``n`` changes put back, the last first."""
    ahead = store.ahead
    anext = store.anext
    for q in range(n - 1, -1, -1):
        s = slots[q]
        if s < 0:
            ahead[-1 - s] = old[q]
        else:
            anext[s] = old[q]


@kernel
def clear_nodes(vs, dead, tree, delta, stats):
    """Take the nodes of the variables ``vs`` (flagged in ``dead``, which no factor and no
    separator of a live node holds any more) out of the tree: out of the roots' list and out
    of a live parent's children, their pool entries counted as freed (``stats[4:6]``, as a
    re-elimination counts them), no node, δ = 0."""
    nxt = tree.nxt
    roots = tree.roots
    first = tree.first
    nchild = tree.nchild
    parent = tree.parent
    for q in range(vs.shape[0]):
        v = vs[q]
        p = parent[v]
        if p < 0 or dead[p]:
            continue
        prev = -1
        c = first[p]
        while c >= 0 and c != v:
            prev = c
            c = nxt[c]
        if c == v:
            if prev < 0:
                first[p] = nxt[v]
            else:
                nxt[prev] = nxt[v]
            nchild[p] -= 1
    prev = -1
    r = roots[0]
    while r >= 0:
        following = nxt[r]
        if dead[r]:
            if prev < 0:
                roots[0] = following
            else:
                nxt[prev] = following
        else:
            prev = r
        r = following
    cond = tree.cond
    dim = tree.dim
    sep_dim = tree.sep_dim
    sep_len = tree.sep_len
    ustart = tree.ustart
    voff = tree.voff
    for q in range(vs.shape[0]):
        v = vs[q]
        d = dim[v]
        if cond[v] >= 0:
            stats[4] += d * (d + sep_dim[v] + 1)
            stats[5] += sep_len[v]
        if ustart[v] >= 0:
            stats[4] += packed(sep_dim[v] + 1)
        cond[v] = -1
        ustart[v] = -1
        sep_len[v] = 0
        sep_dim[v] = 0
        parent[v] = -1
        first[v] = -1
        nxt[v] = -1
        nchild[v] = 0
        for i in range(d):
            delta[voff[v] + i] = 0.0


@kernel
def _move_down(pool, segments, starts, sizes, order):
    """Move the segments of ``pool`` (``starts``, ``sizes``) down to be contiguous, in order of
    address (each moves to where it is or below, over entries already moved or freed);
    ``segments[k]`` receives segment k's new start.  Returns the new top."""
    top = 0
    for q in range(order.shape[0]):
        k = order[q]
        s0 = starts[k]
        for t in range(sizes[k]):
            pool[top + t] = pool[s0 + t]
        segments[k] = top
        top += sizes[k]
    return top


@inline_kernel
def _compact_separators(nv, tree, ipool):
    """Move every live separator down over the freed entries of ``ipool``; returns the new top."""
    cond = tree.cond
    sep_len = tree.sep_len
    sep_start = tree.sep_start
    starts = np.empty(nv, dtype=np.int64)
    sizes = np.empty(nv, dtype=np.int64)
    nodes = np.empty(nv, dtype=np.int64)
    n = 0
    for j in range(nv):
        if cond[j] >= 0 and sep_len[j] > 0:
            starts[n] = sep_start[j]
            sizes[n] = sep_len[j]
            nodes[n] = j
            n += 1
    moved = np.empty(n, dtype=np.int64)
    it = _move_down(ipool, moved, starts[:n], sizes[:n], argsort(starts[:n]))
    for k in range(n):
        sep_start[nodes[k]] = moved[k]
    return it


@inline_kernel
def _compact_floats(nv, tree, fpool):
    """Move every conditional and update matrix down over the freed entries of ``fpool``;
    returns the new top."""
    cond = tree.cond
    dim = tree.dim
    sep_dim = tree.sep_dim
    ustart = tree.ustart
    starts = np.empty(2 * nv, dtype=np.int64)
    sizes = np.empty(2 * nv, dtype=np.int64)
    nodes = np.empty(2 * nv, dtype=np.int64)
    n = 0
    for j in range(nv):
        s = sep_dim[j]
        if cond[j] >= 0:
            starts[n] = cond[j]
            sizes[n] = dim[j] * (dim[j] + s + 1)
            nodes[n] = j
            n += 1
        if ustart[j] >= 0:
            starts[n] = ustart[j]
            sizes[n] = packed(s + 1)
            nodes[n] = -1 - j
            n += 1
    moved = np.empty(n, dtype=np.int64)
    ft = _move_down(fpool, moved, starts[:n], sizes[:n], argsort(starts[:n]))
    for k in range(n):
        j = nodes[k]
        if j >= 0:
            cond[j] = moved[k]
        else:
            ustart[-1 - j] = moved[k]
    return ft


@kernel
def compact_pools(nv, tree, pools):
    """Move every node's separator, conditional and update matrix down over the freed entries of
    the pools, in place, and point the node there; returns the new tops."""
    fpool = pools.fpool
    ipool = pools.ipool
    return _compact_separators(nv, tree, ipool), _compact_floats(nv, tree, fpool)
