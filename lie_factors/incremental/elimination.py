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
    r = tree.roots[0]
    kept = -1
    while r >= 0:
        following = tree.nxt[r]
        if aidx[r] < 0:
            tree.nxt[r] = kept
            kept = r
        r = following
    return kept


@inline_kernel
def _commit(order, orphans, new, tree, work):
    """Write the re-eliminated nodes into the tree (counting the pool entries they free in
    ``work.stats[4:6]``), hang the orphans, and link the new roots before the kept ones."""
    kept = _keep_old_roots(tree, work.aidx)
    for q in range(orphans.shape[0]):
        o = orphans[q]
        tree.nxt[o] = work.cnext[o]
        tree.parent[o] = new.orphan_parent[q]
    stats = work.stats
    dim = tree.dim
    for k in range(order.shape[0]):
        j = order[k]
        if tree.cond[j] >= 0:
            stats[4] += dim[j] * (dim[j] + tree.sep_dim[j] + 1)
            stats[5] += tree.sep_len[j]
        if tree.ustart[j] >= 0:
            stats[4] += packed(tree.sep_dim[j] + 1)
        tree.parent[j] = new.parent[k]
        tree.sep_start[j] = new.sep_start[k]
        tree.sep_len[j] = new.sep_len[k]
        tree.sep_dim[j] = new.sep_dim[k]
        tree.cond[j] = new.cond[k]
        tree.ustart[j] = new.ustart[k]
        tree.first[j] = work.chead[j]
        tree.nxt[j] = work.cnext[j]
        tree.nchild[j] = new.nchild[k]
        work.aidx[j] = -1
    r = new.roots[0]
    last = -1
    while r >= 0:
        last = r
        r = tree.nxt[r]
    if last >= 0:
        tree.nxt[last] = kept
        tree.roots[0] = new.roots[0]
    else:
        tree.roots[0] = kept


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
    this many floats (:data:`KEEP_UPDATE`).  ``work.stats`` (7,) += [columns eliminated,
    update matrices extend-added, factors assembled, frontal scalars², pool floats freed, pool
    ints freed, Σ D·N² over fronts].
    """
    new = begin(order, orphans, base, tree, pools.ipool, work)
    status, detail, it, fall = separators(order, new, tree, pools.ipool, itop, store, work)
    if status == OK:
        need = float_room(order, new, tree.dim, work.aidx, keep_update)
        if ftop + need > pools.fpool.shape[0]:
            status = NEED_FLOAT
            detail = ftop + need
    ft = ftop
    if status == OK:
        status, detail, ft = numeric_pass(order, new, fall, tree, pools, ftop, store, work, keep_update)
    if status != OK:
        restore(order, new, tree.pos, work.aidx)
        return status, detail, itop, ftop
    _commit(order, orphans, new, tree, work)
    return OK, 0, it, ft
