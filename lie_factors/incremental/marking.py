"""Which columns an update re-eliminates, and the graph they are ordered on (compiled kernels).

An update re-eliminates the variables of its new factors, the row subtrees of
the relinearized variables, the ancestors of all of those, and the clique
members below them that keep no update matrix (:func:`mark_affected`); the
subtrees hanging from that set (the *orphans*) enter through their update
matrices.  The set is ordered by constrained COLAMD on the graph of
:func:`ordering_graph`.  Structures: :mod:`lie_factors.incremental.structures`.
"""

from __future__ import annotations

import numpy as np

from ..kernels.jit import inline_kernel, kernel
from .structures import push


@kernel
def _has(ipool, start, length, v):
    for q in range(start, start + length):
        if ipool[q] == v:
            return True
    return False


@inline_kernel
def _take(ids, flag, out, na):
    """Append the variables ``ids`` not yet flagged to ``out[:na]``, flagged; returns the new count."""
    for q in range(ids.shape[0]):
        j = ids[q]
        if flag[j] == 0:
            flag[j] = 1
            out[na] = j
            na += 1
    return na


@inline_kernel
def _row_subtrees(relin, first, nxt, sep_start, sep_len, ipool, flag, out, na):
    """Mark the nodes whose separator holds a relinearized variable (its row subtree, ISAM2's
    ``findAll``): every column the variable's factors reach.  Returns the new count."""
    stack = np.empty(16, dtype=np.int64)
    for q in range(relin.shape[0]):
        r = relin[q]
        top = 0
        c = first[r]
        while c >= 0:
            stack = push(stack, top, c)
            top += 1
            c = nxt[c]
        while top > 0:
            top -= 1
            j = stack[top]
            if not _has(ipool, sep_start[j], sep_len[j], r):
                continue
            if flag[j] == 0:
                flag[j] = 1
                out[na] = j
                na += 1
            c = first[j]
            while c >= 0:
                stack = push(stack, top, c)
                top += 1
                c = nxt[c]
    return na


@inline_kernel
def _ancestors(parent, flag, out, na):
    """Mark every ancestor of the nodes ``out[:na]``; returns the new count."""
    n0 = na
    for q in range(n0):
        j = parent[out[q]]
        while j >= 0 and flag[j] == 0:
            flag[j] = 1
            out[na] = j
            na += 1
            j = parent[j]
    return na


@inline_kernel
def _clique_members_below(first, nchild, ustart, flag, out, na):
    """Mark the only child of a marked node when it keeps no update matrix (the two share a
    clique: the parent cannot be re-eliminated without it), down the chain; returns the count."""
    q = 0
    while q < na:
        p = out[q]
        q += 1
        if nchild[p] == 1:
            c = first[p]
            if flag[c] == 0 and ustart[c] < 0:
                flag[c] = 1
                out[na] = c
                na += 1
    return na


@kernel
def mark_affected(marked, relin, tree, ipool, flag, out_affected, out_orphans):
    """The variables to re-eliminate and the subtrees hanging from them.

    ``marked`` (M,): variables of new factors (and new variables); ``relin`` (Q,):
    relinearized variables, whose every factor changes: the nodes whose
    separator holds one are marked too.  Then every ancestor of a marked node,
    and the only child of an affected node when it keeps no update matrix.
    ``flag`` (V,) zero on entry, zero on return.  Writes ``out_affected`` and
    ``out_orphans`` (the unmarked children of marked nodes); returns their counts.
    """
    first = tree.first
    nxt = tree.nxt
    parent = tree.parent
    na = _row_subtrees(relin, first, nxt, tree.sep_start, tree.sep_len, ipool, flag, out_affected, 0)
    na = _take(marked, flag, out_affected, na)
    na = _take(relin, flag, out_affected, na)
    na = _ancestors(parent, flag, out_affected, na)
    na = _clique_members_below(first, tree.nchild, tree.ustart, flag, out_affected, na)
    no = 0
    for q in range(na):
        c = first[out_affected[q]]
        while c >= 0:
            if flag[c] == 0:
                out_orphans[no] = c
                no += 1
            c = nxt[c]
    for q in range(na):
        flag[out_affected[q]] = 0
    return na, no


