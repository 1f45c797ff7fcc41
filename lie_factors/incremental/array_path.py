"""The array path of an update: a replay's prepared factors added by one compiled call.

:meth:`Smoother.update_prepared <lie_factors.incremental.smoother.Smoother.update_prepared>`
adds new poses and some of a :class:`~lie_factors.incremental.factor_arrays.FactorArrays`'
factors.  When the smoother holds only that group's variables and array factors,
:func:`try_update` takes it here: Python checks the keys and maps them to variables (a dict
lookup each) and appends the new values and factors to the smoother's arrays; on an update
that relinearizes (every ``relinearizeSkip``-th), ISAM2's check picks the variables and their
factors are linearized again (a compiled call per group and per kind); then one compiled call
(:func:`add_and_reeliminate`) linearizes the new factors into the block factor's store, links
them to their variables, marks the columns to re-eliminate, orders them and re-eliminates
them (a set that COLAMD orders, a batch step, pools to grow or a refused pivot: then by the
block factor's Python after it).  Any other update goes through the general path
(:meth:`Smoother._apply <lie_factors.incremental.smoother.Smoother._apply>`): the same
kernels and the same linearization cores, with GTSAM's objects.
"""

from __future__ import annotations

from collections import namedtuple

import numpy as np

from .. import factors as _factors
from ..batch.graph import key_name
from ..batch.loops import whiten_jacobian, whiten_residual
from ..errors import IndeterminantLinearSystem, InputError
from ..kernels import dispatch as _dispatch
from ..kernels.jit import inline_kernel, kernel
from ..robust.online import robust_update
from .factor_arrays import FactorArrays
from .elimination import reeliminate
from .marking import mark_affected
from .ordering import SMALL_SET, has_graph_room, order_small
from .relinearization import relinearized_now
from .removal import NONE as NO_REMOVAL
from .removal import no_value
from .update_args import PLAIN
from .storage import init_variables, link_adjacency
from .undo import Undo

#: A :class:`~lie_factors.incremental.factor_arrays.FactorArrays`' constants, as the kernel
#: takes them: per between factor M⁻¹ (E, m, m) and the whitening R (E, n, n), per prior P⁻¹
#: and R.
Prepared = namedtuple("Prepared", ["Minv", "R", "Pinv", "prior_R"])

#: ``counts`` of :func:`add_and_reeliminate`: variables, factors, variable entries, Jacobian
#: floats and scalars so far; new variables P, between factors E, priors Q; the group's
#: dimension; then for the re-elimination: the next position, the pools' tops (ints, floats),
#: the largest update matrix kept, a new factor stamp, the largest set ordered here and the
#: smallest set that is a batch step.
COUNTS = ("nv", "nf", "nfv", "njac", "nscalar", "P", "E", "Q", "n", "base", "itop", "ftop", "keep_update", "stamp",
          "max_small", "batch_at")
#: The status of :func:`add_and_reeliminate` when it left the ordering and re-elimination to
#: the caller (a larger set, a batch step, no room for the ordering graph).
LEFT = -1


@inline_kernel
def _store_factor(f, vs, nfv, njac, rows, D1, store):
    """Factor ``f`` on the variables ``vs``, its entries from ``nfv`` and its rows × D1
    Jacobian from ``njac`` (written by the caller)."""
    fvars = store.fvars
    store.fnv[f] = vs.shape[0]
    store.fvstart[f] = nfv
    for t in range(vs.shape[0]):
        fvars[nfv + t] = vs[t]
    store.frows[f] = rows
    store.fcols[f] = D1
    store.fjstart[f] = njac
    store.fstamp[f] = 0


