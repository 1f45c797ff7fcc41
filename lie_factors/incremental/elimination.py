"""Compiled kernels of the incremental block factor: marking, re-elimination, back-substitution.

The factor is a tree of block columns (an elimination tree with one node per
variable, ISAM2's Bayes tree at the granularity of variables).  Node ``j`` holds

- its *separator* ``S_j``: the variables after ``j`` in the elimination order
  whose rows of ``L`` are nonzero in column ``j`` (ids in ``ipool``, sorted by
  position);
- its *conditional* ``[R_j | T_j | d_j]`` (d × (d + s + 1), row-major in
  ``fpool``): ``R_j δ_j + T_j δ_S = d_j``, with ``R_jᵀ`` the diagonal block of
  ``L`` and ``T_jᵀ`` the block column below it (``L = Rᵀ``);
- its *update matrix* ``U_j`` ((s + 1) × (s + 1), augmented with the right-hand side,
  stored as its upper triangle row by row, :func:`packed` floats):
  the Schur complement its subtree passes to its ancestors, the multifrontal
  update matrix (Duff and Reid, "The multifrontal solution of indefinite sparse
  symmetric linear equations", ACM TOMS 1983; ISAM2's cached marginal factor,
  Kaess et al., "iSAM2", IJRR 2012, Alg. 4).  It is kept where a later update
  can re-eliminate the parent without the node: the subtree below is then not
  visited again.

Positions are increasing integers: an update gives the re-eliminated
variables positions after every other, so a node's ancestors always come
after it.  Shapes: ``V`` variable capacity, ``F`` factor capacity.

Factors are stored as whitened Jacobians ``[A_1 … A_k | b]`` (r × (D + 1),
row-major in ``jac``), the rows ``A δ ≈ b`` of one factor; a factor enters the
frontal matrix of its first variable in the order.
"""

from __future__ import annotations

import numpy as np

from ..kernels.jit import dense_kernel, kernel  # dense_kernel keeps IEEE NaN, which the pivot test relies on

#: Status codes of :func:`reeliminate`.
OK, NEED_INT, NEED_FLOAT, NOT_POSITIVE = 0, 1, 2, 3

#: A clique member below the last keeps its update matrix (augmented, packed floats) when it
#: is at most this large (a side of 64): an update that re-eliminates only the members above
#: it then starts from it (an odometry step re-eliminates the newest pose alone, not the
#: whole root clique), at the price of that memory.
KEEP_UPDATE = 64 * 65 // 2

#: A pivot is refused when it is not above this fraction of its diagonal entry before
#: elimination (a pivot is 1/(Λ⁻¹)_pp in units of Λ_pp: this refuses a condition number
#: above 1e13, where the variable is not determined to double precision).
PIVOT_TOLERANCE = 1e-13


# --------------------------------------------------------------------------- marking

@kernel
def packed(S1):
    """Entries of an update matrix of side ``S1`` stored as its upper triangle, row by row."""
    return S1 * (S1 + 1) // 2


@kernel
def _push(buf, n, v):
    """buf[n] = v, in ``buf`` or in a copy of twice its size when it is full (the caller keeps
    the array returned)."""
    if n == buf.shape[0]:
        grown = np.empty(2 * n + 16, dtype=buf.dtype)
        grown[:n] = buf
        buf = grown
    buf[n] = v
    return buf


@kernel
def _has(ipool, start, length, v):
    for q in range(start, start + length):
        if ipool[q] == v:
            return True
    return False


