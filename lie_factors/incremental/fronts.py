"""The numeric pass of re-elimination (compiled kernels): dense fronts, assembled and factored.

Elimination is by supernodes: a variable and the chain of parents that each
have it as only child with a separator one shorter (a clique) are eliminated
from one dense *front*.  The front is assembled from the update matrices of
the first member's children (extend-add) and, member by member, from the
factors whose first variable the member is; the trailing update matrix is
computed with all of a block's rows at once.  The clique's last member keeps
its update matrix, and so does every member whose update matrix is at most
``keep_update`` floats.

A front is ``Phi`` (N, N), symmetric, its upper triangle used (its last row below the
diagonal holds, for the pivot test, the diagonal of Λ = Σ AᵀA before any elimination on the
members' columns, summed from every factor on their variables; its last column is the
right-hand side), with ``colmap`` (at least N) scratch, and ``members[:nm]`` the clique's
variables in order.  The helpers take these
arrays, and the dense eliminations are called from :func:`numeric_pass` itself (see
:mod:`~lie_factors.incremental.structures` on why).

Everything is written to fresh pool space and to the
:data:`~lie_factors.incremental.structures.Columns` of the symbolic pass
(:mod:`lie_factors.incremental.symbolic`); the tree is not touched, so a pivot
that fails leaves it as it was.
"""

from __future__ import annotations

import numpy as np
# numba's BLAS is SciPy's: the first compiled call of BLAS in a process imports scipy.linalg
# (lie_factors.kernels.blas_check).  These kernels call it inside an update, once a front is
# large: the import is made with this module, not in the middle of a robot's first large update.
import scipy.linalg.cython_blas  # noqa: F401

from ..kernels.jit import dense_kernel, inline_kernel  # dense_kernel keeps IEEE NaN, which the pivot test relies on
from ..sparse.pivots import PIVOT_TOLERANCE  # the one pivot rule, CHOLMOD's too (its docstring: why 1e-13)
from .structures import NOT_POSITIVE, OK, packed

@dense_kernel
def _row_update(Phi, i, q0, q1):
    """Φ[i, i:] −= Σ_{q0 ≤ q < q1} Φ[q, i]·Φ[q, i:] (upper triangle), four rows q at a time: the
    row of i is read and written once per four."""
    N = Phi.shape[0]
    ri = Phi[i]
    q = q0
    while q + 3 < q1:
        w0 = Phi[q, i]
        w1 = Phi[q + 1, i]
        w2 = Phi[q + 2, i]
        w3 = Phi[q + 3, i]
        r0 = Phi[q]
        r1 = Phi[q + 1]
        r2 = Phi[q + 2]
        r3 = Phi[q + 3]
        for c in range(i, N):
            ri[c] -= w0 * r0[c] + w1 * r1[c] + w2 * r2[c] + w3 * r3[c]
        q += 4
    while q < q1:
        w = Phi[q, i]
        rq = Phi[q]
        for c in range(i, N):
            ri[c] -= w * rq[c]
        q += 1


#: Fronts whose trailing update is at least this many multiply-adds (D·M², M its side)
#: and whose block has at least :data:`BLAS_MIN_COLUMNS` scalars compute it with BLAS
#: (``benchmarks/dense_fronts.py`` measured where BLAS's tiles overtake the compiled loops:
#: a block of one 6-scalar pose is a rank-6 update, bound by memory either way).
BLAS_MIN_WORK = 60_000
BLAS_MIN_COLUMNS = 12

#: OpenBLAS runs a gemm of m·n·k multiply-adds on one thread when m·n·k is at most 4·65536
#: (its GEMM_MULTITHREAD_THRESHOLD times SMP_THRESHOLD_MIN): the trailing update is cut into
#: tiles that small, since threads cost these blocks far more than they save, and several
#: times more when the machine's other cores are busy.
BLAS_SINGLE_THREAD_WORK = 4 * 65536
#: The largest side of a tile.
BLAS_TILE = 64


@inline_kernel
def uses_blas(D, M):
    """Whether eliminating D scalars from a front with M trailing scalars calls BLAS."""
    return D >= BLAS_MIN_COLUMNS and D * M * M >= BLAS_MIN_WORK


