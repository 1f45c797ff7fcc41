"""The incremental block Cholesky factor of a growing least-squares problem.

``BlockFactor`` holds the linearized factors (whitened Jacobians ``[A | b]``,
one block per variable) and the factor ``L`` of ``Λ = Σ AᵀA`` under an
elimination order, as a tree of block columns
(:mod:`lie_factors.incremental.structures`).  An update adds variables and
factors, replaces the Jacobians of relinearized factors, and re-eliminates
only the columns whose entries change: the variables of the new factors, the
nodes whose separator holds a relinearized variable, and their ancestors (the
top of ISAM2's Bayes tree; Kaess et al., "iSAM2: Incremental smoothing and
mapping using the Bayes tree", IJRR 2012, Alg. 3).  Those columns are ordered
afresh by constrained COLAMD (GTSAM's ``Ordering.ColamdConstrainedLast``,
CCOLAMD; the variables of the new factors last), and the subtrees below them
enter through their cached update matrices.  When they are 65 % of all
variables or more, everything is ordered and eliminated afresh (ISAM2's
batch step).

The solution ``δ = Λ⁻¹ η`` (``η = Σ Aᵀb``) is kept up to date by ISAM2's
wildfire back-substitution, exact when its threshold is 0.

This class is the Python side: it keeps the state, grows it, orders the
columns (GTSAM's CCOLAMD) and calls the compiled kernels once each per update:
:mod:`~lie_factors.incremental.storage` (new variables and factors),
:mod:`~lie_factors.incremental.marking` (the columns that change),
:mod:`~lie_factors.incremental.elimination` (their re-elimination) and
:mod:`~lie_factors.incremental.substitution` (δ, marginals).

Every update is all or nothing: an update that leaves a variable without
information (a pivot that is not positive) raises
:class:`IndeterminantLinearSystem` and the factor is as it was before.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np
from numba import typeof

from ..errors import IndeterminantLinearSystem

from ..kernels.jit import direct, entry_point
from . import array_path, elimination, marking, ordering, storage
from . import structures as st
from .elimination import KEEP_UPDATE
from .marking import marked_among
from .ordering import SMALL_SET
from .storage import compact_pools
from .factor_reading import FactorReading

# The kernels every update calls, through their entry points (:func:`~lie_factors.kernels.jit.direct`):
# their arguments are the structures and arrays allocated here, whose types never change.
init_variables = direct(storage.init_variables)
append_factors = direct(storage.append_factors)
link_adjacency = direct(storage.link_adjacency)
unlink_factors = direct(storage.unlink_factors)
relink = direct(storage.relink)
clear_nodes = direct(storage.clear_nodes)
mark_affected = direct(marking.mark_affected)
ordering_graph = direct(marking.ordering_graph)
order_small = direct(ordering.order_small)
reeliminate = direct(elimination.reeliminate)
#: The array path's kernel, through its entry point for each group (its tag's type differs).
_add_and_reeliminate: dict = {}


#: ISAM2's share of re-eliminated variables from which an update orders and eliminates everything.
BATCH_SHARE = 0.65


@dataclass
class UpdateStats:
    """What one update did: columns re-eliminated (``columns``), orphan subtrees reattached,
    update matrices extend-added, factors assembled, whether everything was reordered."""

    columns: int = 0
    orphans: int = 0
    extend_adds: int = 0
    factors: int = 0
    batch: bool = False

    def add(self, other: "UpdateStats") -> None:
        self.columns += other.columns
        self.orphans += other.orphans
        self.extend_adds += other.extend_adds
        self.factors += other.factors
        self.batch += other.batch


class BlockFactor(FactorReading):
    """Variables with block dimensions, factors as whitened Jacobians, and the incremental factor.

    Variables and factors are numbered from 0 in the order they are added.
    ``keep_update``: the largest update matrix (floats) a clique member below the clique's
    last variable keeps (:data:`~lie_factors.incremental.elimination.KEEP_UPDATE`).

    State (:mod:`lie_factors.incremental.structures`, each a namedtuple of arrays the kernels
    take whole, built again when an array grows): ``tree`` (the nodes), ``store`` (the
    factors), ``pools`` (what the nodes point into, filled to ``itop``/``ftop``), ``work``
    (the kernels' scratch and counts), ``wildfire`` (back-substitution's flags).
    Attributes after an update: ``delta`` (solution, see :meth:`solve`),
    ``last`` (:class:`UpdateStats`), ``totals`` (the sums over all updates).
    """

    def __init__(self, keep_update: int = KEEP_UPDATE):
        self.keep_update = int(keep_update)
        #: sets of at most this many variables are ordered by minimum degree (0: all by CCOLAMD)
        self.max_small = ordering.MAX_SMALL
        self.nv = 0
        self.nf = 0
        self.nscalar = 0
        self.nfv = 0
        self.njac = 0
        self.tree = st.empty_tree()
        self.store = st.empty_store()
        self.work = st.empty_workspace()
        self.wildfire = st.empty_wildfire()
        self.pools = st.Pools(np.empty(1 << 14, dtype=np.int64), np.empty(1 << 18))  # (written before read)
        self.itop = 0
        self.ftop = 0
        self.fstamp_box = 0
        self.next_pos = 0
        self.delta = np.zeros(0)
        #: (F,) factors removed (their ids stay taken); (V,) variables removed (no node, no factor)
        self.fremoved = np.zeros(0, dtype=bool)
        self.vdead = np.zeros(0, dtype=np.uint8)
        self.ndead = 0
        self.last = UpdateStats()
        self.totals = UpdateStats()
        self.updates = 0
        self.compactions = 0
        #: :func:`~lie_factors.incremental.structures.pool_plan`'s room factor
        self.pool_room = st.POOL_ROOM
        #: pool entries (ints, floats) written by re-eliminations and moved by compactions,
        #: and re-eliminations that found a pool short
        self.pool_written = np.zeros(2, dtype=np.int64)
        self.pool_moved = np.zeros(2, dtype=np.int64)
        self.pool_requests = 0
        # scratch reused by every update
        self._marks = np.zeros(0, dtype=np.int64)
        self._graph_ptr = np.zeros(0, dtype=np.int64)
        self._graph_vars = np.zeros(0, dtype=np.int64)

    # ------------------------------------------------------------------ storage
    def _reserve_vars(self, n: int) -> None:
        if self.tree.dim.shape[0] >= n:
            return
        self.tree = st.grown(self.tree, n, st.TREE_FILL)
        self.work = st.grown(self.work, n, st.WORKSPACE_FILL)
        self.wildfire = st.grown(self.wildfire, n, dict.fromkeys(st.Wildfire._fields, 0))
        self.store = self.store._replace(ahead=st.grow(self.store.ahead, n, -1))
        self.vdead = st.grow(self.vdead, n, 0)

    def _reserve_factors(self, n: int, nfv: int, njac: int) -> None:
        store = self.store
        # (each group of fields grows together: its first field's length is the group's room)
        if store.fnv.shape[0] >= n and store.fvars.shape[0] >= nfv and store.jac.shape[0] >= njac:
            return
        if store.fnv.shape[0] < n:
            store = st.grown(store, n, dict.fromkeys(st.FACTOR_FIELDS, 0))
            self.fremoved = st.grow(self.fremoved, store.fnv.shape[0], False)
        store = st.grown(store, nfv, dict.fromkeys(st.ENTRY_FIELDS))
        self.store = store._replace(jac=st.grow(store.jac, njac))

    def _reserve_delta(self, n: int) -> None:
        self.delta = st.grow(self.delta, n, 0.0)

    # ------------------------------------------------------------------ updates
    @property
    def live(self) -> int:
        """Variables that have not been removed."""
        return self.nv - self.ndead

    def update(self, new_dims=(), new_factors=(), refreshed=(), relinearized=(), observed=(), removed=(),
               dead=(), groups=None) -> UpdateStats:
        """Add variables and factors, remove factors and variables, replace Jacobians, and
        re-eliminate what changed.

        ``new_dims`` (P,): dimensions of the new variables (they get the next
        indices).  ``new_factors``: sequence of ``(vars (F, k), jac (F, r, D + 1))``,
        the variables of F factors of k variables each and their whitened
        Jacobians ``[A_1 … A_k | b]`` (D = the sum of the k dimensions), numbered in order;
        or ``(vars, jac, fids)``, numbered ``fids`` (F,): then the update's factors together
        take the ids ``nf, nf + 1, …`` each once.
        ``refreshed``: sequence of ``(factor ids (F,), jac (F, r, D + 1))``:
        new Jacobians of existing factors (relinearized).  ``relinearized``:
        variables whose factors all changed (their row subtrees are
        re-eliminated).  ``observed``: more variables to re-eliminate; the
        variables of the new and removed factors and the new variables are always
        re-eliminated and ordered last.  ``removed``: ids of factors to take out (their
        rows leave Λ; the ids stay taken).  ``dead``: variables to take out, every factor on
        them removed (by this update or before): they leave the tree and the order.
        ``groups`` (nv,): when given, the re-eliminated variables are ordered group by group
        (smaller first), instead of the observed ones last.  Raises
        :class:`IndeterminantLinearSystem` (state unchanged) when a pivot is not positive,
        ``ValueError`` (state unchanged) for a removal that is not one.
        """
        new_dims = np.ascontiguousarray(new_dims, dtype=np.int64).reshape(-1)
        removed = np.ascontiguousarray(removed, dtype=np.int64).reshape(-1)
        dead = np.ascontiguousarray(dead, dtype=np.int64).reshape(-1)
        counts = self.nv, self.nf, self.nfv, self.njac, self.nscalar
        undo = []  # (array, indices, old values) to put back if the update fails
        unlinked = None
        try:
            self._add_variables(new_dims)
            observed_parts = [np.asarray(observed, dtype=np.int64).reshape(-1),
                              np.arange(counts[0], self.nv, dtype=np.int64)]
            observed_parts += self._add_factors(new_factors, undo)
            if removed.size:
                unlinked, touched = self._remove_factors(removed, counts[1], undo)
                observed_parts.append(touched)
            if dead.size:
                self._check_dead(dead)
                undo.append((self.vdead, dead, self.vdead[dead].copy()))
                self.vdead[dead] = 1
            self._refresh(refreshed, undo)
            observed_all = np.concatenate(observed_parts)  # repeats allowed
            relin = np.unique(np.asarray(relinearized, dtype=np.int64).reshape(-1)) if len(relinearized) else \
                np.zeros(0, dtype=np.int64)
            self._reeliminate(observed_all, relin, dead, groups)
        except BaseException:
            if unlinked is not None:
                relink(*unlinked, self.store)
            for array, idx, old in reversed(undo):
                array[idx] = old
            self.nv, self.nf, self.nfv, self.njac, self.nscalar = counts
            raise
        self.ndead += len(dead)
        self.updates += 1
        return self.last

    def _remove_factors(self, fids: np.ndarray, nf0: int, undo: list) -> tuple:
        """Take the factors ``fids`` (ids below ``nf0``, each once, none removed before) out of
        the adjacency lists; returns (what :func:`relink` needs to undo it, their variables)."""
        if fids.min() < 0 or fids.max() >= nf0:
            raise ValueError(f"factor ids must be in [0, {nf0}), got {fids.tolist()}")
        if len(np.unique(fids)) != len(fids) or self.fremoved[fids].any():
            raise ValueError("a factor is removed twice")
        store = self.store
        k = store.fnv[fids]
        touched = np.concatenate([store.fvars[a:a + b] for a, b in zip(store.fvstart[fids].tolist(), k.tolist())]
                                 + [np.zeros(0, dtype=np.int64)])
        slots = np.empty(int(k.sum()), dtype=np.int64)
        old = np.empty_like(slots)
        n = unlink_factors(fids, store, slots, old)
        undo.append((self.fremoved, fids, self.fremoved[fids].copy()))
        self.fremoved[fids] = True
        return (slots, old, n), touched

    def _check_dead(self, dead: np.ndarray) -> None:
        """Variables to take out must be live and have no factor left."""
        if dead.min() < 0 or dead.max() >= self.nv or len(np.unique(dead)) != len(dead):
            raise ValueError(f"variables to remove must be distinct, in [0, {self.nv}), got {dead.tolist()}")
        if self.vdead[dead].any():
            raise ValueError("a variable is removed twice")
        if (self.store.ahead[dead] >= 0).any():
            raise ValueError("a variable to remove still has factors")

    def marginalize(self, leaves: np.ndarray, removed: np.ndarray, new_factors=()) -> None:
        """Take the variables ``leaves`` (a set of whole subtrees of the tree) out with every
        factor on them (``removed``), and add ``new_factors`` (``(vars, jac, fids)`` as
        :meth:`update` takes them: the marginal factors of the subtrees on their separators),
        without re-eliminating anything: the conditionals above already hold what the subtrees
        passed up, which is what the marginal factors carry.  A later re-elimination of a
        separator assembles them instead."""
        leaves = np.ascontiguousarray(leaves, dtype=np.int64)
        removed = np.ascontiguousarray(removed, dtype=np.int64)
        if len(leaves):
            self._check_leaves(leaves)
        counts = self.nv, self.nf, self.nfv, self.njac, self.nscalar
        undo: list = []
        unlinked = None
        try:
            self._add_factors(new_factors, undo)
            if removed.size:
                unlinked, _ = self._remove_factors(removed, counts[1], undo)
            if leaves.size:
                self._check_dead(leaves)
        except BaseException:
            if unlinked is not None:
                relink(*unlinked, self.store)
            for array, idx, old in reversed(undo):
                array[idx] = old
            self.nv, self.nf, self.nfv, self.njac, self.nscalar = counts
            raise
        self.vdead[leaves] = 1
        clear_nodes(leaves, self.vdead, self.tree, self.delta, self.work.stats)
        self.ndead += len(leaves)
        self.wildfire.replaced[leaves] = 0

    def _check_leaves(self, leaves: np.ndarray) -> None:
        """``leaves`` must be whole subtrees: every child of one of them is one of them."""
        inside = np.zeros(self.nv, dtype=bool)
        inside[leaves] = True
        found = st.child_outside(self.tree, leaves.tolist(), inside)
        if found is not None:
            raise ValueError(f"variable {found[0]} is not a leaf: variable {found[1]} below it is not marginalized")

    def update_arrays(self, g, X: np.ndarray, velem: np.ndarray, prep, plan: np.ndarray, sizes: tuple,
                      refreshed=()) -> None:
        """The array path's update (:mod:`~lie_factors.incremental.array_path`): P new variables
        of the group ``g`` (dimension n), E between factors and Q priors of ``prep``, linearized
        at ``X``, marked, ordered and re-eliminated by one compiled call (the ordering of a set
        larger than :data:`~lie_factors.incremental.ordering.MAX_SMALL`, a batch step, pools too
        small or a refused pivot: by :meth:`_reeliminate_set` after it).  ``plan``: as
        :func:`~.array_path.add_and_reeliminate` takes it; ``sizes`` (P, E, Q, n).
        ``refreshed``: the relinearized factors' new Jacobians, as :meth:`update` takes them.
        Raises :class:`IndeterminantLinearSystem` (state unchanged) when a pivot is not positive."""
        P, E, Q, n = sizes
        counts = self.nv, self.nf, self.nfv, self.njac, self.nscalar
        nv = self.nv + P
        self._reserve_vars(nv)
        self._reserve_delta(self.nscalar + P * n)
        self._reserve_factors(self.nf + E + Q, self.nfv + 2 * E + Q, self.njac + n * (E * (2 * n + 1) + Q * (n + 1)))
        if self._marks.shape[0] < 3 * nv:
            self._marks = np.empty(6 * nv + 64, dtype=np.int64)
        observed = plan[E + Q:E + Q + P + 2 * E + Q]
        heads = self.store.ahead[observed]  # a copy: the heads to put back if the update fails
        undo = []
        before = self.work.stats.copy()
        self.fstamp_box += 1
        tops = self.itop, self.ftop
        # (a set of BATCH_SHARE of the variables or more is a batch step: ceil, as the count is whole)
        elimination_counts = (self.next_pos, *tops, self.keep_update, self.fstamp_box,
                              max(SMALL_SET, self.max_small), math.ceil(BATCH_SHARE * (self.live + P)))
        try:
            self._refresh(refreshed, undo)
            entry = _add_and_reeliminate.get(g)
            args = (g, X, velem, prep, plan, np.array(counts + (P, E, Q, n) + elimination_counts, dtype=np.int64),
                    self.tree, self.store, self.delta, self.work, self.pools,
                    (self._marks, self._graph_ptr, self._graph_vars))
            if entry is None:
                entry = _add_and_reeliminate[g] = entry_point(array_path.add_and_reeliminate,
                                                              [typeof(a) for a in args])
            ns, na, no, status, it, ft = entry(*args)
            self.nv, self.nf, self.nfv, self.njac, self.nscalar = nv, self.nf + E + Q, self.nfv + 2 * E + Q, \
                self.njac + n * (E * (2 * n + 1) + Q * (n + 1)), int(ns)
            if status == st.OK:
                self._eliminated(self._marks[2 * nv:2 * nv + na], int(no), before, tops, (int(it), int(ft)))
            else:  # what the call left to the general way, which orders, makes room or refuses
                self.work.stats[:] = before
                self._reeliminate_set(self._marks[:na].copy(), self._marks[nv:nv + no].copy(), observed)
        except BaseException:
            self.store.ahead[observed] = heads
            for array, idx, old in reversed(undo):
                array[idx] = old
            self.nv, self.nf, self.nfv, self.njac, self.nscalar = counts
            raise
        self.updates += 1

    def _add_variables(self, new_dims: np.ndarray) -> None:
        P = new_dims.shape[0]
        if not P:
            return
        self._reserve_vars(self.nv + P)
        self._reserve_delta(self.nscalar + int(new_dims.sum()))
        self.nscalar = init_variables(self.nv, new_dims, self.nscalar, self.tree, self.store.ahead, self.delta)
        self.nv += P

    def _add_factors(self, new_factors, undo: list) -> list:
        """Store the new factors and link them to their variables; returns their variables."""
        nf0 = self.nf
        chunks = []
        for chunk in new_factors:
            fvars = np.ascontiguousarray(chunk[0], dtype=np.int64)
            jac = np.ascontiguousarray(chunk[1], dtype=np.float64)
            if fvars.shape[0]:
                chunks.append((fvars, jac, None if len(chunk) < 3 else np.ascontiguousarray(chunk[2], dtype=np.int64)))
        if not chunks:
            return []
        total = sum(len(c[0]) for c in chunks)
        numbered = [c[2] for c in chunks if c[2] is not None]
        if numbered:
            ids = np.concatenate(numbered)
            if len(numbered) != len(chunks) or not np.array_equal(np.sort(ids), np.arange(nf0, nf0 + total)):
                raise ValueError(f"the new factors' ids must be {nf0} … {nf0 + total - 1}, each once")
        self._reserve_factors(nf0 + total, self.nfv + sum(c[0].size for c in chunks),
                              self.njac + sum(c[1].size for c in chunks))
        touched = []
        nf = nf0
        for fvars, jac, fids in chunks:
            F, k = fvars.shape
            if fids is None:
                fids = np.arange(nf, nf + F, dtype=np.int64)
            append_factors(fvars, jac, fids, (self.nfv, self.njac), self.store)
            touched.append(fvars.ravel())
            nf += F
            self.nfv += F * k
            self.njac += jac.size
        self.nf = nf
        allv = np.concatenate(touched)
        undo.append((self.store.ahead, allv, self.store.ahead[allv].copy()))  # repeats: equal heads
        link_adjacency(self.store, nf0, self.nf)
        return touched

    def _refresh(self, refreshed, undo: list) -> None:
        """New Jacobians of existing factors (the old ones kept in ``undo``)."""
        jac_all = self.store.jac
        for fids, jac in refreshed:
            fids = np.asarray(fids, dtype=np.int64)
            if fids.size == 0:
                continue
            jac = np.ascontiguousarray(jac, dtype=np.float64)
            r, D1 = jac.shape[1], jac.shape[2]
            idx = (self.store.fjstart[fids][:, None] + np.arange(r * D1)[None, :])
            undo.append((jac_all, idx, jac_all[idx].copy()))
            jac_all[idx] = jac.reshape(len(fids), r * D1)

    def _affected(self, observed: np.ndarray, relin: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(affected, orphans): the variables to re-eliminate and the subtrees hanging from them."""
        nv = self.nv
        if self._marks.shape[0] < 2 * nv:
            self._marks = np.empty(4 * nv + 64, dtype=np.int64)
        affected = self._marks[:nv]
        orphans = self._marks[nv:2 * nv]
        na, no = mark_affected(observed, relin, self.tree, self.pools.ipool, self.work.flag, affected, orphans)
        return affected[:na].copy(), orphans[:no].copy()

    def _reeliminate(self, observed: np.ndarray, relin: np.ndarray, dead: np.ndarray | None = None,
                     groups: np.ndarray | None = None) -> None:
        affected, orphans = self._affected(observed, relin)
        if self.ndead or (dead is not None and dead.size):
            # a variable taken out has no node: it is not re-eliminated (nothing hangs from it,
            # since every node whose separator held it held one of its factors' variables)
            keep = self.vdead[affected] == 0
            affected = affected[keep]
            observed = observed[self.vdead[observed] == 0]
        self._reeliminate_set(affected, orphans, observed, dead, groups)

    def _reeliminate_set(self, affected: np.ndarray, orphans: np.ndarray, observed: np.ndarray,
                         dead: np.ndarray | None = None, groups: np.ndarray | None = None) -> None:
        """Order and re-eliminate the ``affected`` variables on top of the ``orphans`` (or every
        live variable, when they are :data:`BATCH_SHARE` of them), the ``observed`` ones last
        (or by ``groups``); then take the nodes of ``dead`` out of the tree."""
        batch = len(affected) >= BATCH_SHARE * self.live
        if batch:
            affected = np.flatnonzero(self.vdead[:self.nv] == 0).astype(np.int64) if self.ndead or \
                (dead is not None and dead.size) else np.arange(self.nv, dtype=np.int64)
            orphans = orphans[:0]
        order = self._order(affected, orphans, observed) if groups is None else \
            self._order_groups(affected, orphans, groups, observed)
        stats = self.work.stats
        before = stats.copy()
        # a batch step rewrites every node: into new pools (nothing in the old ones is read),
        # which replace the old ones whole, with nothing freed left in them
        # (sized by the kernel's own count: it asks for the room after its symbolic pass)
        # (as long as the old ones: np.empty touches no page, so only what is written is resident)
        pools, itop, ftop = (st.Pools(np.empty(self.pools.ipool.shape[0], dtype=np.int64),
                                      np.empty(self.pools.fpool.shape[0])), 0, 0) if batch \
            else (self.pools, self.itop, self.ftop)
        while True:
            status, detail, it, ft = reeliminate(order, orphans, self.next_pos, self.tree, pools, itop, ftop,
                                                 self.store, self.work, self.keep_update)
            if status == st.OK:
                break
            stats[:] = before
            if status == st.NOT_POSITIVE:
                raise IndeterminantLinearSystem(
                    f"the linear system is not positive definite at variable {int(detail)}: it is not "
                    "determined by the factors so far", int(detail))
            self.pool_requests += 1
            if batch:
                pool = pools.ipool if status == st.NEED_INT else pools.fpool
                _, capacity = st.pool_plan(0, 0, pool.shape[0], int(detail), self.pool_room)
                pools = self._grown_pools(pools, status, capacity)
            else:
                self._make_room(status, int(detail))
                pools, itop, ftop = self.pools, self.itop, self.ftop
        self.pools = pools
        if dead is not None and dead.size:
            clear_nodes(dead, self.vdead, self.tree, self.delta, stats)
        if batch:
            stats[4:6] = 0
        self._eliminated(order, 0 if batch else len(orphans), before, (itop, ftop), (int(it), int(ft)), batch)

    def _eliminated(self, order: np.ndarray, orphans: int, before: np.ndarray, tops: tuple, new_tops: tuple,
                    batch: bool = False) -> None:
        """The bookkeeping of a re-elimination of ``order`` that succeeded: the pools' tops
        (``tops`` → ``new_tops``), the next position, the wildfire's marks, the update's counts
        (``work.stats`` against ``before``)."""
        self.pool_written += (new_tops[0] - tops[0], new_tops[1] - tops[1])
        self.itop, self.ftop = new_tops
        self.next_pos += len(order)
        self.wildfire.replaced[order] = 1
        done = self.work.stats - before
        self.last = UpdateStats(columns=int(done[0]), orphans=orphans, extend_adds=int(done[1]),
                                factors=int(done[2]), batch=bool(batch))
        self.totals.add(self.last)

    @staticmethod
    def _grown_pools(pools: st.Pools, status: int, size: int) -> st.Pools:
        if status == st.NEED_INT:
            return pools._replace(ipool=st.grow_pool(pools.ipool, size))
        return pools._replace(fpool=st.grow_pool(pools.fpool, size))

    def _make_room(self, status: int, size: int) -> None:
        """Room in the pools for a re-elimination that asked for ``size`` entries of one:
        compacted in place and grown as :func:`~lie_factors.incremental.structures.pool_plan`
        says."""
        ints = status == st.NEED_INT
        pool = self.pools.ipool if ints else self.pools.fpool
        top = self.itop if ints else self.ftop
        freed = int(self.work.stats[5 if ints else 4])
        compact, capacity = st.pool_plan(top, freed, pool.shape[0], size, self.pool_room)
        if compact:
            self._compact()
        if capacity > pool.shape[0]:
            self.pools = self._grown_pools(self.pools, status, capacity)

    def _order(self, affected: np.ndarray, orphans: np.ndarray, observed: np.ndarray) -> np.ndarray:
        """The affected variables in elimination order: minimum degree (at most
        :data:`~lie_factors.incremental.ordering.MAX_SMALL` of them) or CCOLAMD on the factors
        inside them and the orphans' separators, the observed variables last (when some are
        not observed)."""
        na = len(affected)
        flag = self.work.flag
        stamp = self._graph_room(affected, orphans)
        if na <= max(SMALL_SET, self.max_small):
            out = np.empty(na, dtype=np.int64)
            order_small(affected, orphans, observed, self.store, self.tree, self.pools.ipool, flag, stamp,
                        self._graph_ptr, self._graph_vars, self.work.loc, out)
            return out
        import gtsam

        n, m = ordering_graph(affected, orphans, self.store, self.tree, self.pools.ipool, flag, stamp,
                              self._graph_ptr, self._graph_vars)
        obs = marked_among(affected, observed, flag)
        g = _symbolic_graph(self._graph_ptr, self._graph_vars, n, m)
        if 0 < len(obs) < na:
            ordering_ = gtsam.Ordering.ColamdConstrainedLastSymbolicFactorGraph(g, obs.tolist(), False)
        else:
            ordering_ = gtsam.Ordering.ColamdSymbolicFactorGraph(g)
        return np.fromiter(map(ordering_.at, range(ordering_.size())), dtype=np.int64, count=ordering_.size())

    def _order_groups(self, affected: np.ndarray, orphans: np.ndarray, groups: np.ndarray,
                      observed: np.ndarray) -> np.ndarray:
        """The affected variables in an elimination order that takes them group by group
        (``groups[v]``, smaller first: ISAM2's ``constrainedKeys``): ordered as :meth:`_order`
        orders them, the ``observed`` ones last, then sorted stably by group.  The observed last
        (ISAM2's rule without groups) keeps the newest at the root; with the groups alone, a
        chain's oldest variable becomes the root, and a fixed-lag smoother's next
        marginalization re-eliminates the whole window to make it a leaf."""
        if not len(affected):
            return affected
        order = self._order(affected, orphans, observed)
        return order[np.argsort(groups[order], kind="stable")]

    def _graph_room(self, affected: np.ndarray, orphans: np.ndarray) -> int:
        """Room in ``_graph_ptr``/``_graph_vars`` for the graph the affected variables are
        ordered on (:func:`~lie_factors.incremental.marking.ordering_graph`); returns a new
        factor stamp for it."""
        nptr, nout = ordering.graph_size(self.nf, self.nfv, len(orphans), int(self.tree.sep_len[orphans].sum()),
                                         len(affected))
        if self._graph_ptr.shape[0] < nptr:
            self._graph_ptr = np.empty(2 * nptr, dtype=np.int64)
        if self._graph_vars.shape[0] < nout:
            self._graph_vars = np.empty(2 * nout, dtype=np.int64)
        self.fstamp_box += 1
        return self.fstamp_box

    def _compact(self) -> None:
        """Move the live entries of the pools down over the freed ones, in place: when a pool is
        full and most of it is freed, instead of growing it."""
        self.itop, self.ftop = compact_pools(self.nv, self.tree, self.pools)
        self.pool_moved += (self.itop, self.ftop)
        self.work.stats[4:6] = 0
        self.compactions += 1

def _symbolic_graph(ptr: np.ndarray, out: np.ndarray, n: int, m: int):
    """The ``gtsam.SymbolicFactorGraph`` of the ``n`` lists in ``ptr``/``out`` (CSR, ``m``
    entries): the two-variable factors (nearly all) pushed run by run through ``map()``, in
    their order."""
    import gtsam

    g = gtsam.SymbolicFactorGraph()
    push = g.push_factor
    starts = ptr[:n]
    sizes = ptr[1:n + 1] - starts
    firsts = out[starts].tolist()
    seconds = out[np.minimum(starts + 1, max(m - 1, 0))].tolist()
    flat = out[:m].tolist()
    ptr = ptr[:n + 1].tolist()
    done = 0
    for i in np.flatnonzero(sizes != 2).tolist() + [n]:
        if i > done:
            deque(map(push, firsts[done:i], seconds[done:i]), maxlen=0)
        if i < n:
            a, b = ptr[i], ptr[i + 1]
            if b - a <= 3:
                push(*flat[a:b])
            else:
                g.push_back(gtsam.SymbolicFactor.FromKeys(flat[a:b]))
        done = i + 1
    return g