@kernel
def mark_affected(marked, relin, parent, first, nxt, nchild, sep_start, sep_len, ustart, ipool,
                  flag, out_affected, out_orphans):
    """The variables to re-eliminate and the subtrees hanging from them.

    ``marked`` (M,): variables of new factors (and new variables); ``relin`` (Q,):
    relinearized variables, whose every factor changes: the nodes whose
    separator holds one (its row subtree, ISAM2's ``findAll``) are marked too.
    Then every ancestor of a marked node, and the only child of an affected
    node when its separator is the parent's plus the parent (the two share a
    clique; the child keeps no update matrix).  ``flag`` (V,) zero on entry,
    zero on return.  Writes ``out_affected``/``out_orphans``; returns their counts.
    """
    na = 0
    stack = np.empty(16, dtype=np.int64)
    # row subtrees of the relinearized variables
    for q in range(relin.shape[0]):
        r = relin[q]
        top = 0
        c = first[r]
        while c >= 0:
            stack = _push(stack, top, c)
            top += 1
            c = nxt[c]
        while top > 0:
            top -= 1
            j = stack[top]
            if not _has(ipool, sep_start[j], sep_len[j], r):
                continue
            if flag[j] == 0:
                flag[j] = 1
                out_affected[na] = j
                na += 1
            c = first[j]
            while c >= 0:
                stack = _push(stack, top, c)
                top += 1
                c = nxt[c]
    for lst in (marked, relin):
        for q in range(lst.shape[0]):
            j = lst[q]
            if flag[j] == 0:
                flag[j] = 1
                out_affected[na] = j
                na += 1
    # ancestors
    n0 = na
    for q in range(n0):
        j = parent[out_affected[q]]
        while j >= 0 and flag[j] == 0:
            flag[j] = 1
            out_affected[na] = j
            na += 1
            j = parent[j]
    # clique members below an affected node
    q = 0
    while q < na:
        p = out_affected[q]
        q += 1
        if nchild[p] == 1:
            c = first[p]
            if flag[c] == 0 and ustart[c] < 0:
                flag[c] = 1
                out_affected[na] = c
                na += 1
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


@kernel
def ordering_graph(affected, orphans, fnv, fvstart, fvars, ahead, anext, afac, sep_start, sep_len,
                   ipool, flag, fstamp, stamp, out_ptr, out_vars):
    """The graph the affected variables are ordered on: every factor whose variables are all
    affected, every orphan's separator (a clique), and each affected variable in neither alone.  Lists in ``out_ptr``/``out_vars``
    (CSR); returns (lists, entries).  ``flag`` (V,) zero on entry and return; ``fstamp``
    (F,) holds factor stamps below ``stamp``."""
    for q in range(affected.shape[0]):
        flag[affected[q]] = 1
    n = 0
    m = 0
    out_ptr[0] = 0
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


# --------------------------------------------------------------------------- re-elimination

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


@dense_kernel
def _eliminate_columns(Phi, o, D):
    """Eliminate the scalars o … o + D − 1 of the symmetric frontal ``Phi`` (N × N, upper
    triangle read and written, the first o already eliminated; ``Phi[N − 1, :]`` below the
    diagonal holds the diagonal before elimination): rows o … o + D − 1 become [R | T | d]
    (R upper triangular, RᵀR = Φ₁₁, T = R⁻ᵀΦ₁₂), and the trailing upper triangle becomes the
    update matrix Φ₂₂ − [T d]ᵀ[T d].  Row by row (left-looking): each row takes the updates of
    all the pivot rows above it at once, then, if it is a pivot row, is scaled by its pivot's
    square root.  Returns −1, or the first pivot that is not positive (relative to
    :data:`PIVOT_TOLERANCE`)."""
    N = Phi.shape[0]
    e = o + D
    for i in range(o, N):
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
    return -1