@inline_kernel
def _tile_side(D):
    """The side of the square tiles of a rank-D update that OpenBLAS runs on one thread."""
    side = BLAS_TILE
    while side > 8 and side * side * D > BLAS_SINGLE_THREAD_WORK:
        side -= 8
    return side


@dense_kernel
def _trailing_blas(Phi, o, e, Tt, G):
    """Φ[e:, e:] −= TᵀT (upper triangle), T = Φ[o:e, e:]: Tᵀ copied contiguous to ``Tt``
    (at least (N − e)·(e − o) floats), then tile by tile of the upper triangle with BLAS's
    gemm into ``G`` (at least :data:`BLAS_TILE`² floats)."""
    N = Phi.shape[0]
    D = e - o
    M = N - e
    T = Tt[:M * D].reshape((M, D))
    for q in range(D):
        row = Phi[o + q]
        for c in range(M):
            T[c, q] = row[e + c]
    side = _tile_side(D)
    for a0 in range(0, M, side):
        a1 = min(a0 + side, M)
        for b0 in range(a0, M, side):
            b1 = min(b0 + side, M)
            g = G[:(a1 - a0) * (b1 - b0)].reshape((a1 - a0, b1 - b0))
            np.dot(T[a0:a1], T[b0:b1].T, g)
            for a in range(a0, a1):
                ra = Phi[e + a]
                ga = g[a - a0]
                for b in range(max(a, b0), b1):
                    ra[e + b] -= ga[b - b0]


@dense_kernel
def eliminate_columns(Phi, o, D, blas, Tt, G):
    """Eliminate the scalars o … o + D − 1 of the symmetric frontal ``Phi`` (N × N, upper
    triangle read and written, the first o already eliminated; ``Phi[N − 1, :]`` below the
    diagonal holds the diagonal before elimination): rows o … o + D − 1 become [R | T | d]
    (R upper triangular, RᵀR = Φ₁₁, T = R⁻ᵀΦ₁₂), and the trailing upper triangle becomes the
    update matrix Φ₂₂ − [T d]ᵀ[T d].  Row by row (left-looking): each row takes the updates of
    all the pivot rows above it at once, then, if it is a pivot row, is scaled by its pivot's
    square root; with ``blas`` (:func:`uses_blas`), the trailing rows take theirs from BLAS
    (:func:`_trailing_blas`, scratch ``Tt`` and ``G``).  Returns −1, or the first pivot that
    is refused: not above :data:`PIVOT_TOLERANCE` times its entry of ``Phi[N − 1, :]``
    (:mod:`lie_factors.sparse.pivots`)."""
    N = Phi.shape[0]
    e = o + D
    for i in range(o, e if blas else N):
        _row_update(Phi, i, o, min(i, e))
        if i < e:
            a = Phi[i, i]
            if not (a > PIVOT_TOLERANCE * Phi[N - 1, i] and a < np.inf):
                return i
            r = np.sqrt(a)
            inv = 1.0 / r
            Phi[i, i] = r
            for c in range(i + 1, N):
                Phi[i, c] *= inv
    if blas:
        _trailing_blas(Phi, o, e, Tt, G)
    return -1


@inline_kernel
def _chain(j, k, nchild, parent, sep_len, aidx, chead, members):
    """The clique ``j`` (index ``k``) starts: ``j`` and the parents that each have the previous
    member as only child and nest its separator, written to ``members``; returns their count,
    0 when ``j`` is itself such a parent (its child's clique holds it).  ``nchild``,
    ``parent``, ``sep_len``: the new columns'."""
    c = chead[j]
    if nchild[k] == 1 and aidx[c] >= 0 and sep_len[aidx[c]] == sep_len[k] + 1:
        return 0
    members[0] = j
    nm = 1
    top = j
    while True:
        ti = aidx[top]
        p = parent[ti]
        if p < 0:
            break
        pi = aidx[p]
        if nchild[pi] != 1 or sep_len[ti] != sep_len[pi] + 1:
            break
        members[nm] = p
        nm += 1
        top = p
    return nm