@inline_kernel
def _factors_inside(affected, store, flag, stamp, out_ptr, out_vars):
    """The factors whose variables are all affected (``flag`` 1), each once (``store.fstamp``
    set to ``stamp``), appended as lists; their variables flagged 2.  Returns (lists, entries)."""
    afac = store.afac
    ahead = store.ahead
    anext = store.anext
    fnv = store.fnv
    fstamp = store.fstamp
    fvars = store.fvars
    fvstart = store.fvstart
    n = 0
    m = 0
    for q in range(affected.shape[0]):
        e = ahead[affected[q]]
        while e >= 0:
            f = afac[e]
            e = anext[e]
            if fstamp[f] == stamp:
                continue
            fstamp[f] = stamp
            inside = True
            for t in range(fvstart[f], fvstart[f] + fnv[f]):
                if flag[fvars[t]] == 0:
                    inside = False
                    break
            if not inside:
                continue
            for t in range(fvstart[f], fvstart[f] + fnv[f]):
                out_vars[m] = fvars[t]
                flag[fvars[t]] = 2
                m += 1
            n += 1
            out_ptr[n] = m
    return n, m


@kernel
def ordering_graph(affected, orphans, store, tree, ipool, flag, stamp, out_ptr, out_vars):
    """The graph the affected variables are ordered on: every factor whose variables are all
    affected, every orphan's separator (a clique), and each affected variable in neither alone.
    Lists in ``out_ptr``/``out_vars`` (CSR); returns (lists, entries).  ``flag`` (V,) zero on
    entry and return; ``store.fstamp`` holds factor stamps below ``stamp``."""
    sep_len = tree.sep_len
    sep_start = tree.sep_start
    for q in range(affected.shape[0]):
        flag[affected[q]] = 1
    out_ptr[0] = 0
    n, m = _factors_inside(affected, store, flag, stamp, out_ptr, out_vars)
    for q in range(orphans.shape[0]):
        o = orphans[q]
        for t in range(sep_start[o], sep_start[o] + sep_len[o]):
            out_vars[m] = ipool[t]
            flag[ipool[t]] = 2
            m += 1
        n += 1
        out_ptr[n] = m
    # a variable in none of those still needs its column
    for q in range(affected.shape[0]):
        v = affected[q]
        if flag[v] == 1:
            out_vars[m] = v
            m += 1
            n += 1
            out_ptr[n] = m
        flag[v] = 0
    return n, m


@kernel
def marked_among(affected, observed, flag):
    """The variables of ``affected`` that are in ``observed`` (repeats allowed), once each, in
    the order of ``affected``.  ``flag`` (V,) zero on entry and return."""
    for q in range(observed.shape[0]):
        flag[observed[q]] = 1
    n = 0
    for q in range(affected.shape[0]):
        if flag[affected[q]] == 1:
            n += 1
    out = np.empty(n, dtype=np.int64)
    n = 0
    for q in range(affected.shape[0]):
        if flag[affected[q]] == 1:
            out[n] = affected[q]
            n += 1
    for q in range(observed.shape[0]):
        flag[observed[q]] = 0
    return out


@kernel
def factors_of(variables, store, nf):
    """The factors on any of ``variables``, each once, in increasing order (of the first ``nf``)."""
    afac = store.afac
    ahead = store.ahead
    anext = store.anext
    seen = np.zeros(nf, dtype=np.uint8)
    n = 0
    for q in range(variables.shape[0]):
        e = ahead[variables[q]]
        while e >= 0:
            f = afac[e]
            if seen[f] == 0:
                seen[f] = 1
                n += 1
            e = anext[e]
    out = np.empty(n, dtype=np.int64)
    k = 0
    for f in range(nf):
        if seen[f]:
            out[k] = f
            k += 1
    return out
