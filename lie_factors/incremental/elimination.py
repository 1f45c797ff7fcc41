"""Re-elimination of the columns an update changes (compiled): the symbolic pass, the numeric one, commit.

:func:`reeliminate` runs the symbolic pass (:mod:`lie_factors.incremental.symbolic`:
positions, separators, parents, the room needed), then the numeric one
(:mod:`lie_factors.incremental.fronts`: dense fronts assembled and factored), and
only then writes the new nodes into the tree.  A pool too small, or a pivot that
fails, leaves the tree as it was.  Structures: :mod:`lie_factors.incremental.structures`.
"""

from __future__ import annotations

from ..kernels.jit import dense_kernel, inline_kernel
from .fronts import numeric_pass
from .structures import NEED_FLOAT, OK, packed
from .symbolic import begin, float_room, restore, separators

#: A clique member below the last keeps its update matrix (augmented, packed floats) when it
#: is at most this large (a side of 64): an update that re-eliminates only the members above
#: it then starts from it (an odometry step re-eliminates the newest pose alone, not the
#: whole root clique), at the price of that memory.
KEEP_UPDATE = 64 * 65 // 2


@inline_kernel
def _keep_old_roots(tree, aidx):
    """The old roots that are not re-eliminated, linked through ``tree.nxt`` (reversed);
    returns the first, or −1."""
    nxt = tree.nxt
    roots = tree.roots
    r = roots[0]
    kept = -1
    while r >= 0:
        following = nxt[r]
        if aidx[r] < 0:
            nxt[r] = kept
            kept = r
        r = following
    return kept


@inline_kernel
def _commit(order, orphans, new, tree, work):
    """Write the re-eliminated nodes into the tree (counting the pool entries they free in
    ``work.stats[4:6]``), hang the orphans, and link the new roots before the kept ones."""
    new_cond = new.cond
    new_nchild = new.nchild
    orphan_parent = new.orphan_parent
    new_parent = new.parent
    new_roots = new.roots
    new_sep_dim = new.sep_dim
    new_sep_len = new.sep_len
    new_sep_start = new.sep_start
    new_ustart = new.ustart
    tree_cond = tree.cond
    dim = tree.dim
    first = tree.first
    tree_nchild = tree.nchild
    nxt = tree.nxt
    tree_parent = tree.parent
    tree_roots = tree.roots
    tree_sep_dim = tree.sep_dim
    tree_sep_len = tree.sep_len
    tree_sep_start = tree.sep_start
    tree_ustart = tree.ustart
    aidx = work.aidx
    chead = work.chead
    cnext = work.cnext
    stats = work.stats
    kept = _keep_old_roots(tree, aidx)
    for q in range(orphans.shape[0]):
        o = orphans[q]
        nxt[o] = cnext[o]
        tree_parent[o] = orphan_parent[q]
    for k in range(order.shape[0]):
        j = order[k]
        if tree_cond[j] >= 0:
            stats[4] += dim[j] * (dim[j] + tree_sep_dim[j] + 1)
            stats[5] += tree_sep_len[j]
        if tree_ustart[j] >= 0:
            stats[4] += packed(tree_sep_dim[j] + 1)
        tree_parent[j] = new_parent[k]
        tree_sep_start[j] = new_sep_start[k]
        tree_sep_len[j] = new_sep_len[k]
        tree_sep_dim[j] = new_sep_dim[k]
        tree_cond[j] = new_cond[k]
        tree_ustart[j] = new_ustart[k]
        first[j] = chead[j]
        nxt[j] = cnext[j]
        tree_nchild[j] = new_nchild[k]
        aidx[j] = -1
    r = new_roots[0]
    last = -1
    while r >= 0:
        last = r
        r = nxt[r]
    if last >= 0:
        nxt[last] = kept
        tree_roots[0] = new_roots[0]
    else:
        tree_roots[0] = kept


@dense_kernel
def reeliminate(order, orphans, base, tree, pools, itop, ftop, store, work, keep_update):
    """Re-eliminate the variables ``order`` (in that order, given positions ``base``, ``base`` + 1, …)
    on top of the subtrees ``orphans`` (their update matrices cached).

    New separators, conditionals and update matrices are written past ``itop``/``ftop`` in
    ``pools``; the tree is only written once every variable has been eliminated, so a refusal
    leaves the factor as it was (positions are restored).  Returns (status, detail, new itop,
    new ftop): status :data:`~lie_factors.incremental.structures.OK`;
    ``NEED_INT``/``NEED_FLOAT`` with a pool size to grow to before calling again (the floats
    are counted exactly after the symbolic pass); ``NOT_POSITIVE`` with the variable whose
    pivot failed.  ``work.aidx`` −1 on entry and return; ``work.stamps[0]``: the last mark
    used.  ``keep_update``: a clique member below the last keeps an update matrix of at most
    this many floats (:data:`KEEP_UPDATE`).  ``work.stats`` (8,) += [columns eliminated,
    update matrices extend-added, factors assembled, frontal scalars², pool floats freed, pool
    ints freed, Σ D·N² over fronts, blocks whose trailing update BLAS computed].
    """
    fpool = pools.fpool
    ipool = pools.ipool
    dim = tree.dim
    pos = tree.pos
    aidx = work.aidx
    new = begin(order, orphans, base, tree, ipool, work)
    status, detail, it, fall = separators(order, new, tree, ipool, itop, store, work)
    if status == OK:
        need = float_room(order, new, dim, aidx, keep_update)
        if ftop + need > fpool.shape[0]:
            status = NEED_FLOAT
            detail = ftop + need
    ft = ftop
    if status == OK:
        status, detail, ft = numeric_pass(order, new, fall, tree, pools, ftop, store, work, keep_update)
    if status != OK:
        restore(order, new, pos, aidx)
        return status, detail, itop, ftop
    _commit(order, orphans, new, tree, work)
    return OK, 0, it, ft
