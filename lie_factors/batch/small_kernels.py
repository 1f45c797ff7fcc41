"""The whole solve of a small problem in one compiled call: GTSAM's Levenberg–Marquardt (or
Gauss–Newton) over factor groups reached by address, a block-sparse Cholesky of fixed pattern.

:func:`solve` runs ``defaultOptimize`` with ``iterate``/``tryLambda`` of
:mod:`lie_factors.lm` silently: its λ rules, step judgement and convergence test are that module's
own functions, compiled here (:data:`_converged` …), so the schedule is written once.  What
:mod:`lie_factors.batch.small` hands over:

* **groups** ``gtab`` (K, :data:`G_COLUMNS`): each a kernel reached by address (a factor kind's or
  a Between/Prior group's C entry, :mod:`lie_factors.kernels.ccall`) with its descriptor
  ``descs[k]``, F factors of m rows on ``nslot`` variables; it writes, for its factors, the
  whitened rows: slot j's Jacobian block of factor f at ``apool[astart_j + f·fstride_j]`` (m rows
  of ``rstride_j``, d_j columns), b at ``bpool[B0 + f·m]``, ‖b‖² at ``sqpool[SQ0 + f]`` and a
  status at ``stpool[SQ0 + f]`` (> 0: a fault, which Python raises: :data:`FAULT`);
* **variables** by elimination position p (dims (P,), scalar offsets soff (P+1,)): ``fvar`` gives
  each factor slot's position; their values live in ``x_work`` (where the groups read them) and
  ``x_best`` (the estimate), each block of a type retracted by its C entry (``rtab``/``rdescs``):
  x_work = x_best ⊕ δ;
* **losses** per factor (``loss_kind``, ``loss_k``: :mod:`lie_factors.robust.losses`, 0
  Gaussian; ``loss_scale`` s, a GNC weight): each linearization scales a factor's rows by
  √(s·w(‖b‖)), and its error is s·ρ(‖b‖);
* ``params`` (:data:`P_COLUMNS`) and the outputs: the error and λ after each iteration
  (``errors``, ``lambdas``) and ``stats`` (:data:`S_COLUMNS`).

The linear system is Λ = Σ AᵀA in the layout of :mod:`lie_factors.sparse.blockchol` (its pattern
computed here once from the factors' variable pairs), damped on a copy: Λ + λI (or λ·D with
``diagonalDamping``), factored with the sign rule (GTSAM's LM raises λ where a factorization fails);
Gauss–Newton's undamped Λ with the pivot rule (a refused pivot: :data:`SINGULAR`).  The
linearized cost change is GTSAM's ``deltaError``: ½Σ‖b‖² − ½Σ‖Aδ − b‖².
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba.extending import register_jitable

from .. import lm
from ..kernels.ccall import call_c
from ..kernels.jit import helper_kernel, inline_kernel, kernel
from ..robust import losses as robust
from ..sparse import blockchol
from ..sparse.min_degree import minimum_degree
from ..sparse.pivots import PIVOT_TOLERANCE
from .small_arrays import (BUFFERS, FAULT, G_COLUMNS, NONFINITE_START, NONFINITE_STEP, OK, P_COLUMNS, S_COLUMNS,
                           SINGULAR, Arena, Groups, Losses, Pools, Retraction, State, Variables)

__all__ = ["Groups", "Variables", "Pools", "Losses", "Retraction", "Arena", "State", "G_COLUMNS", "P_COLUMNS",
           "S_COLUMNS", "BUFFERS", "OK", "FAULT", "SINGULAR", "NONFINITE_START", "NONFINITE_STEP", "solve"]

_ADDR, _JAC, _F, _M, _NSLOT, _SLOT0, _FVAR0, _PAIR0, _B0, _FIRST = range(len(G_COLUMNS))
_VALUE, _BEST, _WORK, _DELTA, _OFFSETS, _A, _B, _SQ, _STATUS, _FLOATS, _INTS = range(len(BUFFERS))

register_jitable(lm.ieee_divide)  # what lm.converged divides with, compiled where it is
#: False, True as values read at run time: a literal True or False argument would compile the
#: callee once for each.
_FLAGS = np.array([False, True])

_converged = inline_kernel(lm.converged)
_after_success = inline_kernel(lm.lambda_after_success)
_after_failure = inline_kernel(lm.lambda_after_failure)
_judge = inline_kernel(lm.judge_step)


class _Layout(NamedTuple):
    """Λ's block pattern over the supernodes (``pattern``, a :class:`lie_factors.sparse.blockchol.
    Pattern`) and where each factor slot's variable is in it: its supernode ``fblk``, offset
    within it ``foff``, scalar offset ``fscal``; ``targets`` the block each slot pair adds to;
    each variable's supernode ``vnode`` and offset within it ``vwithin``."""

    pattern: blockchol.Pattern
    fblk: np.ndarray
    foff: np.ndarray
    fscal: np.ndarray
    targets: np.ndarray
    vnode: np.ndarray
    vwithin: np.ndarray


class _System(NamedTuple):
    """Λ's values, its factor's, g, Λ's diagonal and the damping's diagonal (n,)."""

    h: np.ndarray
    l: np.ndarray
    g: np.ndarray
    hdiag: np.ndarray
    damping: np.ndarray


@inline_kernel
def _fill(a, value):
    """Every entry of the 1-D ``a`` set to ``value`` (element by element: an array assignment would
    compile numba's shape-mismatch message, seconds of string formatting on a first run)."""
    for i in range(a.shape[0]):
        a[i] = value


@inline_kernel
def _copy(src, dst):
    """``dst`` = ``src`` (1-D, the same length), element by element (:func:`_fill`: why)."""
    for i in range(src.shape[0]):
        dst[i] = src[i]


@helper_kernel
def _resolve(G, R, X, pools, arena):
    """``G.descs`` and ``R.descs`` from their ``entries`` and ``codes`` (:data:`BUFFERS`)."""
    bases = np.zeros(len(BUFFERS), dtype=np.int64)
    bases[_BEST], bases[_WORK], bases[_DELTA] = X.best.ctypes.data, X.work.ctypes.data, X.delta.ctypes.data
    bases[_OFFSETS] = R.offsets.ctypes.data
    bases[_A], bases[_B], bases[_SQ] = pools.a.ctypes.data, pools.b.ctypes.data, pools.sq.ctypes.data
    bases[_STATUS] = pools.status.ctypes.data
    bases[_FLOATS], bases[_INTS] = arena.floats.ctypes.data, arena.ints.ctypes.data
    _point(G.entries, G.codes, bases, G.descs)
    _point(R.entries, R.codes, bases, R.descs)


@inline_kernel
def _point(entries, codes, bases, descs):
    for i in range(entries.shape[0]):
        for j in range(entries.shape[1]):
            c = codes[i, j]
            descs[i, j] = entries[i, j] if c == _VALUE else bases[c] + 8 * entries[i, j]


@helper_kernel
def _evaluate(G, pools, losses, jacobians, stats):
    """Every group's kernel (with Jacobians or not), then the losses: factor f's error is
    s_f·ρ_f(‖b‖) (s_f·½‖b‖² for a Gaussian one), and with Jacobians its rows are scaled by
    √(s_f·w_f(‖b‖)) (GTSAM's ``Robust::WhitenSystem``; s_f a GNC weight, 1 otherwise).  Returns
    the error, or NaN after recording a fault (the first group with a status > 0) in ``stats``."""
    total = 0.0
    gtab = G.gtab
    for k in range(gtab.shape[0]):
        G.descs[k, gtab[k, _JAC]] = 1 if jacobians else 0
        call_c(gtab[k, _ADDR], G.descs[k].ctypes)
        F, first = gtab[k, _F], gtab[k, _FIRST]
        for f in range(F):
            if pools.status[first + f] > 0:
                stats[3] = FAULT
                stats[4] = k
                stats[5] = f
                return math.nan
        for f in range(F):
            sq = pools.sq[first + f]
            kind, scale = losses.kind[first + f], losses.scale[first + f]
            if kind == 0:
                total += scale * (0.5 * sq)
                if scale == 1.0 or not jacobians:
                    continue
                w = scale
            else:
                d = math.sqrt(sq)
                total += scale * robust.loss(kind, losses.k[first + f], d)
                if not jacobians:
                    continue
                w = scale * robust.weight(kind, losses.k[first + f], d)
            pools.sq[first + f] = w * sq  # the reweighted rows' ‖b‖²: the linearized error
            _scale_rows(G, pools, k, f, math.sqrt(w))
    return total


@inline_kernel
def _scale_rows(G, pools, k, f, root):
    """Factor f of group k's rows of A and b times ``root``."""
    m = G.gtab[k, _M]
    bo = G.gtab[k, _B0] + f * m
    for i in range(m):
        pools.b[bo + i] *= root
    for j in range(G.gtab[k, _NSLOT]):
        s = G.gtab[k, _SLOT0] + j
        ao = G.astart[s] + f * G.fstride[s]
        for i in range(m):
            for c in range(G.dim[s]):
                pools.a[ao + i * G.rstride[s] + c] *= root


@helper_kernel
def _layout(G, V, R):
    """The :class:`_Layout` of the problem: the supernodes in the variables' minimum-degree order
    (:func:`lie_factors.sparse.min_degree.minimum_degree`, :func:`_supernodes`), Λ's pattern over
    them, each factor slot's place; writes each value's offset in δ into ``R.offsets``."""
    vnode, vwithin, dims = _supernodes(V.dims, minimum_degree(V.dims.shape[0], V.pairs), V.pairs)
    bpairs = np.empty_like(V.pairs)
    for t in range(V.pairs.shape[0]):
        bpairs[t, 0] = vnode[V.pairs[t, 0]]
        bpairs[t, 1] = vnode[V.pairs[t, 1]]
    soff, colptr, rows, boff, doff, rowptr, rowblk, bcol, size = blockchol.symbolic(dims, bpairs)
    fvar = G.fvar
    fblk = np.empty_like(fvar)
    foff = np.empty_like(fvar)
    fscal = np.empty_like(fvar)
    for t in range(fvar.shape[0]):
        v = fvar[t]
        fblk[t] = vnode[v]
        foff[t] = vwithin[v]
        fscal[t] = soff[vnode[v]] + vwithin[v]
    for t in range(R.var.shape[0]):
        v = R.var[t]
        R.offsets[t] = soff[vnode[v]] + vwithin[v] if v >= 0 else -1
    targets = _targets(G.gtab, fblk, colptr, rows, boff, doff)
    pattern = blockchol.Pattern(dims, soff, colptr, rows, boff, doff, rowptr, rowblk, bcol, size)
    return _Layout(pattern, fblk, foff, fscal, targets, vnode, vwithin)


@helper_kernel
def _targets(gtab, fblk, colptr, rows, boff, doff):
    """The offset in Λ's values of the block each factor's slot pair (a ≤ b, in ``gtab``'s pair
    order) adds to: a supernode's diagonal block where both variables are in it, else the block
    (max, min) of their supernodes."""
    count = 0
    for k in range(gtab.shape[0]):
        ns = gtab[k, _NSLOT]
        count += gtab[k, _F] * (ns * (ns + 1) // 2)
    out = np.empty(count, dtype=np.int64)
    for k in range(gtab.shape[0]):
        ns = gtab[k, _NSLOT]
        at = gtab[k, _PAIR0]
        for f in range(gtab[k, _F]):
            base = gtab[k, _FVAR0] + f * ns
            for a in range(ns):
                for b in range(a, ns):
                    pa, pb = fblk[base + a], fblk[base + b]
                    out[at] = blockchol.block_offset(colptr, rows, boff, doff, max(pa, pb), min(pa, pb))
                    at += 1
    return out


@helper_kernel
def _assemble(G, pools, L, system):
    """Λ = Σ AᵀA into ``system.h`` (the lower triangle of each supernode's diagonal block, its
    blocks below whole), g = Σ Aᵀb, and Λ's diagonal."""
    widest = 0
    for s in range(G.dim.shape[0]):
        widest = max(widest, G.dim[s])
    scratch = np.empty(widest * widest)
    _fill(system.h, 0.0)
    _fill(system.g, 0.0)
    gtab = G.gtab
    for k in range(gtab.shape[0]):
        ns, m = gtab[k, _NSLOT], gtab[k, _M]
        at = gtab[k, _PAIR0]
        for f in range(gtab[k, _F]):
            base = gtab[k, _FVAR0] + f * ns
            bo = gtab[k, _B0] + f * m
            for a in range(ns):
                sa = gtab[k, _SLOT0] + a
                aa = G.astart[sa] + f * G.fstride[sa]
                go = L.fscal[base + a]
                for c in range(G.dim[sa]):
                    acc = 0.0
                    for i in range(m):
                        acc += pools.a[aa + i * G.rstride[sa] + c] * pools.b[bo + i]
                    system.g[go + c] += acc
                for b in range(a, ns):
                    sb = gtab[k, _SLOT0] + b
                    _gram(pools.a, aa, G.rstride[sa], G.dim[sa], G.astart[sb] + f * G.fstride[sb], G.rstride[sb],
                          G.dim[sb], m, scratch)
                    _add_block(system.h, L, L.targets[at], base + a, base + b, a == b, scratch, G.dim[sa],
                               G.dim[sb])
                    at += 1
    for p in range(L.pattern.dims.shape[0]):
        d, o, so = L.pattern.dims[p], L.pattern.doff[p], L.pattern.soff[p]
        for i in range(d):
            system.hdiag[so + i] = system.h[o + i * d + i]


@inline_kernel
def _gram(a, aa, ra, da, ab, rb, db, m, W):
    """W (da × db, row-major, flat) = A_aᵀA_b of one factor (m rows of A_a at ``a[aa]``, row
    stride ``ra``; A_b likewise), row by row of A."""
    for q in range(da * db):
        W[q] = 0.0
    for r in range(m):
        for i in range(da):
            x = a[aa + r * ra + i]
            for j in range(db):
                W[i * db + j] += x * a[ab + r * rb + j]


@inline_kernel
def _add_block(h, L, t, slot_a, slot_b, same, W, da, db):
    """Add W = A_aᵀA_b (:func:`_gram`): its (i, j) is Λ's (oa + i, ob + j) within the two
    supernodes, stored at that place of block (pa, pb) if pa > pb, as its transpose in block
    (pb, pa), or in the lower triangle of a diagonal block (``same``: one slot, W symmetric)."""
    pa, pb, oa, ob = L.fblk[slot_a], L.fblk[slot_b], L.foff[slot_a], L.foff[slot_b]
    if pa > pb:
        for i in range(da):
            row = t + (oa + i) * L.pattern.dims[pb] + ob
            for j in range(db):
                h[row + j] += W[i * db + j]
    elif pa < pb:
        for j in range(db):
            row = t + (ob + j) * L.pattern.dims[pa] + oa
            for i in range(da):
                h[row + i] += W[i * db + j]
    else:
        w = L.pattern.dims[pa]
        for i in range(da):
            for j in range(i + 1 if same else db):
                if oa + i >= ob + j:
                    h[t + (oa + i) * w + ob + j] += W[i * db + j]
                else:
                    h[t + (ob + j) * w + oa + i] += W[i * db + j]


@helper_kernel
def _new_linear_error(G, pools, L, delta):
    """½Σ‖A_f δ − b_f‖² over every factor (GTSAM's linear error at δ)."""
    total = 0.0
    gtab = G.gtab
    for k in range(gtab.shape[0]):
        ns, m = gtab[k, _NSLOT], gtab[k, _M]
        for f in range(gtab[k, _F]):
            base = gtab[k, _FVAR0] + f * ns
            bo = gtab[k, _B0] + f * m
            for i in range(m):
                acc = -pools.b[bo + i]
                for a in range(ns):
                    s = gtab[k, _SLOT0] + a
                    ao = G.astart[s] + f * G.fstride[s] + i * G.rstride[s]
                    o = L.fscal[base + a]
                    for c in range(G.dim[s]):
                        acc += pools.a[ao + c] * delta[o + c]
                total += 0.5 * acc * acc
    return total


@helper_kernel
def _supernodes(var_dims, position, pairs):
    """The supernodes of the factor in the variables' elimination order: consecutive variables p,
    p + 1 share one where L's block column of p is p + 1 and then exactly p + 1's (Liu's
    fundamental supernodes: no entry is added to L).  Returns (the supernode of each variable,
    its scalar offset in it, the supernodes' widths)."""
    V = var_dims.shape[0]
    perm = np.empty(V, dtype=np.int64)
    for v in range(V):
        perm[position[v]] = v
    pdims = np.empty(V, dtype=np.int64)
    for p in range(V):
        pdims[p] = var_dims[perm[p]]
    ppairs = np.empty_like(pairs)
    for t in range(pairs.shape[0]):
        ppairs[t, 0] = position[pairs[t, 0]]
        ppairs[t, 1] = position[pairs[t, 1]]
    _, colptr, rows, _, _, _, _, _, _ = blockchol.symbolic(pdims, ppairs)
    node = np.empty(V, dtype=np.int64)
    within = np.empty(V, dtype=np.int64)
    width = np.empty(V, dtype=np.int64)
    S = 0
    for p in range(V):
        q = p - 1
        joins = (q >= 0 and colptr[q + 1] > colptr[q] and rows[colptr[q]] == p
                 and colptr[q + 1] - colptr[q] - 1 == colptr[p + 1] - colptr[p])
        if joins:
            node[p] = S - 1
            within[p] = width[S - 1]
            width[S - 1] += pdims[p]
        else:
            node[p] = S
            within[p] = 0
            width[S] = pdims[p]
            S += 1
    vnode = np.empty(V, dtype=np.int64)
    vwithin = np.empty(V, dtype=np.int64)
    for v in range(V):
        vnode[v] = node[position[v]]
        vwithin[v] = within[position[v]]
    return vnode, vwithin, width[:S].copy()


@inline_kernel
def _variable_at(column, var_dims, L):
    """The variable whose scalars include ``column`` of the permuted system."""
    for v in range(var_dims.shape[0]):
        o = L.pattern.soff[L.vnode[v]] + L.vwithin[v]
        if o <= column < o + var_dims[v]:
            return v
    return -1


@inline_kernel
def _retract(R):
    """State.work = State.best ⊕ δ, every block by its type's C entry (their descriptors point at
    both and at δ)."""
    for t in range(R.address.shape[0]):
        call_c(R.address[t], R.descs[t].ctypes)


@inline_kernel
def _step(L, system, lam, tolerance, delta):
    """δ = (Λ + λ·diag(damping))⁻¹g (λ = 0: Λ itself, with the pivot rule's ``tolerance``); returns
    −1, or the column whose pivot the factorization refused (δ then unset)."""
    _copy(system.h, system.l)
    if lam != 0.0:
        for p in range(L.pattern.dims.shape[0]):
            d, o, so = L.pattern.dims[p], L.pattern.doff[p], L.pattern.soff[p]
            for i in range(d):
                system.l[o + i * d + i] += lam * system.damping[so + i]
    P = L.pattern
    bad = blockchol.factor(P.dims, P.soff, P.colptr, P.rows, P.boff, P.doff, P.rowptr, P.rowblk, P.bcol, system.l,
                           system.hdiag, tolerance)
    if bad < 0:
        _copy(system.g, delta)
        blockchol.solve(P.dims, P.soff, P.colptr, P.rows, P.boff, P.doff, system.l, delta)
    return bad


@helper_kernel
def _linearize(G, pools, losses, L, system, diagonal_damping, stats):
    """Linearize at the estimate, assemble Λ and g (and the damping's diagonal); returns the
    linear error ½Σ‖b‖² (NaN after a fault)."""
    _evaluate(G, pools, losses, _FLAGS[1], stats)
    if stats[3] == FAULT:
        return math.nan
    linear0 = 0.0
    for f in range(pools.sq.shape[0]):
        linear0 += 0.5 * pools.sq[f]
    _assemble(G, pools, L, system)
    if diagonal_damping:
        for i in range(system.hdiag.shape[0]):
            system.damping[i] = min(max(system.hdiag[i], lm.MIN_DIAGONAL), lm.MAX_DIAGONAL)
    return linear0


@helper_kernel
def _gauss_newton(G, V, pools, losses, R, X, L, system, stats):
    """One Gauss–Newton iteration (the step accepted whatever its error, as GTSAM's); returns the
    new error."""
    if not _linearize(G, pools, losses, L, system, _FLAGS[0], stats) < math.inf:
        return math.nan
    bad = _step(L, system, 0.0, PIVOT_TOLERANCE, X.delta)
    if bad >= 0:
        stats[3] = SINGULAR
        stats[5] = _variable_at(bad, V.dims, L)
        return math.nan
    _retract(R)
    new_error = _evaluate(G, pools, losses, _FLAGS[0], stats)
    if stats[3] == FAULT:
        return math.nan
    stats[0] += 1
    stats[1] += 1
    if not new_error < math.inf:
        stats[3] = NONFINITE_STEP
        return math.nan
    _copy(X.work, X.best)
    return new_error


@helper_kernel
def _levenberg_marquardt(G, pools, losses, R, X, L, system, params, error, schedule, stats):
    """One LM iteration (GTSAM's ``iterate``: linearize once, ``tryLambda`` until a step is
    accepted or LM stops); ``schedule`` [λ, its factor] is updated.  Returns the error after it."""
    lam, factor = schedule[0], schedule[1]
    upper, lower, min_fidelity, rel_tol = params[2], params[3], params[4], params[5]
    fixed = params[10] != 0.0
    linear0 = _linearize(G, pools, losses, L, system, params[9] != 0.0, stats)
    if not linear0 < math.inf:
        return error
    while True:
        success = False
        stop = False
        fidelity = 0.0
        new_error = math.inf
        if _step(L, system, lam, 0.0, X.delta) < 0:
            change = linear0 - _new_linear_error(G, pools, L, X.delta)
            if change >= 0:
                _retract(R)
                new_error = _evaluate(G, pools, losses, _FLAGS[0], stats)
                if stats[3] == FAULT:
                    break
                success, stop, fidelity = _judge(change, linear0, error, new_error, min_fidelity, rel_tol)
        if success:
            lam, factor = _after_success(lam, factor, fidelity, fixed, lower)
            stats[1] += 1
            _copy(X.work, X.best)
            error = new_error
            stats[0] += 1
            break
        if stop:
            break
        lam, factor = _after_failure(lam, factor, fixed)
        stats[1] += 1
        if lam >= upper:
            stats[7] += 1
            break
    schedule[0], schedule[1] = lam, factor
    return error


@kernel
def solve(G, V, pools, losses, R, X, arena, params, errors, lambdas, stats):
    """GTSAM's ``defaultOptimize`` of LM (or Gauss–Newton) on the problem (module docstring),
    with :class:`Groups` ``G``, :class:`Variables` ``V``, :class:`Pools`, :class:`Losses`,
    :class:`Retraction` ``R``, :class:`State` ``X`` and the :class:`Arena` of the descriptors
    (:mod:`lie_factors.batch.small_arrays`).  The step δ (n,), in the order of the supernodes, is
    what the retraction entries read, each value at its variable's offset.
    Writes ``X.best`` (the estimate), ``errors``, ``lambdas`` (max_iterations + 2,) and
    ``stats``."""
    rel_tol, abs_tol, err_tol = params[5], params[6], params[7]
    max_iterations = int(params[8])
    gauss_newton = params[11] != 0.0
    _resolve(G, R, X, pools, arena)
    L = _layout(G, V, R)
    n = L.pattern.soff[L.pattern.dims.shape[0]]
    system = _System(np.empty(L.pattern.size), np.empty(L.pattern.size), np.empty(n), np.empty(n), np.ones(n))
    schedule = np.array([params[0], params[1]])
    _fill(stats, 0)
    _copy(X.best, X.work)
    error = _evaluate(G, pools, losses, _FLAGS[0], stats)
    if stats[3] == FAULT:
        return
    errors[0] = error
    lambdas[0] = schedule[0]
    stats[6] = 1
    if not error < math.inf:
        stats[3] = NONFINITE_START
        return
    if error <= err_tol:
        stats[2] = 1
        return
    while stats[0] < max_iterations:
        current = error
        _copy(X.best, X.work)
        if gauss_newton:
            error = _gauss_newton(G, V, pools, losses, R, X, L, system, stats)
        else:
            error = _levenberg_marquardt(G, pools, losses, R, X, L, system, params, error, schedule, stats)
        if stats[3] != OK or stats[6] >= errors.shape[0]:  # (the second: tolerances that never stop)
            break
        errors[stats[6]] = error
        lambdas[stats[6]] = schedule[0]
        stats[6] += 1
        done = _converged(rel_tol, abs_tol, err_tol, current, error)
        if stats[0] >= max_iterations:
            stats[2] = 1 if done else 0
            break
        if done:
            stats[2] = 1
            break
        if not current < math.inf:
            break