@dense_kernel
def reeliminate(order, orphans, base,
                dim, pos, parent, first, nxt, nchild, sep_start, sep_len, sep_dim, cond, ustart,
                roots, ipool, itop, fpool, ftop,
                fnv, fvstart, fvars, frows, fjstart, fcols, jac, ahead, anext, afac,
                aidx, mark, stamps, loc, chead, cnext, stats, keep_update):
    """Re-eliminate the variables ``order`` (in that order, given positions ``base``, ``base`` + 1, …)
    on top of the subtrees ``orphans`` (their update matrices cached).

    First the symbolic pass (each variable's separator: its factors' later variables and its
    children's separators), then the numeric one by supernodes: a variable and the chain of
    parents that each have it as only child with the separator one shorter (a clique) are
    eliminated from one dense front, assembled from their factors and the update matrices of
    the first one's children; only the last member keeps its update matrix.

    New separators, conditionals and update matrices are written past ``itop``/``ftop``
    in the pools; the nodes' arrays are only written once every variable has
    been eliminated, so a refusal leaves the factor as it was (positions are
    restored).  Returns (status, detail, new itop, new ftop): status
    :data:`OK`; :data:`NEED_INT`/:data:`NEED_FLOAT` with a pool size to grow to
    before calling again (the floats are counted exactly after the symbolic pass); :data:`NOT_POSITIVE` with the variable whose
    pivot failed.  ``aidx`` (V,) −1 on entry and return; ``mark``, ``loc``,
    ``chead``, ``cnext`` (V,) scratch; ``stamps[0]``: the last mark used (above
    every entry of ``mark``).  ``keep_update``: a clique member below the last keeps an
    update matrix of at most this many floats (:data:`KEEP_UPDATE`).  ``stats`` (6,): += [columns eliminated, update matrices
    extend-added, factors assembled, frontal scalars², pool floats freed, pool ints freed,
    Σ D·N² over fronts (the work of their dense elimination, in multiply-adds up to a constant)].
    """
    K = order.shape[0]
    old_pos = np.empty(K, dtype=np.int64)
    for k in range(K):
        j = order[k]
        old_pos[k] = pos[j]
        pos[j] = base + k
        aidx[j] = k
        chead[j] = -1
    t_parent = np.empty(K, dtype=np.int64)
    t_sep = np.empty(K, dtype=np.int64)
    t_len = np.empty(K, dtype=np.int64)
    t_sdim = np.empty(K, dtype=np.int64)
    t_cond = np.empty(K, dtype=np.int64)
    t_u = np.full(K, -1, dtype=np.int64)
    t_nch = np.zeros(K, dtype=np.int64)
    f_start = np.empty(K + 1, dtype=np.int64)
    fall = np.empty(16, dtype=np.int64)
    nfall = 0
    new_roots = -1
    # orphans hang from the first of their separator's variables in the new order
    o_parent = np.empty(orphans.shape[0], dtype=np.int64)
    for q in range(orphans.shape[0]):
        o = orphans[q]
        best = -1
        for t in range(sep_start[o], sep_start[o] + sep_len[o]):
            v = ipool[t]
            if best < 0 or pos[v] < pos[best]:
                best = v
        o_parent[q] = best
        cnext[o] = chead[best]
        chead[best] = o
        t_nch[aidx[best]] += 1
    it = itop
    sbuf = np.empty(64, dtype=np.int64)
    status = OK
    detail = 0
    stamp = stamps[0]
    # ---- symbolic pass
    for k in range(K):
        j = order[k]
        stamp += 1
        mark[j] = stamp
        ns = 0
        f_start[k] = nfall
        # factors whose first variable is j
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
            fall = _push(fall, nfall, f)
            nfall += 1
            for t in range(fvstart[f], fvstart[f] + fnv[f]):
                v = fvars[t]
                if mark[v] != stamp:
                    mark[v] = stamp
                    sbuf = _push(sbuf, ns, v)
                    ns += 1
        # children's separators
        c = chead[j]
        while c >= 0:
            ci = aidx[c]
            s0 = t_sep[ci] if ci >= 0 else sep_start[c]
            sl = t_len[ci] if ci >= 0 else sep_len[c]
            for t in range(s0, s0 + sl):
                v = ipool[t]
                if mark[v] != stamp:
                    mark[v] = stamp
                    sbuf = _push(sbuf, ns, v)
                    ns += 1
            c = cnext[c]
        _sort_by(pos, sbuf, ns)
        if it + ns > ipool.shape[0]:
            status = NEED_INT
            detail = max(2 * ipool.shape[0], it + ns)
            break
        s = 0
        for q in range(ns):
            ipool[it + q] = sbuf[q]
            s += dim[sbuf[q]]
        t_sep[k] = it
        t_len[k] = ns
        t_sdim[k] = s
        it += ns
        # this node hangs from the first variable of its separator
        if ns > 0:
            p = sbuf[0]
            t_parent[k] = p
            cnext[j] = chead[p]
            chead[p] = j
            t_nch[aidx[p]] += 1
        else:
            t_parent[k] = -1
            cnext[j] = new_roots
            new_roots = j
    f_start[K] = nfall
    stamps[0] = stamp
    if status == OK:
        # the floats the numeric pass writes: every conditional, the update matrix of every
        # clique's last member and of the members that keep theirs
        need = 0
        for k in range(K):
            d = dim[order[k]]
            S1 = t_sdim[k] + 1
            need += d * (d + S1)
            p = t_parent[k]
            top = p < 0 or t_nch[aidx[p]] != 1 or t_len[k] != t_len[aidx[p]] + 1
            if top or packed(S1) <= keep_update:
                need += packed(S1)
        if ftop + need > fpool.shape[0]:
            status = NEED_FLOAT
            detail = ftop + need
    # ---- numeric pass, one supernode at a time
    ft = ftop
    colmap = np.empty(64, dtype=np.int64)
    members = np.empty(16, dtype=np.int64)
    scratch = np.empty(4096)  # the fronts, reused (grown to the largest)
    if status == OK:
        for k in range(K):
            j = order[k]
            # a member of the supernode of its parent's chain is eliminated with the chain's first
            c = chead[j]
            if t_nch[k] == 1 and aidx[c] >= 0 and t_len[aidx[c]] == t_len[k] + 1:
                continue
            # the chain j → parent → … while the parent has j as only child and nests its separator
            nm = 0
            members = _push(members, nm, j)
            nm += 1
            top = j
            while True:
                ti = aidx[top]
                p = t_parent[ti]
                if p < 0:
                    break
                pi = aidx[p]
                if t_nch[pi] != 1 or t_len[ti] != t_len[pi] + 1:
                    break
                members = _push(members, nm, p)
                nm += 1
                top = p
            topk = aidx[top]
            D = 0
            for q in range(nm):
                v = members[q]
                loc[v] = D
                D += dim[v]
            s = t_sdim[topk]
            o = D
            for t in range(t_sep[topk], t_sep[topk] + t_len[topk]):
                v = ipool[t]
                loc[v] = o
                o += dim[v]
            N = D + s + 1
            need_f = packed(s + 1)
            for q in range(nm):
                need_f += dim[members[q]] * (N - loc[members[q]])
            if N * N + N > scratch.shape[0]:
                scratch = np.empty(2 * (N * N + N))
            Phi = scratch[:N * N].reshape((N, N))
            for i in range(N):  # the upper triangle is all that is read
                for c in range(i, N):
                    Phi[i, c] = 0.0
            scratch[N * N:N * N + N] = 0.0
            diag0 = scratch[N * N:N * N + N]  # the diagonal as assembled, for the pivot test
            # the update matrices of the first member's children (extend-add)
            nu = 0
            c = chead[j]
            while c >= 0:
                ci = aidx[c]
                s0 = t_sep[ci] if ci >= 0 else sep_start[c]
                sl = t_len[ci] if ci >= 0 else sep_len[c]
                u0 = t_u[ci] if ci >= 0 else ustart[c]
                if u0 < 0:
                    # never: a child without an update matrix shares its parent's clique
                    status = NOT_POSITIVE
                    detail = c
                    break
                S1 = (t_sdim[ci] if ci >= 0 else sep_dim[c]) + 1
                if S1 > colmap.shape[0]:
                    colmap = np.empty(2 * S1, dtype=np.int64)
                cc = 0
                for t in range(s0, s0 + sl):
                    v = ipool[t]
                    for i in range(dim[v]):
                        colmap[cc] = loc[v] + i
                        cc += 1
                colmap[cc] = N - 1
                u = u0
                for a in range(S1):
                    ta = colmap[a]
                    diag0[ta] += fpool[u]
                    for b in range(a, S1):
                        tb = colmap[b]
                        if ta <= tb:
                            Phi[ta, tb] += fpool[u]
                        else:
                            Phi[tb, ta] += fpool[u]
                        u += 1
                nu += 1
                c = cnext[c]
            if status != OK:
                break
            # members in blocks, each ending at a member that keeps its update matrix (the last
            # always does; the others when it is small: a later update that re-eliminates only
            # the members above starts from it).  A member's factors enter just before its block
            # (they touch no column before it), so that each update matrix kept is its subtree's
            # alone.  The members' update matrices are stored past the top's.
            ux = ft + need_f
            b0 = 0
            bad = -1
            nf = 0
            for q in range(nm):
                v = members[q]
                mk = aidx[v]
                for t in range(f_start[mk], f_start[mk + 1]):
                    f = fall[t]
                    nf += 1
                    D1 = fcols[f]
                    if D1 > colmap.shape[0]:
                        colmap = np.empty(2 * D1, dtype=np.int64)
                    cc = 0
                    for u in range(fvstart[f], fvstart[f] + fnv[f]):
                        w = fvars[u]
                        for i in range(dim[w]):
                            colmap[cc] = loc[w] + i
                            cc += 1
                    colmap[cc] = N - 1
                    J0 = fjstart[f]
                    r = frows[f]
                    for c1 in range(D1):
                        t1 = colmap[c1]
                        for c2 in range(D1):
                            t2 = colmap[c2]
                            if t1 > t2:
                                continue
                            acc = 0.0
                            for rr in range(r):
                                acc += jac[J0 + rr * D1 + c1] * jac[J0 + rr * D1 + c2]
                            Phi[t1, t2] += acc
                            if t1 == t2:
                                diag0[t1] += acc
                e = loc[v] + dim[v]
                sq = N - e
                last = q == nm - 1
                if not last and packed(sq) > keep_update:
                    continue
                for p in range(b0, e):
                    Phi[N - 1, p] = diag0[p]
                bad = _eliminate_columns(Phi, b0, e - b0)
                if bad >= 0:
                    break
                b0 = e
                if not last:
                    t_u[mk] = ux
                    for a in range(sq):
                        for b in range(a, sq):
                            fpool[ux] = Phi[e + a, e + b]
                            ux += 1
            if bad >= 0:
                status = NOT_POSITIVE
                for q in range(nm):
                    v = members[q]
                    if loc[v] <= bad < loc[v] + dim[v]:
                        detail = v
                break
            # conditionals: member q's rows, from its own columns on
            for q in range(nm):
                v = members[q]
                o = loc[v]
                W = N - o
                t_cond[aidx[v]] = ft
                for p in range(dim[v]):
                    for qq in range(W):
                        cidx = o + qq
                        fpool[ft + p * W + qq] = Phi[o + p, cidx] if cidx >= o + p else 0.0
                ft += dim[v] * W
            S1 = s + 1
            t_u[topk] = ft
            for a in range(S1):
                for b in range(a, S1):
                    fpool[ft] = Phi[D + a, D + b]
                    ft += 1
            ft = ux
            stats[0] += nm
            stats[1] += nu
            stats[2] += nf
            stats[3] += N * N
            stats[6] += D * N * N
    if status != OK:
        for k in range(K):
            j = order[k]
            pos[j] = old_pos[k]
            aidx[j] = -1
        return status, detail, itop, ftop
    # commit: the old roots that were not re-eliminated stay roots
    r = roots[0]
    kept = -1
    while r >= 0:
        following = nxt[r]
        if aidx[r] < 0:
            nxt[r] = kept
            kept = r
        r = following
    for q in range(orphans.shape[0]):
        o = orphans[q]
        nxt[o] = cnext[o]
        parent[o] = o_parent[q]
    for k in range(K):
        j = order[k]
        if cond[j] >= 0:
            stats[4] += dim[j] * (dim[j] + sep_dim[j] + 1)
            stats[5] += sep_len[j]
        if ustart[j] >= 0:
            stats[4] += packed(sep_dim[j] + 1)
        parent[j] = t_parent[k]
        sep_start[j] = t_sep[k]
        sep_len[j] = t_len[k]
        sep_dim[j] = t_sdim[k]
        cond[j] = t_cond[k]
        ustart[j] = t_u[k]
        first[j] = chead[j]
        nxt[j] = cnext[j]
        nchild[j] = t_nch[k]
        aidx[j] = -1
    # prepend the new roots to the kept ones
    r = new_roots
    last = -1
    while r >= 0:
        last = r
        r = nxt[r]
    if last >= 0:
        nxt[last] = kept
        roots[0] = new_roots
    else:
        roots[0] = kept
    return OK, 0, it, ft


