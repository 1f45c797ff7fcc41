"""The symbolic pass of re-elimination (compiled kernels): new positions, separators, parents, sizes.

Given the order of the variables to re-eliminate and the orphan subtrees below
them (:mod:`lie_factors.incremental.marking`), :func:`begin` gives the
variables their new positions and hangs each orphan from the first variable of
its separator; :func:`separators` finds each variable's separator (its
factors' later variables and its children's separators), writes it to the
int pool and hangs the variable from the first of them; :func:`float_room`
counts the floats the numeric pass will write.  Nothing here touches a node:
the results are held in a :data:`~lie_factors.incremental.structures.Columns`
until the numeric pass has passed every pivot.
"""

from __future__ import annotations

import numpy as np

from ..kernels.jit import inline_kernel, kernel
from .structures import NEED_INT, OK, Columns, packed, push


@inline_kernel
def begin(order, orphans, base, tree, ipool, work):
    """The variables ``order`` at positions ``base``, ``base`` + 1, … (``work.aidx``: their
    index in ``order``, no children yet), and the orphans hung from the first variable of their
    separator in the new order; returns the :data:`Columns` to fill."""
    K = order.shape[0]
    new = Columns(np.empty(K, dtype=np.int64), np.empty(K, dtype=np.int64), np.empty(K, dtype=np.int64),
                  np.empty(K, dtype=np.int64), np.empty(K, dtype=np.int64), np.empty(K, dtype=np.int64),
                  np.full(K, -1, dtype=np.int64), np.zeros(K, dtype=np.int64), np.empty(K + 1, dtype=np.int64),
                  np.empty(orphans.shape[0], dtype=np.int64), np.full(1, -1, dtype=np.int64))
    for k in range(K):
        j = order[k]
        new.old_pos[k] = tree.pos[j]
        tree.pos[j] = base + k
        work.aidx[j] = k
        work.chead[j] = -1
    for q in range(orphans.shape[0]):
        o = orphans[q]
        best = -1
        for t in range(tree.sep_start[o], tree.sep_start[o] + tree.sep_len[o]):
            v = ipool[t]
            if best < 0 or tree.pos[v] < tree.pos[best]:
                best = v
        new.orphan_parent[q] = best
        work.cnext[o] = work.chead[best]
        work.chead[best] = o
        new.nchild[work.aidx[best]] += 1
    return new


@inline_kernel
def restore(order, new, pos, aidx):
    """Undo :func:`begin`'s positions and indices (a refused re-elimination)."""
    for k in range(order.shape[0]):
        j = order[k]
        pos[j] = new.old_pos[k]
        aidx[j] = -1


@kernel
def _sort_by(keys_of, buf, n):
    """Insertion sort of buf[:n] by keys_of[buf[i]] (separators are short)."""
    for i in range(1, n):
        v = buf[i]
        k = keys_of[v]
        t = i - 1
        while t >= 0 and keys_of[buf[t]] > k:
            buf[t + 1] = buf[t]
            t -= 1
        buf[t + 1] = v


@inline_kernel
def _own_factors(j, store, pos, mark, stamp, sep, fall):
    """The factors whose first variable in the order is ``j``, appended to ``fall``, and their
    later variables (not yet stamped ``stamp``) to ``sep``.  ``sep`` and ``fall`` are
    (buffer, count) pairs; returns both, the buffers grown when full."""
    sbuf, ns = sep
    flist, nfall = fall
    e = store.ahead[j]
    while e >= 0:
        f = store.afac[e]
        e = store.anext[e]
        first_var = True
        for t in range(store.fvstart[f], store.fvstart[f] + store.fnv[f]):
            v = store.fvars[t]
            if v != j and pos[v] < pos[j]:
                first_var = False
                break
        if not first_var:
            continue
        flist = push(flist, nfall, f)
        nfall += 1
        for t in range(store.fvstart[f], store.fvstart[f] + store.fnv[f]):
            v = store.fvars[t]
            if mark[v] != stamp:
                mark[v] = stamp
                sbuf = push(sbuf, ns, v)
                ns += 1
    return (sbuf, ns), (flist, nfall)