@kernel
def add_and_reeliminate(g, X, velem, prep, plan, counts, tree, store, delta, work, pools, scratch):
    """Add P new variables and E between factors and Q priors of ``prep`` (a :data:`Prepared`)
    to the block factor, linearized at the elements ``X`` (``velem``: a variable's element),
    mark the columns to re-eliminate (the new factors' variables and the relinearized ones,
    whose factors the caller has linearized again), order them and re-eliminate them.

    ``plan``: the factors' indices in ``prep`` (E between, then Q priors), then the observed
    variables: the P new ones, each between factor's two, each prior's one; then the
    relinearized variables.  ``counts``: :data:`COUNTS`.  The structures have room for the
    factors (the caller grows them); ``scratch``: (marks (≥ 3 nv), the ordering graph's
    pointers and lists).  Writes the affected variables to ``marks[:nv]``, the orphans to
    ``marks[nv:2 nv]`` and the order to ``marks[2 nv:]`` (nv the new variable count).  Returns
    (scalars, affected, orphans, status, new itop, new ftop): status that of
    :func:`~lie_factors.incremental.elimination.reeliminate`, or :data:`LEFT` when the set is
    a batch step, larger than ``max_small`` or its graph has no room (the factors are added
    and the set marked either way).
    """
    nv0, nf0, nfv, njac, ns0, P, E, Q, n = counts[0], counts[1], counts[2], counts[3], counts[4], \
        counts[5], counts[6], counts[7], counts[8]
    dims = np.full(P, n, dtype=np.int64)
    ns = init_variables(nv0, dims, ns0, tree, store.ahead, delta)
    observed = plan[E + Q:E + Q + P + 2 * E + Q]
    relin = plan[E + Q + P + 2 * E + Q:]
    jac = store.jac
    e = np.empty(n)
    H1 = np.empty((n, n))
    H2 = np.empty((n, n))
    Ad = np.empty((n, n))
    A1 = np.empty((n, n))
    A2 = np.empty((n, n))
    b = np.empty(n)
    for q in range(E + Q):
        f = nf0 + q
        k = plan[q]
        if q < E:
            vs = observed[P + 2 * q:P + 2 * q + 2]
            D1 = 2 * n + 1
            _dispatch.Ad(g, prep.Minv[k], Ad)
            _factors.between(g, prep.Minv[k], Ad, X[velem[vs[0]]], X[velem[vs[1]]], e, H1, H2)
            Rf = prep.R[k]
            whiten_jacobian(Rf, H2, A2)
        else:
            vs = observed[P + 2 * E + q - E:P + 2 * E + q - E + 1]
            D1 = n + 1
            _factors.prior(g, prep.Pinv[k], X[velem[vs[0]]], e, H1)
            Rf = prep.prior_R[k]
        whiten_residual(Rf, e, b)
        whiten_jacobian(Rf, H1, A1)
        _store_factor(f, vs, nfv, njac, n, D1, store)
        for r in range(n):
            row = njac + r * D1
            for c in range(n):
                jac[row + c] = A1[r, c]
            if q < E:
                for c in range(n):
                    jac[row + n + c] = A2[r, c]
            jac[row + D1 - 1] = b[r]
        nfv += vs.shape[0]
        njac += n * D1
    link_adjacency(store, nf0, nf0 + E + Q)
    nv = nv0 + P
    marks, ptr, lists = scratch
    na, no = mark_affected(observed, relin, tree, pools.ipool, work.flag, marks[:nv], marks[nv:2 * nv])
    base, itop, ftop, keep, stamp, max_small, batch_at = counts[9], counts[10], counts[11], counts[12], \
        counts[13], counts[14], counts[15]
    affected, orphans, order = marks[:na], marks[nv:nv + no], marks[2 * nv:2 * nv + na]
    if na >= batch_at or na > max_small or (na > SMALL_SET and not has_graph_room(nf0 + E + Q, nfv, orphans, tree,
                                                                                affected, ptr, lists)):
        return ns, na, no, LEFT, itop, ftop
    order_small(affected, orphans, observed, store, tree, pools.ipool, work.flag, stamp, ptr, lists, work.loc, order)
    status, _, it, ft = reeliminate(order, orphans, base, tree, pools, itop, ftop, store, work, keep)
    return ns, na, no, status, it, ft


def prepared(fa) -> Prepared:
    """The kernel's view of ``fa``'s constants, made once per FactorArrays."""
    prep = getattr(fa, "_prepared", None)
    if prep is None:
        prep = fa._prepared = Prepared(np.ascontiguousarray(fa.Minv), np.ascontiguousarray(fa.R),
                                       np.ascontiguousarray(fa.Pinv), np.ascontiguousarray(fa.prior_R))
    return prep


