"""The incremental block Cholesky factor of a growing least-squares problem.

``BlockFactor`` holds the linearized factors (whitened Jacobians ``[A | b]``,
one block per variable) and the factor ``L`` of ``Λ = Σ AᵀA`` under an
elimination order, as a tree of block columns
(:mod:`lie_factors.incremental.elimination`).  An update adds variables and
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

Every update is all or nothing: an update that leaves a variable without
information (a pivot that is not positive) raises
:class:`IndeterminantLinearSystem` and the factor is as it was before.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from ..errors import IndeterminantLinearSystem
from . import elimination as _el


#: ISAM2's share of re-eliminated variables from which an update orders and eliminates everything.
BATCH_SHARE = 0.65

#: Sets this small are ordered as they were, the observed variables last (an odometry step:
#: the previous pose and the new one, perhaps the one before), without building a graph for
#: COLAMD (about 70 µs of Python and GTSAM calls).
SMALL_SET = 3


def _grow(a: np.ndarray, n: int, fill=None) -> np.ndarray:
    """``a`` with room for at least ``n`` entries along its first axis (capacity doubles)."""
    if a.shape[0] >= n:
        return a
    cap = max(n, 2 * a.shape[0], 16)
    out = np.empty((cap,) + a.shape[1:], dtype=a.dtype)
    out[:a.shape[0]] = a
    if fill is not None:
        out[a.shape[0]:] = fill
    return out


def _grow_pool(a: np.ndarray, n: int) -> np.ndarray:
    """The pool ``a`` with room for ``n`` entries and a quarter more, its entries kept.  Pools
    are most of the factor's memory: they grow by less than doubling, and in place
    (``ndarray.resize``: a large block is remapped, not copied, so the old and the new pool
    are never both in memory); no view of a pool outlives a call."""
    if a.shape[0] >= n:
        return a
    a.resize(n + n // 4, refcheck=False)
    return a


@dataclass
class UpdateStats:
    """What one update did: columns re-eliminated (``columns``), orphan subtrees reattached,
    update matrices extend-added, factors assembled, whether everything was reordered."""

    columns: int = 0
    orphans: int = 0
    extend_adds: int = 0
    factors: int = 0
    batch: bool = False


class BlockFactor:
    """Variables with block dimensions, factors as whitened Jacobians, and the incremental factor.

    Variables and factors are numbered from 0 in the order they are added.
    ``keep_update``: the largest update matrix (floats) a clique member below the clique's
    last variable keeps (:data:`~lie_factors.incremental.elimination.KEEP_UPDATE`).
    Attributes after an update: ``delta`` (solution, see :meth:`solve`),
    ``last`` (:class:`UpdateStats`), ``totals`` (the sums over all updates).
    """

    _VAR_ARRAYS = ("dim", "voff", "pos", "parent", "first", "nxt", "nchild", "sep_start", "sep_len",
                   "sep_dim", "cond", "ustart", "ahead", "aidx", "mark", "loc", "chead", "cnext", "flag",
                   "replaced", "changed", "visited")
    _FAC_ARRAYS = ("fnv", "fvstart", "frows", "fcols", "fjstart", "fstamp")

    def __init__(self, keep_update: int = _el.KEEP_UPDATE):
        self.keep_update = int(keep_update)
        self.nv = 0
        self.nf = 0
        self.nscalar = 0
        for name in self._VAR_ARRAYS:
            setattr(self, name, np.zeros(0, dtype=np.int64))
        for name in self._FAC_ARRAYS:
            setattr(self, name, np.zeros(0, dtype=np.int64))
        self.fvars = np.zeros(0, dtype=np.int64)
        self.nfv = 0
        self.jac = np.zeros(0)
        self.njac = 0
        # adjacency lists of the variables, one entry per (factor, variable) parallel to fvars
        self.anext = np.zeros(0, dtype=np.int64)
        self.afac = np.zeros(0, dtype=np.int64)
        self.ipool = np.zeros(1 << 14, dtype=np.int64)
        self.itop = 0
        self.fpool = np.zeros(1 << 18)
        self.ftop = 0
        self.roots = np.full(1, -1, dtype=np.int64)
        self.stamps = np.zeros(1, dtype=np.int64)
        self.fstamp_box = 0
        self.next_pos = 0
        self.delta = np.zeros(0)
        self.stats = np.zeros(7, dtype=np.int64)
        self.last = UpdateStats()
        self.totals = UpdateStats()
        self.updates = 0
        self.compactions = 0
        # scratch reused by every update
        self._marks = np.zeros(0, dtype=np.int64)
        self._graph_ptr = np.zeros(0, dtype=np.int64)
        self._graph_vars = np.zeros(0, dtype=np.int64)

    # ------------------------------------------------------------------ storage
    def _reserve_vars(self, n: int) -> None:
        if self.dim.shape[0] >= n:
            return
        for name in self._VAR_ARRAYS:
            fill = -1 if name in ("parent", "first", "nxt", "ahead", "aidx", "cond", "ustart",
                                  "chead", "cnext") else 0
            setattr(self, name, _grow(getattr(self, name), n, fill))

    def _reserve_factors(self, n: int, nfv: int, njac: int) -> None:
        if self.fnv.shape[0] < n:
            for name in self._FAC_ARRAYS:
                setattr(self, name, _grow(getattr(self, name), n, 0))
        self.fvars = _grow(self.fvars, nfv)
        self.jac = _grow(self.jac, njac)
        self.anext = _grow(self.anext, nfv)
        self.afac = _grow(self.afac, nfv)

    def _reserve_delta(self, n: int) -> None:
        self.delta = _grow(self.delta, n, 0.0)

    # ------------------------------------------------------------------ updates
    def update(self, new_dims=(), new_factors=(), refreshed=(), relinearized=(), observed=()) -> UpdateStats:
        """Add variables and factors, replace Jacobians, and re-eliminate what changed.

        ``new_dims`` (P,): dimensions of the new variables (they get the next
        indices).  ``new_factors``: sequence of ``(vars (F, k), jac (F, r, D + 1))``,
        the variables of F factors of k variables each and their whitened
        Jacobians ``[A_1 … A_k | b]`` (D = the sum of the k dimensions).
        ``refreshed``: sequence of ``(factor ids (F,), jac (F, r, D + 1))``:
        new Jacobians of existing factors (relinearized).  ``relinearized``:
        variables whose factors all changed (their row subtrees are
        re-eliminated).  ``observed``: more variables to re-eliminate; the
        variables of the new factors and the new variables are always
        re-eliminated and ordered last.  Raises
        :class:`IndeterminantLinearSystem` (state unchanged) when a pivot is not positive.
        """
        new_dims = np.asarray(new_dims, dtype=np.int64).reshape(-1)
        nv0, nf0, nfv0, njac0, ns0 = self.nv, self.nf, self.nfv, self.njac, self.nscalar
        saved_heads = None
        saved_jac = []
        try:
            P = new_dims.shape[0]
            if P:
                self._reserve_vars(nv0 + P)
                self._reserve_delta(ns0 + int(new_dims.sum()))
                self.nscalar = _el.init_variables(nv0, new_dims, ns0, self.dim, self.voff, self.parent, self.first,
                                                  self.nxt, self.nchild, self.sep_len, self.sep_dim, self.cond,
                                                  self.ustart, self.ahead, self.delta)
                self.nv = nv0 + P
            observed_parts = [np.asarray(observed, dtype=np.int64).reshape(-1),
                              np.arange(nv0, self.nv, dtype=np.int64)]
            touched_vars = []
            for fvars, jac in new_factors:
                fvars = np.ascontiguousarray(fvars, dtype=np.int64)
                jac = np.ascontiguousarray(jac, dtype=np.float64)
                F, k = fvars.shape
                if F == 0:
                    continue
                r, D1 = jac.shape[1], jac.shape[2]
                self._reserve_factors(self.nf + F, self.nfv + F * k, self.njac + F * r * D1)
                _el.append_factors(fvars, jac, self.nf, self.nfv, self.njac, self.fnv, self.fvstart, self.fvars,
                                   self.frows, self.fcols, self.fjstart, self.jac, self.fstamp)
                touched_vars.append(fvars.ravel())
                observed_parts.append(fvars.ravel())
                self.nf += F
                self.nfv += F * k
                self.njac += F * r * D1
            if touched_vars:
                allv = np.concatenate(touched_vars)
                saved_heads = (allv, self.ahead[allv].copy())  # repeated variables: equal heads
                _el.link_adjacency(self.ahead, self.anext, self.afac, self.fvars, self.fnv, self.fvstart, nf0, self.nf)
            for fids, jac in refreshed:
                fids = np.asarray(fids, dtype=np.int64)
                if fids.size == 0:
                    continue
                jac = np.ascontiguousarray(jac, dtype=np.float64)
                r, D1 = jac.shape[1], jac.shape[2]
                idx = (self.fjstart[fids][:, None] + np.arange(r * D1)[None, :])
                saved_jac.append((idx, self.jac[idx].copy()))
                self.jac[idx] = jac.reshape(len(fids), r * D1)
            observed_all = np.concatenate(observed_parts)  # repeats allowed
            relin = np.unique(np.asarray(relinearized, dtype=np.int64).reshape(-1)) if len(relinearized) else \
                np.zeros(0, dtype=np.int64)
            self._reeliminate(observed_all, relin)
        except BaseException:
            if saved_heads is not None:
                self.ahead[saved_heads[0]] = saved_heads[1]
            for idx, old in reversed(saved_jac):
                self.jac[idx] = old
            self.nv, self.nf, self.nfv, self.njac, self.nscalar = nv0, nf0, nfv0, njac0, ns0
            raise
        self.updates += 1
        return self.last

    def _reeliminate(self, observed: np.ndarray, relin: np.ndarray) -> None:
        nv = self.nv
        if self._marks.shape[0] < 2 * nv:
            self._marks = np.empty(4 * nv + 64, dtype=np.int64)
        affected = self._marks[:nv]
        orphans = self._marks[nv:2 * nv]
        na, no = _el.mark_affected(observed, relin, self.parent, self.first, self.nxt, self.nchild,
                                   self.sep_start, self.sep_len, self.ustart, self.ipool, self.flag, affected,
                                   orphans)
        affected, orphans = affected[:na].copy(), orphans[:no].copy()
        batch = na >= BATCH_SHARE * nv
        if batch:
            affected = np.arange(nv, dtype=np.int64)
            orphans = orphans[:0]
        order = self._order(affected, orphans, observed)
        st = self.stats
        before = st.copy()
        # a batch step rewrites every node: into new pools (nothing in the old ones is read),
        # which replace the old ones whole, with nothing freed left in them
        # (sized by the kernel's own count: it asks for the room after its symbolic pass)
        ipool, itop = (np.empty(self.itop + 1024, dtype=np.int64), 0) if batch else (self.ipool, self.itop)
        fpool, ftop = (np.empty(0), 0) if batch else (self.fpool, self.ftop)
        while True:
            status, detail, it, ft = _el.reeliminate(
                order, orphans, self.next_pos,
                self.dim, self.pos, self.parent, self.first, self.nxt, self.nchild, self.sep_start,
                self.sep_len, self.sep_dim, self.cond, self.ustart, self.roots, ipool, itop, fpool, ftop,
                self.fnv, self.fvstart, self.fvars, self.frows, self.fjstart, self.fcols, self.jac,
                self.ahead, self.anext, self.afac,
                self.aidx, self.mark, self.stamps, self.loc, self.chead, self.cnext, st, self.keep_update)
            if status == _el.OK:
                break
            st[:] = before
            if status == _el.NEED_INT:
                if batch:
                    ipool = _grow_pool(ipool, int(detail))
                elif 2 * self.stats[5] > self.itop:
                    self._compact()
                else:
                    self.ipool = _grow_pool(self.ipool, int(detail))
            elif status == _el.NEED_FLOAT:
                if batch:
                    fpool = _grow_pool(fpool, int(detail))
                elif 2 * self.stats[4] > self.ftop and int(detail) - self.stats[4] <= self.fpool.shape[0]:
                    self._compact()
                else:
                    self.fpool = _grow_pool(self.fpool, int(detail))
            else:
                raise IndeterminantLinearSystem(
                    f"the linear system is not positive definite at variable {int(detail)}: it is not "
                    "determined by the factors so far", int(detail))
            if not batch:
                ipool, itop, fpool, ftop = self.ipool, self.itop, self.fpool, self.ftop
        self.ipool, self.fpool = ipool, fpool
        if batch:
            st[4:6] = 0
        self.itop, self.ftop = int(it), int(ft)
        self.next_pos += len(order)
        self.replaced[order] = 1
        done = st - before
        self.last = UpdateStats(columns=int(done[0]), orphans=int(no if not batch else 0),
                                extend_adds=int(done[1]), factors=int(done[2]), batch=bool(batch))
        t = self.totals
        t.columns += self.last.columns
        t.orphans += self.last.orphans
        t.extend_adds += self.last.extend_adds
        t.factors += self.last.factors
        t.batch += self.last.batch

    def _order(self, affected: np.ndarray, orphans: np.ndarray, observed: np.ndarray) -> np.ndarray:
        """The affected variables in elimination order: CCOLAMD on the factors inside them and the
        orphans' separators, the observed variables last (when some are not observed)."""
        na = len(affected)
        if na <= SMALL_SET:
            # no choice to make: the others (in their order so far), then the observed ones
            # (lists: for three variables or fewer, numpy's set routines cost more than the work)
            obs = _el.marked_among(affected, observed, self.flag).tolist()
            pos = self.pos
            rest = sorted((v for v in affected.tolist() if v not in obs), key=lambda v: pos[v])
            return np.array(rest + obs, dtype=np.int64)
        import gtsam

        nptr = self.nf + len(orphans) + 1 + na
        nout = self.nfv + int(self.sep_len[orphans].sum()) + 1 + na
        if self._graph_ptr.shape[0] < nptr:
            self._graph_ptr = np.empty(2 * nptr, dtype=np.int64)
        if self._graph_vars.shape[0] < nout:
            self._graph_vars = np.empty(2 * nout, dtype=np.int64)
        ptr, out = self._graph_ptr, self._graph_vars
        self.fstamp_box += 1
        n, m = _el.ordering_graph(affected, orphans, self.fnv, self.fvstart, self.fvars, self.ahead, self.anext,
                                  self.afac, self.sep_start, self.sep_len, self.ipool, self.flag, self.fstamp,
                                  self.fstamp_box, ptr, out)
        obs = _el.marked_among(affected, observed, self.flag)
        g = gtsam.SymbolicFactorGraph()
        push = g.push_factor
        # the two-variable factors (nearly all) pushed run by run through map(), in their order
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
        if 0 < len(obs) < na:
            ordering = gtsam.Ordering.ColamdConstrainedLastSymbolicFactorGraph(g, obs.tolist(), False)
        else:
            ordering = gtsam.Ordering.ColamdSymbolicFactorGraph(g)
        return np.fromiter(map(ordering.at, range(ordering.size())), dtype=np.int64, count=ordering.size())

    def _compact(self) -> None:
        """Move the live entries of the pools down over the freed ones, in place: when a pool is
        full and most of it is freed, instead of growing it."""
        self.itop, self.ftop = _el.compact_pools(self.nv, self.dim, self.sep_start, self.sep_len, self.sep_dim,
                                                 self.cond, self.ustart, self.ipool, self.fpool)
        self.stats[4:6] = 0
        self.compactions += 1

    # ------------------------------------------------------------------ solving
    def solve(self, threshold: float = 0.0) -> int:
        """Bring ``delta`` up to date after updates (wildfire, see
        :func:`~lie_factors.incremental.elimination.back_substitute`); returns the nodes solved."""
        return int(_el.back_substitute(float(threshold), self.replaced, self.changed, self.roots, self.first,
                                       self.nxt, self.dim, self.voff, self.sep_start, self.sep_len, self.sep_dim,
                                       self.cond, self.ipool, self.fpool, self.delta, self.visited))

    def variable_delta(self, v: int) -> np.ndarray:
        o = int(self.voff[v])
        return self.delta[o:o + int(self.dim[v])]

    def marginal_covariance(self, v: int) -> np.ndarray:
        """(d, d): the block of Λ⁻¹ of variable ``v`` (only the path from ``v`` to its root is read)."""
        d = int(self.dim[v])
        out = np.empty((d, d))
        _el.marginal_information_root_path(int(v), self.parent, self.dim, self.voff, self.sep_start, self.sep_len,
                                           self.cond, self.ipool, self.fpool, out)
        return out

    # ------------------------------------------------------------------ inspection (tests, small problems)
    def ordering(self) -> np.ndarray:
        """Variable indices in elimination order."""
        return np.argsort(self.pos[:self.nv], kind="stable")

    def dense_system(self) -> tuple[np.ndarray, np.ndarray]:
        """(Λ, η) = (Σ AᵀA, Σ Aᵀb) as dense arrays in variable-offset order, from the stored Jacobians."""
        n = self.nscalar
        H = np.zeros((n + 1, n + 1))
        for f in range(self.nf):
            k, v0 = int(self.fnv[f]), int(self.fvstart[f])
            vs = self.fvars[v0:v0 + k]
            r, D1 = int(self.frows[f]), int(self.fcols[f])
            J = self.jac[int(self.fjstart[f]):int(self.fjstart[f]) + r * D1].reshape(r, D1)
            cols = np.concatenate([self.voff[v] + np.arange(self.dim[v]) for v in vs] + [[n]])
            H[np.ix_(cols, cols)] += J.T @ J
        return H[:n, :n], H[:n, n]

    def dense_factor(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(perm, L, y): scalar permutation of the elimination order, the lower-triangular
        L with L Lᵀ = Λ[perm][:, perm], and y = L⁻¹ η[perm], assembled from the nodes."""
        order = self.ordering()
        perm = np.concatenate([self.voff[v] + np.arange(self.dim[v]) for v in order]).astype(np.int64)
        where = np.empty(self.nscalar, dtype=np.int64)
        where[perm] = np.arange(self.nscalar)
        n = self.nscalar
        L = np.zeros((n, n))
        y = np.zeros(n)
        for v in order:
            d = int(self.dim[v])
            sep = self.ipool[int(self.sep_start[v]):int(self.sep_start[v]) + int(self.sep_len[v])]
            s = int(self.sep_dim[v])
            N = d + s + 1
            C = self.fpool[int(self.cond[v]):int(self.cond[v]) + d * N].reshape(d, N)
            rows = np.concatenate([where[self.voff[w] + np.arange(self.dim[w])] for w in [v, *sep]]).astype(np.int64)
            cols = where[self.voff[v] + np.arange(d)]
            L[np.ix_(rows, cols)] = C[:, :d + s].T
            y[cols] = C[:, N - 1]
        return perm, L, y