@inline_kernel
def _children_separators(j, new, tree, ipool, work, stamp, sep):
    """The variables of the separators of ``j``'s children (new ones from ``new``, orphans from
    the tree) not yet stamped, appended to ``sep`` (buffer, count); returns it."""
    sbuf, ns = sep
    c = work.chead[j]
    while c >= 0:
        ci = work.aidx[c]
        s0 = new.sep_start[ci] if ci >= 0 else tree.sep_start[c]
        sl = new.sep_len[ci] if ci >= 0 else tree.sep_len[c]
        for t in range(s0, s0 + sl):
            v = ipool[t]
            if work.mark[v] != stamp:
                work.mark[v] = stamp
                sbuf = push(sbuf, ns, v)
                ns += 1
        c = work.cnext[c]
    return sbuf, ns


@inline_kernel
def _hang(k, j, sbuf, ns, new, work):
    """Variable ``j`` (index ``k``) hangs from the first variable of its separator, or is a new root."""
    if ns > 0:
        p = sbuf[0]
        new.parent[k] = p
        work.cnext[j] = work.chead[p]
        work.chead[p] = j
        new.nchild[work.aidx[p]] += 1
    else:
        new.parent[k] = -1
        work.cnext[j] = new.roots[0]
        new.roots[0] = j


@inline_kernel
def separators(order, new, tree, ipool, itop, store, work):
    """Each variable's separator, in order: written to ``ipool`` from ``itop`` and to ``new``
    (start, length, scalars), the variable hung from its first entry.

    Returns (status, detail, new itop, factors): :data:`OK`, or :data:`NEED_INT` with the pool
    size to grow to; ``factors``: the factors each variable assembles, variable ``order[k]``'s
    from ``new.fstart[k]`` to ``new.fstart[k + 1]``.  ``work.stamps[0]`` moves past the stamps used.
    """
    K = order.shape[0]
    fall = (np.empty(16, dtype=np.int64), 0)
    sbuf = np.empty(64, dtype=np.int64)
    status = OK
    detail = 0
    it = itop
    stamp = work.stamps[0]
    for k in range(K):
        j = order[k]
        stamp += 1
        work.mark[j] = stamp
        new.fstart[k] = fall[1]
        sep, fall = _own_factors(j, store, tree.pos, work.mark, stamp, (sbuf, 0), fall)
        sbuf, ns = _children_separators(j, new, tree, ipool, work, stamp, sep)
        _sort_by(tree.pos, sbuf, ns)
        if it + ns > ipool.shape[0]:
            status = NEED_INT
            detail = max(2 * ipool.shape[0], it + ns)
            break
        s = 0
        for q in range(ns):
            ipool[it + q] = sbuf[q]
            s += tree.dim[sbuf[q]]
        new.sep_start[k] = it
        new.sep_len[k] = ns
        new.sep_dim[k] = s
        it += ns
        _hang(k, j, sbuf, ns, new, work)
    new.fstart[K] = fall[1]
    work.stamps[0] = stamp
    return status, detail, it, fall[0]


@inline_kernel
def float_room(order, new, dim, aidx, keep_update):
    """The floats the numeric pass writes: every conditional, the update matrix of every clique's
    last member and of the members that keep theirs (at most ``keep_update`` floats)."""
    need = 0
    for k in range(order.shape[0]):
        d = dim[order[k]]
        S1 = new.sep_dim[k] + 1
        need += d * (d + S1)
        p = new.parent[k]
        top = p < 0 or new.nchild[aidx[p]] != 1 or new.sep_len[k] != new.sep_len[aidx[p]] + 1
        if top or packed(S1) <= keep_update:
            need += packed(S1)
    return need