@inline_kernel
def _locate(members, nm, s0, sl, dim, ipool, loc):
    """The front's columns (``loc``): the members' first, then those of the last member's
    separator (``ipool[s0:s0 + sl]``), then the right-hand side; returns the members' scalars D."""
    D = 0
    for q in range(nm):
        v = members[q]
        loc[v] = D
        D += dim[v]
    o = D
    for t in range(s0, s0 + sl):
        v = ipool[t]
        loc[v] = o
        o += dim[v]
    return D


@inline_kernel
def _cleared_front(scratch, N):
    """The front (N, N) at the start of ``scratch``, its upper triangle zero (all that is read
    but its last row)."""
    Phi = scratch[:N * N].reshape((N, N))
    for i in range(N):
        for c in range(i, N):
            Phi[i, c] = 0.0
    return Phi


@inline_kernel
def _separator_columns(s0, sl, ipool, dim, loc, colmap):
    """``colmap``: the front's columns of the separator ``ipool[s0:s0 + sl]``, scalar by scalar;
    returns their count."""
    cc = 0
    for t in range(s0, s0 + sl):
        v = ipool[t]
        for i in range(dim[v]):
            colmap[cc] = loc[v] + i
            cc += 1
    return cc


@inline_kernel
def _add_packed(Phi, colmap, S1, fpool, u):
    """Add the packed update matrix at ``fpool[u]`` (side ``S1``) to the front's rows and
    columns ``colmap[:S1]`` (extend-add)."""
    for a in range(S1):
        ta = colmap[a]
        for b in range(a, S1):
            tb = colmap[b]
            if ta <= tb:
                Phi[ta, tb] += fpool[u]
            else:
                Phi[tb, ta] += fpool[u]
            u += 1


@inline_kernel
def _extend_add(j, Phi, colmap, new, tree, work, pools):
    """The update matrices of ``j``'s children (re-eliminated ones from ``new``, orphans from the
    tree) added to the front.  Returns (child, count): child −1, or a child without an update
    matrix (never: such a child shares its parent's clique)."""
    new_sep_dim = new.sep_dim
    new_sep_len = new.sep_len
    new_sep_start = new.sep_start
    new_ustart = new.ustart
    fpool = pools.fpool
    ipool = pools.ipool
    dim = tree.dim
    tree_sep_dim = tree.sep_dim
    tree_sep_len = tree.sep_len
    tree_sep_start = tree.sep_start
    tree_ustart = tree.ustart
    aidx = work.aidx
    chead = work.chead
    cnext = work.cnext
    loc = work.loc
    N = Phi.shape[0]
    missing = -1
    nu = 0
    c = chead[j]
    while c >= 0 and missing < 0:
        ci = aidx[c]
        s0 = new_sep_start[ci] if ci >= 0 else tree_sep_start[c]
        sl = new_sep_len[ci] if ci >= 0 else tree_sep_len[c]
        u0 = new_ustart[ci] if ci >= 0 else tree_ustart[c]
        if u0 < 0:
            missing = c
        else:
            S1 = (new_sep_dim[ci] if ci >= 0 else tree_sep_dim[c]) + 1
            cc = _separator_columns(s0, sl, ipool, dim, loc, colmap)
            colmap[cc] = N - 1
            _add_packed(Phi, colmap, S1, fpool, u0)
            nu += 1
        c = cnext[c]
    return missing, nu


@inline_kernel
def _factor_columns(f, fvstart, fnv, fvars, dim, loc, colmap, N):
    """``colmap``: the front's columns of factor ``f``'s variables, then the right-hand side."""
    cc = 0
    for u in range(fvstart[f], fvstart[f] + fnv[f]):
        w = fvars[u]
        for i in range(dim[w]):
            colmap[cc] = loc[w] + i
            cc += 1
    colmap[cc] = N - 1


@inline_kernel
def _add_gram(J, r, D1, jac, Phi, colmap):
    """Add AᵀA (augmented with Aᵀb) of the r × D1 Jacobian at ``jac[J]`` to the front's upper
    triangle, at its columns ``colmap[:D1]``."""
    for c1 in range(D1):
        t1 = colmap[c1]
        for c2 in range(D1):
            t2 = colmap[c2]
            if t1 > t2:
                continue
            acc = 0.0
            for rr in range(r):
                acc += jac[J + rr * D1 + c1] * jac[J + rr * D1 + c2]
            Phi[t1, t2] += acc