def takes(s, fa) -> bool:
    """Whether the smoother ``s`` can take an update of ``fa``'s factors on the array path: it
    holds only ``fa``'s group and array factors (and marginal factors), and neither
    ``evaluateNonlinearError`` nor ``enableAdaptiveReorder`` is set."""
    p = s.smoother_params
    # (an update that reports the error, or may reorder every variable, is the general path's;
    # marginal factors are linear on held variables, so the array path never relinearizes them)
    return not (len(s.native) > s.marginal_natives or s.other_types
                or (s.group_names and s.group_names != [fa.group])
                or p.evaluateNonlinearError or p.enableAdaptiveReorder)


def _observed(s, fa, klist: list, edges: list, priors: list) -> list:
    """The variables of the new keys, then of each factor's keys, checked as the general path
    checks them (every key known or new, every new key in a new factor)."""
    var = s.var
    nv0 = len(s.keys)
    new = {}
    for q, k in enumerate(klist):
        if k in var:
            raise InputError(f"key {key_name(k)} is already a variable of the smoother")
        if k in new:
            raise InputError(f"key {key_name(k)} is given twice")
        new[k] = nv0 + q
    obs = list(range(nv0, nv0 + len(klist)))
    for kind, idx, keys, count in (("between", edges, fa.edge_keys, fa.E), ("prior", priors, fa.prior_keys, fa.Q)):
        if idx and not (min(idx) >= 0 and max(idx) < count):
            raise InputError(f"{kind} factor indices must be in [0, {count}), got {idx}")
        for k in (keys[idx].ravel().tolist() if idx else ()):
            v = new.get(k)
            if v is None:
                v = var.get(k)
                if v is None:
                    raise no_value(f"{fa.group} factor", k)
            obs.append(v)
    used = set(obs[len(klist):])
    for q, k in enumerate(klist):
        if nv0 + q not in used:
            raise InputError(f"new key {key_name(k)} is in no new factor: it would be unconstrained")
    return obs


def arrays_of(nf, numbered: bool = True):
    """(FactorArrays, the new values (P, m, m), the factor objects by kind) of an update read from
    GTSAM's factor objects (``nf``, a :class:`~lie_factors.incremental.factor_arrays.NewFactors`)
    that holds only one group's Between and Prior factors and new variables of that group; with
    ``numbered``, also the Betweens first in the update's graph (as the array path numbers them).
    None for any other update."""
    if nf.native or nf.nulls or not nf.arrays:
        return None
    names = {name for _, name in nf.arrays}
    if len(names) != 1:
        return None
    (group,) = names
    between, prior = nf.arrays.get(("between", group), {}), nf.arrays.get(("prior", group), {})
    if len(nf.arrays) != bool(between) + bool(prior) or any(k != group for k in nf.kinds):
        return None
    fa = FactorArrays.of_constants(group, between.get("keys"), between.get("C"), between.get("R"),
                                   prior.get("keys"), prior.get("C"), prior.get("R"))
    if numbered and not (list(between.get("pos", ())) == list(range(fa.E))
                         and list(prior.get("pos", ())) == list(range(fa.E, fa.E + fa.Q))):
        return None
    values = np.array(nf.values) if nf.values else None
    return fa, values, {"between": between.get("src", []), "prior": prior.get("src", [])}


def update_read(s, nf, args):
    """:meth:`Smoother.update` once its arguments are read (``nf``, ``args``): the robust
    smoother's update, the array path where it takes the update, the general path otherwise."""
    if s.robust is not None:
        return robust_objects(s, nf, args)
    if args == PLAIN:
        result = try_objects(s, nf)
        if result is not None:
            return result
    return s._apply(nf, args)


def try_objects(s, nf):
    """The update of :meth:`Smoother.update` (GTSAM's factor objects, read into ``nf``) on the
    array path, or None when it needs the general path: :func:`arrays_of` takes the update and
    :func:`takes` it.  The general path's own checks run first, so a refusal reads the same."""
    found = arrays_of(nf)
    if found is None or not takes(s, found[0]):
        return None
    fa, values, sources = found
    s._validate(nf)
    return try_update(s, fa, nf.keys, values, range(fa.E), range(fa.Q), sources, nf)