# --------------------------------------------------------------------------- solving

@dense_kernel
def _solve_node(j, dim, voff, sep_start, sep_len, cond, ipool, fpool, delta, x, xs):
    """x = R_j⁻¹ (d_j − T_j δ_S): the node's variable given its separator's values in ``delta``
    (gathered once into ``xs``, so that each row is one contiguous dot product)."""
    d = dim[j]
    c0 = cond[j]
    s = 0
    for t in range(sep_start[j], sep_start[j] + sep_len[j]):
        v = ipool[t]
        o = voff[v]
        for i in range(dim[v]):
            xs[s] = delta[o + i]
            s += 1
    N = d + s + 1
    for p in range(d):
        row = c0 + p * N + d
        acc = fpool[c0 + p * N + N - 1]
        for k in range(s):
            acc -= fpool[row + k] * xs[k]
        x[p] = acc
    for p in range(d - 1, -1, -1):
        acc = x[p]
        for q in range(p + 1, d):
            acc -= fpool[c0 + p * N + q] * x[q]
        x[p] = acc / fpool[c0 + p * N + p]


@dense_kernel
def back_substitute(threshold, replaced, changed, roots, first, nxt, dim, voff, sep_start, sep_len, sep_dim,
                    cond, ipool, fpool, delta, visited):
    """ISAM2's wildfire back-substitution (Kaess et al., IJRR 2012, Alg. 5), from the roots down.

    A node is solved again when it was re-eliminated (``replaced``) or a variable
    of its separator changed; its new value is kept, and the node counts as
    changed, when it was re-eliminated or moved by ``threshold`` or more (max
    norm), else its old value stays.  Children are visited below solved nodes only.
    ``threshold`` ≤ 0: every change propagates (the exact solution).  ``replaced``
    and ``changed`` (V,) are cleared on return (every re-eliminated node is below a
    re-eliminated root, so all are visited); ``visited`` (V,) scratch.
    Returns the number of nodes solved.
    """
    x = np.empty(64)
    xs = np.empty(256)
    pending = np.empty(64, dtype=np.int64)
    npend = 0
    r = roots[0]
    while r >= 0:
        pending = _push(pending, npend, r)
        npend += 1
        r = nxt[r]
    solved = 0
    cleared = 0
    while npend > 0:
        npend -= 1
        j = pending[npend]
        dirty = replaced[j] != 0
        if not dirty:
            for t in range(sep_start[j], sep_start[j] + sep_len[j]):
                if changed[ipool[t]] != 0:
                    dirty = True
                    break
        if not dirty:
            continue
        d = dim[j]
        if d > x.shape[0]:
            x = np.empty(2 * d)
        if sep_dim[j] > xs.shape[0]:
            xs = np.empty(2 * sep_dim[j])
        _solve_node(j, dim, voff, sep_start, sep_len, cond, ipool, fpool, delta, x, xs)
        solved += 1
        o = voff[j]
        keep = replaced[j] != 0
        if not keep:
            m = 0.0
            for p in range(d):
                a = abs(x[p] - delta[o + p])
                if a > m:
                    m = a
            keep = m >= threshold
        if keep:
            for p in range(d):
                delta[o + p] = x[p]
            changed[j] = 1
            visited[cleared] = j
            cleared += 1
        replaced[j] = 0
        c = first[j]
        while c >= 0:
            pending = _push(pending, npend, c)
            npend += 1
            c = nxt[c]
    for q in range(cleared):
        changed[visited[q]] = 0
    return solved