@inline_kernel
def _assemble(t0, t1, fall, store, dim, loc, Phi, colmap):
    """Add the AᵀA (augmented with Aᵀb) of the factors ``fall[t0:t1]`` to the front's upper
    triangle."""
    fcols = store.fcols
    fjstart = store.fjstart
    fnv = store.fnv
    frows = store.frows
    fvars = store.fvars
    fvstart = store.fvstart
    jac = store.jac
    N = Phi.shape[0]
    for t in range(t0, t1):
        f = fall[t]
        _factor_columns(f, fvstart, fnv, fvars, dim, loc, colmap, N)
        _add_gram(fjstart[f], frows[f], fcols[f], jac, Phi, colmap)


@inline_kernel
def _diagonal_of(v, o, dim, store, row):
    """``row[o:o + dim[v]]`` = the diagonal of Λ = Σ AᵀA on the scalars of variable ``v``: the
    squared norms of v's columns of every factor on it (its adjacency list in ``store``), a
    factor that holds v twice counted once, its two columns added.  The denominator of the
    pivot rule, the same whatever part of Λ reaches the front through update matrices."""
    ahead = store.ahead
    anext = store.anext
    afac = store.afac
    fnv = store.fnv
    fvstart = store.fvstart
    fvars = store.fvars
    frows = store.frows
    fcols = store.fcols
    fjstart = store.fjstart
    jac = store.jac
    d = dim[v]
    for i in range(d):
        row[o + i] = 0.0
    t = ahead[v]
    while t >= 0:
        f = afac[t]
        s0 = fvstart[f]
        first = True  # the factor's first entry on v: the factor is counted there only
        for q in range(s0, t):
            if fvars[q] == v:
                first = False
        if first:
            D1 = fcols[f]
            J = fjstart[f]
            for i in range(d):
                acc = 0.0
                for r in range(frows[f]):
                    x = 0.0
                    c = 0
                    for q in range(s0, s0 + fnv[f]):
                        w = fvars[q]
                        if w == v:
                            x += jac[J + r * D1 + c + i]
                        c += dim[w]
                    acc += x * x
                row[o + i] += acc
        t = anext[t]


@inline_kernel
def _write_update(Phi, e, at, fpool):
    """The trailing update matrix Φ[e:, e:] written packed to ``fpool`` from ``at``; returns its end."""
    N = Phi.shape[0]
    for a in range(e, N):
        for b in range(a, N):
            fpool[at] = Phi[a, b]
            at += 1
    return at


@inline_kernel
def _block_end(members, nm, q0, N, dim, loc, keep_update):
    """The block of members eliminated together from ``members[q0]``: up to the first that keeps
    its update matrix (the last member always does; the others when it is at most
    ``keep_update`` floats: a later update that re-eliminates only the members above starts
    from it).  Returns (q1, e): past its last member, and past its last column."""
    e = loc[members[q0]] + dim[members[q0]]
    q = q0 + 1
    while q < nm and packed(N - e) > keep_update:
        e = loc[members[q]] + dim[members[q]]
        q += 1
    return q, e


@inline_kernel
def _write_conditionals(Phi, members, nm, ft, cond, aidx, loc, dim, fpool):
    """Each member's conditional, its rows of the front from its own columns on (zero below
    the diagonal), written to ``fpool`` from ``ft`` (its start to ``cond``); returns the end."""
    N = Phi.shape[0]
    for q in range(nm):
        v = members[q]
        o = loc[v]
        W = N - o
        cond[aidx[v]] = ft
        for p in range(dim[v]):
            for qq in range(W):
                cidx = o + qq
                fpool[ft + p * W + qq] = Phi[o + p, cidx] if cidx >= o + p else 0.0
        ft += dim[v] * W
    return ft


@inline_kernel
def _variable_of(members, nm, column, dim, loc):
    """The member whose columns hold ``column``."""
    found = -1
    for q in range(nm):
        v = members[q]
        if loc[v] <= column < loc[v] + dim[v]:
            found = v
    return found


