"""Solving with the block factor (compiled kernels): wildfire back-substitution and marginal covariances.

δ = Λ⁻¹η is brought up to date by ISAM2's wildfire back-substitution from the
roots (:func:`back_substitute`); the marginal covariance of a variable is read
from the path of its column to its root (:func:`marginal_covariance`).
Structures: :mod:`lie_factors.incremental.structures`.
"""

from __future__ import annotations

import numpy as np

from ..kernels.jit import dense_kernel, inline_kernel, kernel


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


@inline_kernel
def _push_list(pending, npend, head, nxt):
    """Push the list ``head``, ``nxt[head]``, … (children or roots) on the stack (room for every
    node); returns its new height."""
    c = head
    while c >= 0:
        pending[npend] = c
        npend += 1
        c = nxt[c]
    return npend


@inline_kernel
def _dirty(j, sep_start, sep_len, ipool, replaced, changed):
    """Whether node ``j`` was re-eliminated or a variable of its separator changed."""
    if replaced[j] != 0:
        return True
    for t in range(sep_start[j], sep_start[j] + sep_len[j]):
        if changed[ipool[t]] != 0:
            return True
    return False


@inline_kernel
def _moved(x, delta, o, d):
    """max_p |x[p] − δ[o + p]|: how far a solved node moved."""
    m = 0.0
    for p in range(d):
        a = abs(x[p] - delta[o + p])
        if a > m:
            m = a
    return m


@dense_kernel
def back_substitute(threshold, tree, pools, delta, wildfire):
    """ISAM2's wildfire back-substitution (Kaess et al., IJRR 2012, Alg. 5), from the roots down.

    A node is solved again when it was re-eliminated (``wildfire.replaced``) or a variable
    of its separator changed; it counts as changed, and its children are solved again, when
    it was re-eliminated or moved by ``threshold`` or more (max norm).  Its new value is kept
    either way, as GTSAM's ISAM2 keeps it (``ISAM2Clique::restoreFromOriginals`` writes the
    old values to a copy): the paper's rule, which puts the old value back, leaves δ a
    threshold off at every level it stops, and an online run that starts each new variable
    at the estimate feeds that error back (a 1 000-pose chain then ends tenths away from the
    exact back-substitution's, GTSAM's 1e-3).  Children are visited below solved nodes only.
    ``threshold`` ≤ 0: every change propagates (the exact solution).  ``replaced``
    and ``changed`` are cleared on return (every re-eliminated node is below a
    re-eliminated root, so all are visited).  Returns the number of nodes solved.
    """
    fpool = pools.fpool
    ipool = pools.ipool
    cond = tree.cond
    dim = tree.dim
    first = tree.first
    nxt = tree.nxt
    roots = tree.roots
    sep_dim = tree.sep_dim
    voff = tree.voff
    x = np.empty(64)
    xs = np.empty(256)
    replaced = wildfire.replaced
    changed = wildfire.changed
    visited = wildfire.visited
    sep_len = tree.sep_len
    sep_start = tree.sep_start
    # each node is pushed once at most: a stack that never grows
    pending = np.empty(dim.shape[0], dtype=np.int64)
    npend = _push_list(pending, 0, roots[0], nxt)
    solved = 0
    cleared = 0
    while npend > 0:
        npend -= 1
        j = pending[npend]
        if not _dirty(j, sep_start, sep_len, ipool, replaced, changed):
            continue
        d = dim[j]
        if d > x.shape[0]:
            x = np.empty(2 * d)
        if sep_dim[j] > xs.shape[0]:
            xs = np.empty(2 * sep_dim[j])
        _solve_node(j, dim, voff, sep_start, sep_len, cond, ipool, fpool, delta, x, xs)
        solved += 1
        o = voff[j]
        if replaced[j] != 0 or _moved(x, delta, o, d) >= threshold:
            changed[j] = 1
            visited[cleared] = j
            cleared += 1
        for p in range(d):
            delta[o + p] = x[p]
        replaced[j] = 0
        npend = _push_list(pending, npend, first[j], nxt)
    for q in range(cleared):
        changed[visited[q]] = 0
    return solved


@inline_kernel
def _forward_node(q, path, start, where, Y, tree, pools):
    """Node ``path[q]``'s rows of Y = R⁻ᵀ(B − the contributions already subtracted), then Tᵀ
    times them subtracted from the rows of its separator (all in ``path``, its ancestors);
    ``where[j]``: node j's place in ``path``, −1 off it."""
    cond = tree.cond
    sep_len = tree.sep_len
    sep_start = tree.sep_start
    dim, ipool, fpool = tree.dim, pools.ipool, pools.fpool
    dv = Y.shape[1]
    j = path[q]
    d = dim[j]
    c0 = cond[j]
    s = 0
    for t in range(sep_start[j], sep_start[j] + sep_len[j]):
        s += dim[ipool[t]]
    N = d + s + 1
    y0 = start[q]
    # row by row, each a contiguous loop over Y's columns (numba vectorizes it)
    for p in range(d):
        for t in range(p):
            f = fpool[c0 + t * N + p]
            for col in range(dv):
                Y[y0 + p, col] -= f * Y[y0 + t, col]
        f = fpool[c0 + p * N + p]
        for col in range(dv):
            Y[y0 + p, col] /= f
    cc = d
    for t in range(sep_start[j], sep_start[j] + sep_len[j]):
        w = ipool[t]
        dw = dim[w]
        if where[w] >= 0:
            yw = start[where[w]]
            for i in range(dw):
                for p in range(d):
                    f = fpool[c0 + p * N + cc + i]
                    for col in range(dv):
                        Y[yw + i, col] -= f * Y[y0 + p, col]
        cc += dw


