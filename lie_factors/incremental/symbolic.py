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
from .structures import NEED_INT, OK, Columns, packed


@inline_kernel
def begin(order, orphans, base, tree, ipool, work):
    """The variables ``order`` at positions ``base``, ``base`` + 1, … (``work.aidx``: their
    index in ``order``, no children yet), and the orphans hung from the first variable of their
    separator in the new order; returns the :data:`Columns` to fill."""
    pos = tree.pos
    sep_len = tree.sep_len
    sep_start = tree.sep_start
    aidx = work.aidx
    chead = work.chead
    cnext = work.cnext
    K = order.shape[0]
    new = Columns(np.empty(K, dtype=np.int64), np.empty(K, dtype=np.int64), np.empty(K, dtype=np.int64),
                  np.empty(K, dtype=np.int64), np.empty(K, dtype=np.int64), np.empty(K, dtype=np.int64),
                  np.full(K, -1, dtype=np.int64), np.zeros(K, dtype=np.int64), np.empty(K + 1, dtype=np.int64),
                  np.empty(orphans.shape[0], dtype=np.int64), np.full(1, -1, dtype=np.int64))
    for k in range(K):
        j = order[k]
        new.old_pos[k] = pos[j]
        pos[j] = base + k
        aidx[j] = k
        chead[j] = -1
    for q in range(orphans.shape[0]):
        o = orphans[q]
        best = -1
        for t in range(sep_start[o], sep_start[o] + sep_len[o]):
            v = ipool[t]
            if best < 0 or pos[v] < pos[best]:
                best = v
        new.orphan_parent[q] = best
        cnext[o] = chead[best]
        chead[best] = o
        new.nchild[aidx[best]] += 1
    return new


@inline_kernel
def restore(order, new, pos, aidx):
    """Undo :func:`begin`'s positions and indices (a refused re-elimination)."""
    old_pos = new.old_pos
    for k in range(order.shape[0]):
        j = order[k]
        pos[j] = old_pos[k]
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
def _own_factors(j, store, pos, mark, stamp, sbuf, flist, nfall):
    """The factors whose first variable in the order is ``j``, appended to ``flist[:nfall]``,
    and their later variables not yet stamped ``stamp``, stamped and written to ``sbuf`` from
    its start.  Returns (variables written, new ``nfall``)."""
    ahead = store.ahead
    anext = store.anext
    afac = store.afac
    fvstart = store.fvstart
    fnv = store.fnv
    fvars = store.fvars
    ns = 0
    e = ahead[j]
    while e >= 0:
        f = afac[e]
        e = anext[e]
        first_var = True
        for t in range(fvstart[f], fvstart[f] + fnv[f]):
            v = fvars[t]
            if v != j and pos[v] < pos[j]:
                first_var = False
                break
        if not first_var:
            continue
        flist[nfall] = f
        nfall += 1
        for t in range(fvstart[f], fvstart[f] + fnv[f]):
            v = fvars[t]
            if mark[v] != stamp:
                mark[v] = stamp
                sbuf[ns] = v
                ns += 1
    return ns, nfall


@inline_kernel
def _children_separators(j, new, tree, ipool, work, stamp, sbuf, ns):
    """The variables of the separators of ``j``'s children (new ones from ``new``, orphans from
    the tree) not yet stamped, stamped and appended to ``sbuf[:ns]``; returns the new count."""
    new_sep_len = new.sep_len
    new_sep_start = new.sep_start
    tree_sep_len = tree.sep_len
    tree_sep_start = tree.sep_start
    aidx = work.aidx
    chead = work.chead
    cnext = work.cnext
    mark = work.mark
    c = chead[j]
    while c >= 0:
        ci = aidx[c]
        s0 = new_sep_start[ci] if ci >= 0 else tree_sep_start[c]
        sl = new_sep_len[ci] if ci >= 0 else tree_sep_len[c]
        for t in range(s0, s0 + sl):
            v = ipool[t]
            if mark[v] != stamp:
                mark[v] = stamp
                sbuf[ns] = v
                ns += 1
        c = cnext[c]
    return ns


@inline_kernel
def _hang(k, j, p, parent, nchild, aidx, chead, cnext):
    """Variable ``j`` (index ``k``) hangs from ``p``, the first variable of its separator
    (``parent``, ``nchild``: the new columns')."""
    parent[k] = p
    cnext[j] = chead[p]
    chead[p] = j
    nchild[aidx[p]] += 1


@inline_kernel
def separators(order, new, tree, ipool, itop, store, work):
    """Each variable's separator, in order: written to ``ipool`` from ``itop`` and to ``new``
    (start, length, scalars), the variable hung from its first entry.

    Returns (status, detail, new itop, factors): :data:`OK`, or :data:`NEED_INT` with the pool
    size to grow to; ``factors``: the factors each variable assembles, variable ``order[k]``'s
    from ``new.fstart[k]`` to ``new.fstart[k + 1]``.  ``work.stamps[0]`` moves past the stamps used.
    """
    fstart = new.fstart
    nchild = new.nchild
    parent = new.parent
    roots = new.roots
    sep_dim = new.sep_dim
    sep_len = new.sep_len
    sep_start = new.sep_start
    dim = tree.dim
    pos = tree.pos
    aidx = work.aidx
    chead = work.chead
    cnext = work.cnext
    mark = work.mark
    stamps = work.stamps
    K = order.shape[0]
    # sized once, never grown in the loop (see structures): a factor enters once per entry of
    # its variables' adjacency lists at most, and a separator holds a variable once
    flist = np.empty(store.afac.shape[0], dtype=np.int64)
    sbuf = np.empty(dim.shape[0], dtype=np.int64)
    nfall = 0
    status = OK
    detail = 0
    it = itop
    stamp = stamps[0]
    for k in range(K):
        j = order[k]
        stamp += 1
        mark[j] = stamp
        fstart[k] = nfall
        ns, nfall = _own_factors(j, store, pos, mark, stamp, sbuf, flist, nfall)
        ns = _children_separators(j, new, tree, ipool, work, stamp, sbuf, ns)
        _sort_by(pos, sbuf, ns)
        if it + ns > ipool.shape[0]:
            status = NEED_INT
            detail = max(2 * ipool.shape[0], it + ns)
            break
        s = 0
        for q in range(ns):
            ipool[it + q] = sbuf[q]
            s += dim[sbuf[q]]
        sep_start[k] = it
        sep_len[k] = ns
        sep_dim[k] = s
        it += ns
        if ns > 0:
            _hang(k, j, sbuf[0], parent, nchild, aidx, chead, cnext)
        else:  # a new root
            parent[k] = -1
            cnext[j] = roots[0]
            roots[0] = j
    fstart[K] = nfall
    stamps[0] = stamp
    return status, detail, it, flist


@inline_kernel
def float_room(order, new, dim, aidx, keep_update):
    """The floats the numeric pass writes: every conditional, the update matrix of every clique's
    last member and of the members that keep theirs (at most ``keep_update`` floats)."""
    nchild = new.nchild
    parent = new.parent
    sep_dim = new.sep_dim
    sep_len = new.sep_len
    need = 0
    for k in range(order.shape[0]):
        d = dim[order[k]]
        S1 = sep_dim[k] + 1
        need += d * (d + S1)
        p = parent[k]
        top = p < 0 or nchild[aidx[p]] != 1 or sep_len[k] != sep_len[aidx[p]] + 1
        if top or packed(S1) <= keep_update:
            need += packed(S1)
    return need