@inline_kernel
def numeric_pass(order, new, fall, tree, pools, ftop, store, work, keep_update):
    """Eliminate ``order``'s variables clique by clique (see the module docstring), writing
    conditionals and update matrices to ``pools.fpool`` from ``ftop`` (room counted by
    :func:`~lie_factors.incremental.symbolic.float_room`) and their places to ``new``.

    Returns (status, detail, new ftop): :data:`OK`, or :data:`NOT_POSITIVE` with the variable
    whose pivot failed.  ``work.stats`` += [columns eliminated, update matrices extend-added,
    factors assembled, frontal scalars², …, Σ D·N² over fronts (the work of their dense
    elimination, in multiply-adds up to a constant), blocks whose trailing update BLAS
    computed] (entries 0–3, 6 and 7).
    """
    cond = new.cond
    fstart = new.fstart
    nchild = new.nchild
    parent = new.parent
    sep_dim = new.sep_dim
    sep_len = new.sep_len
    sep_start = new.sep_start
    ustart = new.ustart
    fpool = pools.fpool
    ipool = pools.ipool
    dim = tree.dim
    aidx = work.aidx
    chead = work.chead
    loc = work.loc
    stats = work.stats
    K = order.shape[0]
    members = np.empty(K, dtype=np.int64)
    # the fronts' arrays, reused (grown to the largest)
    scratch = np.empty(4096)
    colmap = np.empty(64, dtype=np.int64)
    Tt = np.empty(4096)
    G = np.empty(BLAS_TILE * BLAS_TILE)
    ft = ftop
    for k in range(K):
        j = order[k]
        nm = _chain(j, k, nchild, parent, sep_len, aidx, chead, members)
        if nm == 0:
            continue
        topk = aidx[members[nm - 1]]
        D = _locate(members, nm, sep_start[topk], sep_len[topk], dim, ipool, loc)
        N = D + sep_dim[topk] + 1
        need_f = packed(N - D)  # the conditionals and the last member's update matrix
        for q in range(nm):
            need_f += dim[members[q]] * (N - loc[members[q]])
        if N * N > scratch.shape[0]:
            scratch = np.empty(2 * N * N)
            Tt = np.empty(2 * N * N)
        if N > colmap.shape[0]:
            colmap = np.empty(2 * N, dtype=np.int64)
        Phi = _cleared_front(scratch, N)
        for q in range(nm):  # Λ's diagonal on the members' columns, for the pivot test
            v = members[q]
            _diagonal_of(v, loc[v], dim, store, Phi[N - 1])
        child, nu = _extend_add(j, Phi, colmap, new, tree, work, pools)
        if child >= 0:
            return NOT_POSITIVE, child, ftop
        # the members' factors assembled and their columns eliminated, block by block; a
        # member's factors enter just before its block (they touch no column before it), so
        # that each update matrix kept is its subtree's alone (those below the last from ux)
        ux = ft + need_f
        nf = 0
        b0 = 0
        q0 = 0
        while q0 < nm:
            q1, e = _block_end(members, nm, q0, N, dim, loc, keep_update)
            for q in range(q0, q1):
                mk = aidx[members[q]]
                _assemble(fstart[mk], fstart[mk + 1], fall, store, dim, loc, Phi, colmap)
                nf += fstart[mk + 1] - fstart[mk]
            blas = uses_blas(e - b0, N - e)
            bad = eliminate_columns(Phi, b0, e - b0, blas, Tt, G)
            stats[7] += blas
            if bad >= 0:
                return NOT_POSITIVE, _variable_of(members, nm, bad, dim, loc), ftop
            if q1 < nm:
                ustart[aidx[members[q1 - 1]]] = ux
                ux = _write_update(Phi, e, ux, fpool)
            b0 = e
            q0 = q1
        ft = _write_conditionals(Phi, members, nm, ft, cond, aidx, loc, dim, fpool)
        ustart[topk] = ft
        _write_update(Phi, D, ft, fpool)
        ft = ux
        stats[0] += nm
        stats[1] += nu
        stats[2] += nf
        stats[3] += N * N
        stats[6] += D * N * N
    return OK, 0, ft