@inline_kernel
def _paths_union(variables, parent, pos, where):
    """The nodes on the paths from ``variables`` to their roots, each once, in elimination order
    (a node before its parent: ``pos`` grows up the tree); ``where[j]`` is set to node j's place
    in it (it must hold −1 everywhere on entry)."""
    nodes = np.empty(parent.shape[0], dtype=np.int64)
    count = 0
    for v in variables:
        j = v
        while j >= 0 and where[j] < 0:
            where[j] = 0  # marked: the path above j is already collected
            nodes[count] = j
            count += 1
            j = parent[j]
    nodes = nodes[:count][np.argsort(pos[nodes[:count]])]
    for q in range(count):
        where[nodes[q]] = q
    return nodes


@kernel
def solve_on_paths(variables, rhs, tree, pools):
    """(nodes, Z): Z = R⁻ᵀ B for B = Σ_i E_{v_i} B_i, where ``rhs`` (Σ_i d_{v_i}, m) stacks the
    blocks B_i of ``variables`` (distinct, in their order), and Z is nonzero only on the union of
    their paths to their roots, ``nodes`` (each node's rows in Z in that order).

    Forward substitution Rᵀ Z = B visiting only those nodes, children first: a node's rows take
    the contributions of the nodes below it through their blocks T (whose separators are their
    ancestors, on the union too).  So Bᵀ Λ⁻¹ B = Bᵀ R⁻¹ R⁻ᵀ B = ZᵀZ costs the union of the paths,
    however many columns B has; Λ⁻¹'s block of one variable v is YᵀY for Y = R⁻ᵀ E_v."""
    dim = tree.dim
    where = np.full(tree.parent.shape[0], -1, dtype=np.int64)
    nodes = _paths_union(variables, tree.parent, tree.pos, where)
    count = nodes.shape[0]
    start = np.empty(count, dtype=np.int64)
    tot = 0
    for q in range(count):
        start[q] = tot
        tot += dim[nodes[q]]
    m = rhs.shape[1]
    Z = np.zeros((tot, m))
    r = 0
    for v in variables:
        z0 = start[where[v]]
        for p in range(dim[v]):
            for col in range(m):
                Z[z0 + p, col] += rhs[r + p, col]
        r += dim[v]
    for q in range(count):
        _forward_node(q, nodes, start, where, Z, tree, pools)
    return nodes, Z


@kernel
def marginal_covariance(v, tree, pools, out):
    """Σ_v = YᵀY with Y = R⁻ᵀ E_v (:func:`solve_on_paths`): ``out`` (d_v, d_v) receives the
    marginal covariance of ``v``, from the path from ``v`` to its root alone."""
    _, Y = solve_on_paths(np.array([v]), np.eye(tree.dim[v]), tree, pools)
    dv = Y.shape[1]
    tot = Y.shape[0]
    for a in range(dv):
        for b in range(dv):
            acc = 0.0
            for r in range(tot):
                acc += Y[r, a] * Y[r, b]
            out[a, b] = acc


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
def conditional_squares(x, with_d, nv, tree, pools):
    """Σ over the nodes of ‖R_j x_j + T_j x_S − d_j‖² (``with_d``) or of ‖R_j x_j + T_j x_S‖²,
    at the scalars ``x`` (nscalar,): twice the error of the factor's conditionals, or ‖R x‖²."""
    fpool = pools.fpool
    ipool = pools.ipool
    cond = tree.cond
    dim = tree.dim
    sep_len = tree.sep_len
    sep_start = tree.sep_start
    sep_dim = tree.sep_dim
    voff = tree.voff
    total = 0.0
    for j in range(nv):
        c0 = cond[j]
        if c0 < 0:
            continue
        d = dim[j]
        N = d + sep_dim[j] + 1
        o = voff[j]
        for p in range(d):
            row = c0 + p * N
            acc = -fpool[row + N - 1] if with_d else 0.0
            for q in range(p, d):
                acc += fpool[row + q] * x[o + q]
            c = d
            for t in range(sep_start[j], sep_start[j] + sep_len[j]):
                w = ipool[t]
                ow = voff[w]
                for i in range(dim[w]):
                    acc += fpool[row + c + i] * x[ow + i]
                c += dim[w]
            total += acc * acc
    return total


@kernel
def gradient_at_zero(nv, tree, pools, g):
    """g = −Σ over the nodes of [R_j | T_j]ᵀ d_j, the gradient at zero of ½‖R x − d‖² (ISAM2's
    ``gradientAtZero``), written into ``g`` (nscalar,)."""
    fpool = pools.fpool
    ipool = pools.ipool
    cond = tree.cond
    dim = tree.dim
    sep_len = tree.sep_len
    sep_start = tree.sep_start
    sep_dim = tree.sep_dim
    voff = tree.voff
    g[:] = 0.0
    for j in range(nv):
        c0 = cond[j]
        if c0 < 0:
            continue
        d = dim[j]
        N = d + sep_dim[j] + 1
        o = voff[j]
        for p in range(d):
            row = c0 + p * N
            dp = fpool[row + N - 1]
            for q in range(p, d):
                g[o + q] -= fpool[row + q] * dp
            c = d
            for t in range(sep_start[j], sep_start[j] + sep_len[j]):
                w = ipool[t]
                ow = voff[w]
                for i in range(dim[w]):
                    g[ow + i] -= fpool[row + c + i] * dp
                c += dim[w]