@kernel
def clear_flags(flags, idx):
    for q in range(idx.shape[0]):
        flags[idx[q]] = 0


@kernel
def marginal_information_root_path(v, parent, dim, voff, sep_start, sep_len, cond, ipool, fpool, out):
    """Σ_v = YᵀY with Y = R⁻ᵀ E_v, nonzero only on the path from ``v`` to its root
    (``out`` (d_v, d_v) receives the marginal covariance of ``v``).

    Forward substitution Rᵀ Y = E_v visiting only that path: a node's rows of Y
    take the contributions of the path nodes below it through their blocks T."""
    dv = dim[v]
    # path from v to the root
    plen = 0
    j = v
    while j >= 0:
        plen += 1
        j = parent[j]
    path = np.empty(plen, dtype=np.int64)
    j = v
    q = 0
    while j >= 0:
        path[q] = j
        q += 1
        j = parent[j]
    # Y rows of each path node, (d_j, dv), accumulated right-hand side first
    tot = 0
    start = np.empty(plen, dtype=np.int64)
    for q in range(plen):
        start[q] = tot
        tot += dim[path[q]]
    Y = np.zeros((tot, dv))
    where = {}
    for q in range(plen):
        where[path[q]] = q
    for i in range(dv):
        Y[i, i] = 1.0
    for q in range(plen):
        j = path[q]
        d = dim[j]
        c0 = cond[j]
        s = 0
        for t in range(sep_start[j], sep_start[j] + sep_len[j]):
            s += dim[ipool[t]]
        N = d + s + 1
        y0 = start[q]
        # Y_j = R_j⁻ᵀ (E_j − contributions already subtracted)
        for col in range(dv):
            for p in range(d):
                acc = Y[y0 + p, col]
                for t in range(p):
                    acc -= fpool[c0 + t * N + p] * Y[y0 + t, col]
                Y[y0 + p, col] = acc / fpool[c0 + p * N + p]
        # push T_jᵀ Y_j down to the separator's rows (all on the path)
        cc = d
        for t in range(sep_start[j], sep_start[j] + sep_len[j]):
            w = ipool[t]
            dw = dim[w]
            if w in where:
                yw = start[where[w]]
                for i in range(dw):
                    for col in range(dv):
                        acc = 0.0
                        for p in range(d):
                            acc += fpool[c0 + p * N + cc + i] * Y[y0 + p, col]
                        Y[yw + i, col] -= acc
            cc += dw
    for a in range(dv):
        for b in range(dv):
            acc = 0.0
            for r in range(tot):
                acc += Y[r, a] * Y[r, b]
            out[a, b] = acc