def robust_objects(smoother, nf, args):
    """:meth:`~lie_factors.incremental.Smoother.update` of a robust smoother: ``nf``, the update
    read from GTSAM's (or our) Between and Prior factors of one group, offered as
    :func:`robust_update` offers arrays (its loop closures the candidates); ``args`` the update's
    other arguments, which must be none."""
    if args != PLAIN:
        raise InputError("a robust smoother takes new factors and values only (no removeFactorIndices, "
                         "constrainedKeys, noRelinKeys, extraReelimKeys or force_relinearize): it adds "
                         "and removes loop closures by its own decisions")
    smoother._validate(nf)
    found = arrays_of(nf, numbered=False)
    if found is None:
        raise InputError("a robust smoother takes Between and Prior factors of one group and their new "
                         "values (or update_arrays): its loop closures are tested before they enter")
    fa, values, _ = found
    return robust_update(smoother, fa, nf.keys, values)


def try_update(s, fa, keys, values, edges, priors, sources=None, nf=None):
    """The update of :meth:`Smoother.update_prepared` on the array path, or None when it needs
    the general path (:func:`takes`).  Raises as the general path does, with the smoother
    as it was.  ``sources``: kind → the factor objects read (by default none, arrays only);
    ``nf``: the update read from them, for its report."""
    if not takes(s, fa):
        return None
    spec = fa.spec
    m, n = spec.mat, spec.dim
    klist = np.asarray(keys, dtype=np.int64).reshape(-1).tolist()
    P = len(klist)
    X = np.zeros((0, m, m)) if P == 0 and values is None else np.asarray(values, dtype=np.float64)
    if X.shape != (P, m, m):
        raise InputError(f"values: expected shape ({P}, {m}, {m}), got {X.shape}")
    if not np.isfinite(X).all():
        raise InputError("values: not finite")
    edges = np.asarray(edges, dtype=np.int64).reshape(-1).tolist()
    priors = np.asarray(priors, dtype=np.int64).reshape(-1).tolist()
    obs = _observed(s, fa, klist, edges, priors)
    # the structural rule (lie_factors.posegraph.gauge): edges are relative, priors anchor, and
    # each factor has the group's dimension in rows on every variable it touches
    E2 = P + 2 * len(edges)
    joined, free = s.gauge.join(P, obs[P:E2:2], obs[P + 1:E2:2], obs[E2:], obs)
    if free is not None:
        raise s._refusal(free, klist)
    relin = relinearized_now(s)
    nv0 = len(s.keys)
    el = s._elements(fa.group)
    n_el = el.n
    kinds = [(s._kind(kind, fa.group), C, R, idx, k) for kind, C, R, idx, k in
             (("between", fa.Minv, fa.R, edges, 2), ("prior", fa.Pinv, fa.prior_R, priors, 1)) if idx]
    kind_n = [kind.n for kind, *_ in kinds]
    s.keys.extend(klist)
    s.var.update(zip(klist, range(nv0, nv0 + P)))
    s.vgroup.extend([fa.group] * P)
    s._grow_variables(nv0 + P)
    s.velem[nv0:nv0 + P] = el.append(X, np.arange(nv0, nv0 + P))
    s.vcode[nv0:nv0 + P] = el.code
    s.vnative[nv0:nv0 + P] = False
    bf = s.bf
    at, fid = P, bf.nf
    for kind, C, R, idx, k in kinds:
        v = np.array(obs[at:at + k * len(idx)], dtype=np.int64).reshape(-1, k)
        local = kind.append(v, s.velem[v], C[idx], R[idx],
                            [None] * len(idx) if sources is None else sources[kind.kind])
        kind.fid[local] = np.arange(fid, fid + len(idx))
        s._register(kind.fid[local], kind.code, local, kind.kind == "between")
        at += k * len(idx)
        fid += len(idx)
    plan = np.concatenate([np.array(edges + priors + obs, dtype=np.int64), relin])
    undo = Undo(s)
    try:
        refreshed = s._relinearize(relin, undo) if len(relin) else ()
        bf.update_arrays(spec.group, el.X, s.velem, prepared(fa), plan, (P, len(edges), len(priors), n),
                         refreshed)
    except BaseException as exc:
        undo.run()
        del s.keys[nv0:], s.vgroup[nv0:]
        for k in klist:
            s.var.pop(k, None)
        el.n = n_el
        for (kind, *_), kn in zip(kinds, kind_n):
            kind.truncate(kn)
        if isinstance(exc, IndeterminantLinearSystem):
            raise s._indeterminant(exc, klist) from None
        raise
    s.gauge.commit(joined)
    return s._updated(len(relin)) if nf is None else s._updated(len(relin), nf, NO_REMOVAL, (), relin)