# --------------------------------------------------------------------------- storage

@kernel
def link_adjacency(ahead, anext, afac, fvars, fnv, fvstart, f0, f1):
    """Prepend factors f0..f1-1 to their variables' adjacency lists (entry t of fvars is entry t)."""
    for f in range(f0, f1):
        for t in range(fvstart[f], fvstart[f] + fnv[f]):
            v = fvars[t]
            afac[t] = f
            anext[t] = ahead[v]
            ahead[v] = t


@kernel
def _move_down(pool, segments, starts, sizes, order):
    """Move the segments of ``pool`` (``starts``, ``sizes``) down to be contiguous, in order of
    address (each moves to where it is or below, over entries already moved or freed);
    ``segments[k]`` receives segment k's new start.  Returns the new top."""
    top = 0
    for q in range(order.shape[0]):
        k = order[q]
        s0 = starts[k]
        for t in range(sizes[k]):
            pool[top + t] = pool[s0 + t]
        segments[k] = top
        top += sizes[k]
    return top


@kernel
def compact_pools(nv, dim, sep_start, sep_len, sep_dim, cond, ustart, ipool, fpool):
    """Move every node's separator, conditional and update matrix down over the freed entries of
    the pools, in place, and point the node there; returns the new tops."""
    # separators
    starts = np.empty(nv, dtype=np.int64)
    sizes = np.empty(nv, dtype=np.int64)
    nodes = np.empty(nv, dtype=np.int64)
    n = 0
    for j in range(nv):
        if cond[j] >= 0 and sep_len[j] > 0:
            starts[n] = sep_start[j]
            sizes[n] = sep_len[j]
            nodes[n] = j
            n += 1
    moved = np.empty(n, dtype=np.int64)
    it = _move_down(ipool, moved, starts[:n], sizes[:n], np.argsort(starts[:n]))
    for k in range(n):
        sep_start[nodes[k]] = moved[k]
    # conditionals and update matrices
    starts = np.empty(2 * nv, dtype=np.int64)
    sizes = np.empty(2 * nv, dtype=np.int64)
    nodes = np.empty(2 * nv, dtype=np.int64)
    n = 0
    for j in range(nv):
        s = sep_dim[j]
        if cond[j] >= 0:
            starts[n] = cond[j]
            sizes[n] = dim[j] * (dim[j] + s + 1)
            nodes[n] = j
            n += 1
        if ustart[j] >= 0:
            starts[n] = ustart[j]
            sizes[n] = packed(s + 1)
            nodes[n] = -1 - j
            n += 1
    moved = np.empty(n, dtype=np.int64)
    ft = _move_down(fpool, moved, starts[:n], sizes[:n], np.argsort(starts[:n]))
    for k in range(n):
        j = nodes[k]
        if j >= 0:
            cond[j] = moved[k]
        else:
            ustart[-1 - j] = moved[k]
    return it, ft


@kernel
def factors_of(variables, ahead, anext, afac, nf):
    """The factors on any of ``variables``, each once, in increasing order."""
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


@kernel
def max_abs_blocks(delta, voff, dim):
    """max_i |δ_v[i]| of every variable v: (V,)."""
    V = voff.shape[0]
    out = np.empty(V)
    for v in range(V):
        m = 0.0
        for i in range(dim[v]):
            a = abs(delta[voff[v] + i])
            if a > m:
                m = a
        out[v] = m
    return out


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
def init_variables(nv0, dims, ns0, dim, voff, parent, first, nxt, nchild, sep_len, sep_dim, cond, ustart, ahead,
                   delta):
    """Variables nv0, nv0 + 1, … of dimensions ``dims``: no node yet, no factor, δ = 0, scalar
    offsets from ``ns0``; returns the new scalar count."""
    o = ns0
    for q in range(dims.shape[0]):
        j = nv0 + q
        dim[j] = dims[q]
        voff[j] = o
        for i in range(dims[q]):
            delta[o + i] = 0.0
        o += dims[q]
        parent[j] = -1
        first[j] = -1
        nxt[j] = -1
        nchild[j] = 0
        sep_len[j] = 0
        sep_dim[j] = 0
        cond[j] = -1
        ustart[j] = -1
        ahead[j] = -1
    return o


@kernel
def append_factors(fv, J, nf, nfv, njac, fnv, fvstart, fvars, frows, fcols, fjstart, jac, fstamp):
    """Factors nf, nf + 1, … on the variables ``fv`` (F, k) with Jacobians ``J`` (F, r, D + 1),
    stored from ``nfv`` in ``fvars`` and ``njac`` in ``jac``."""
    F, k = fv.shape
    r, D1 = J.shape[1], J.shape[2]
    for q in range(F):
        f = nf + q
        fnv[f] = k
        fvstart[f] = nfv + q * k
        for t in range(k):
            fvars[nfv + q * k + t] = fv[q, t]
        frows[f] = r
        fcols[f] = D1
        fjstart[f] = njac + q * r * D1
        for a in range(r):
            for b in range(D1):
                jac[njac + q * r * D1 + a * D1 + b] = J[q, a, b]
        fstamp[f] = 0
