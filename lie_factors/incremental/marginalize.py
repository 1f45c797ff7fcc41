"""ISAM2's ``marginalizeLeaves``: variables taken out of the smoother, their information kept.

The keys to marginalize must be leaves of the factor's tree in ISAM2's sense:
with every variable eliminated below them (whole subtrees).  Each subtree
whose parent stays passes its information to its separator S as one linear
factor, the Schur complement of the subtree's factors onto S:

    [A_M A_S | b] = Q [[R_MM R_MS r_M], [0 R_SS r_S]]  →  the factor ‖R_SS δ_S − r_S‖²

(QR of the factors on the subtree, its columns first), which is what the
subtree's update matrix U = [[Λ_SS, η_S], [η_Sᵀ, ·]] passed to its parent: where the
subtree's top keeps U, R_SS is its Cholesky factor and r_S = R_SS⁻ᵀ η_S instead, with no
QR.  The fixed-lag smoother marginalizes late (:func:`marginalize_late`,
:func:`hold_for_later`).  The factors on the subtree are
removed, the marginal factors added as ``gtsam.LinearContainerFactor`` (linear
at the current θ of S, GTSAM's ``JacobianFactor`` inside), the variables of S
held at their linearization point from then on (ISAM2's *fixed variables*), and
the subtrees' nodes taken out of the tree.  Nothing is re-eliminated: the
conditionals above already hold the same information.  A subtree hanging from
no parent (a root) leaves nothing behind.
"""

from __future__ import annotations

import gtsam
import numpy as np
from scipy.linalg import lapack

from ..batch.graph import key_name
from ..errors import InputError
from ..interop import to_gtsam
from .gtsam_objects import insert_from
from .removal import factor_variables, forget
from .structures import child_outside
from .update_args import order_groups, read_args


def _subtree_marginal(s, top: int, inside: np.ndarray) -> tuple:
    """(separator variables, [R_SS | r_S]) of the subtree under ``top`` (module docstring), or
    (empty, None) when it hangs from no parent: from the update matrix ``top`` keeps where it
    keeps one and it is positive definite, by QR of the subtree's factors otherwise."""
    bf = s.bf
    tree = bf.tree
    sep = bf.pools.ipool[int(tree.sep_start[top]):int(tree.sep_start[top]) + int(tree.sep_len[top])].copy()
    if not sep.size:
        return sep, None
    kept = _kept_marginal(bf, top)
    return sep, kept if kept is not None else _factors_marginal(s, top, inside, sep)


def _kept_marginal(bf, top: int):
    """[R_SS | r_S] from the update matrix ``U = [[Λ_SS, η_S], [η_Sᵀ, ·]]`` the node ``top``
    passed to its parent (the Schur complement of its subtree's whitened factors ``[A | b]ᵀ[A |
    b]`` onto its separator, :mod:`~lie_factors.incremental.structures`): ``R_SSᵀR_SS = Λ_SS``
    (Cholesky), ``R_SSᵀ r_S = η_S``, the same factor as the QR's up to the signs of its rows.
    None where the node keeps no update matrix or ``Λ_SS`` is not positive definite (the
    subtree does not determine every direction of its separator)."""
    u = int(bf.tree.ustart[top])
    if u < 0:
        return None
    sd = int(bf.tree.sep_dim[top])
    n = sd + 1
    U = np.zeros((n, n))
    U[np.triu_indices(n)] = bf.pools.fpool[u:u + n * (n + 1) // 2]
    R, info = lapack.dpotrf(U[:sd, :sd], lower=0, clean=1)
    if info != 0:
        return None
    r, info = lapack.dtrtrs(R, U[:sd, sd], lower=0, trans=1)
    out = np.empty((sd, n))
    out[:, :sd] = R
    out[:, sd] = r
    return out


def _factors_marginal(s, top: int, inside: np.ndarray, sep: np.ndarray) -> np.ndarray:
    """[R_SS | r_S] by QR of the factors on the subtree under ``top`` (separator ``sep``)."""
    bf = s.bf
    tree = bf.tree
    members, stack = [], [top]
    while stack:
        v = stack.pop()
        members.append(v)
        stack += _children(tree, v)
    members = np.array(members, dtype=np.int64)
    columns = np.concatenate([members, sep])
    offset = np.zeros(bf.nv + 1, dtype=np.int64)
    dims = tree.dim[columns]
    starts = np.concatenate([[0], np.cumsum(dims)])
    offset[columns] = starts[:-1]
    m = int(starts[len(members)])
    width = int(starts[-1])
    store = bf.store
    rows = []
    in_sep = set(sep.tolist())
    for f in bf.factors_of(members).tolist():
        r, D1 = int(store.frows[f]), int(store.fcols[f])
        J = store.jac[int(store.fjstart[f]):int(store.fjstart[f]) + r * D1].reshape(r, D1)
        row = np.zeros((r, width + 1))
        c = 0
        for w in store.fvars[int(store.fvstart[f]):int(store.fvstart[f]) + int(store.fnv[f])].tolist():
            d = int(tree.dim[w])
            if not inside[w] and w not in in_sep:
                raise InputError(f"marginalizeLeaves: a factor on {key_name(s.keys[members[0]])}'s subtree reaches "
                                 f"{key_name(s.keys[w])}, outside its separator")
            row[:, offset[w]:offset[w] + d] += J[:, c:c + d]
            c += d
        row[:, width] = J[:, D1 - 1]
        rows.append(row)
    stacked = np.concatenate(rows)
    if stacked.shape[0] < width + 1:
        stacked = np.concatenate([stacked, np.zeros((width + 1 - stacked.shape[0], width + 1))])
    R = np.linalg.qr(stacked, mode="r")
    return R[m:width, m:]


def _type_name(s, w: int) -> str:
    return s.vgroup[w] if s.vgroup[w] is not None else s.other_types[s.keys[w]]


def _container(s, sep: np.ndarray, Rs: np.ndarray, point: gtsam.Values):
    """The marginal factor ``[R_SS | r_S]`` on the variables ``sep`` as GTSAM's
    ``LinearContainerFactor`` at their θ in ``point``."""
    tree = s.bf.tree
    terms, c = [], 0
    for w in sep.tolist():
        d = int(tree.dim[w])
        terms.append((s.keys[w], np.ascontiguousarray(Rs[:, c:c + d])))
        c += d
    jf = linear_factor(terms, np.ascontiguousarray(Rs[:, -1]))
    theta = gtsam.Values()
    for w in sep.tolist():
        insert_from(theta, point, s.keys[w], _type_name(s, w))
    return gtsam.LinearContainerFactor(jf, theta)


def linear_factor(terms: list, b: np.ndarray):
    """GTSAM's linear factor ‖Σ_j A_j x_j − b‖² of ``terms`` [(key, A_j)]: a ``JacobianFactor``
    (GTSAM's Python constructors take up to three keys), or beyond three keys the same
    information as a ``HessianFactor`` (G = AᵀA, g = Aᵀb, f = bᵀb), summed from pairwise
    pieces (``HessianFactor(GaussianFactorGraph)`` adds them up)."""
    model = gtsam.noiseModel.Unit.Create(b.shape[0])
    if len(terms) <= 3:
        args = [x for key, A in terms for x in (key, A)]
        return gtsam.JacobianFactor(*args, b, model)
    graph = gtsam.GaussianFactorGraph()
    As = [A for _, A in terms]
    last = len(terms) - 1
    for i in range(last):
        for j in range(i + 1, len(terms)):
            # the pair (i, j) carries the block G_ij; the first pair of each i carries G_ii and g_i,
            # the pair (last − 1, last) carries G_ll, g_l and f
            first = j == i + 1
            end = (i, j) == (last - 1, last)
            Gii = As[i].T @ As[i] if first else np.zeros((As[i].shape[1],) * 2)
            gi = As[i].T @ b if first else np.zeros(As[i].shape[1])
            Gjj = As[j].T @ As[j] if end else np.zeros((As[j].shape[1],) * 2)
            gj = As[j].T @ b if end else np.zeros(As[j].shape[1])
            graph.push_back(gtsam.HessianFactor(terms[i][0], terms[j][0], Gii, As[i].T @ As[j], gi, Gjj, gj,
                                                float(b @ b) if end else 0.0))
    return gtsam.HessianFactor(graph)


def marginalize_leaves(s, keys) -> tuple[list, list]:
    """Marginalize the variables ``keys`` out of the smoother ``s`` (module docstring); returns
    (the marginal factors' indices, the removed factors' indices).  Refused, with nothing
    changed, for a key that is not a variable or a variable that is not a leaf."""
    keys = [int(k) for k in keys]
    bf = s.bf
    leaves = np.array(sorted({s._var_of(k) for k in keys}), dtype=np.int64)
    if not leaves.size:
        return [], []
    inside = np.zeros(bf.nv, dtype=bool)
    inside[leaves] = True
    tree = bf.tree
    found = child_outside(tree, leaves.tolist(), inside)
    if found is not None:
        raise InputError(f"marginalizeLeaves: {key_name(s.keys[found[0]])} is not a leaf: "
                         f"{key_name(s.keys[found[1]])} is eliminated below it and is not marginalized")
    tops = [v for v in leaves.tolist() if tree.parent[v] < 0 or not inside[tree.parent[v]]]
    marginals = [m for m in (_subtree_marginal(s, t, inside) for t in tops) if m[1] is not None and m[1].shape[0]]
    removed = bf.factors_of(leaves)
    point = _theta_of(s, np.unique(np.concatenate([sep for sep, _ in marginals] + [leaves[:0]])))
    factors = [(sep, _container(s, sep, Rs, point), Rs) for sep, Rs in marginals]
    fids = list(range(bf.nf, bf.nf + len(factors)))
    # the structure needs no check: the marginal factors hold every variable the subtrees
    # joined (their separators) and anchor it, and a Schur complement of a positive definite
    # system is positive definite
    plan, _ = s.gauge.join(0, [int(sep[0]) for sep, _, _ in factors for _ in sep[1:]],
                           [int(w) for sep, _, _ in factors for w in sep[1:]],
                           [int(sep[0]) for sep, _, _ in factors], [])
    bf.marginalize(leaves, removed, [(sep[None, :], Rs[None], np.array([fid]))
                                     for (sep, _, Rs), fid in zip(factors, fids)])
    for (sep, f, _), fid in zip(factors, fids):
        s.native.append((f, sep, fid))
        s.marginal_natives += 1
        s._register(np.array([fid]), -1, np.array([len(s.native) - 1]), False)
        s.vfixed[sep] = True
        s.vnative[sep] = True
        for w in sep.tolist():
            if not s.native_theta.exists(s.keys[w]):
                insert_from(s.native_theta, point, s.keys[w], _type_name(s, w))
    s.gauge.commit(plan)
    forget(s, leaves)
    return fids, removed.tolist()


def marginalize_late(s, keys: list, constrained: dict) -> None:
    """Marginalize ``keys`` some updates after they left a fixed-lag window, as if it had been
    done when they left: they are made leaves first where they are not, by one re-elimination
    ordered by ``constrained`` (``constrainedKeys``: the fixed-lag smoother's grouping, ``keys``
    first) of the nodes whose separator holds one (``extraReelimKeys``), adding nothing and
    counting as no update.  Exact as long as no update since they left has relinearized one of
    them or a variable their marginalization holds (:func:`hold_for_later`), or used one of
    ``keys``."""
    var = s.var
    old = [var[k] for k in keys]
    inside = np.zeros(s.bf.nv, dtype=bool)
    inside[old] = True
    if child_outside(s.bf.tree, old, inside) is not None:
        extra = np.array([var[k] for k in row_subtree_keys(s, keys)], dtype=np.int64)
        s.bf.update(observed=extra, groups=order_groups(s, read_args(constrainedKeys=constrained), 0, {}))
        s._fresh = False
    marginalize_leaves(s, keys)


def hold_for_later(s, keys: list) -> None:
    """Hold (never relinearize again, ISAM2's fixed variables) the variables of ``keys``, to be
    marginalized later, and every variable a factor joins to one of them: the variables their
    marginalization would hold (its marginal factors' separators are the variables outside
    ``keys`` that their factors reach)."""
    vs = np.array([s.var[k] for k in keys], dtype=np.int64)
    s.vfixed[factor_variables(s.bf.store, s.bf.factors_of(vs))] = True
    s.vfixed[vs] = True


def _theta_of(s, variables: np.ndarray) -> gtsam.Values:
    """θ of ``variables`` as a ``gtsam.Values``."""
    out = gtsam.Values()
    for w in variables.tolist():
        k = s.keys[w]
        if s.vgroup[w] is not None:
            out.insert(k, to_gtsam(s.vgroup[w], s.elements[s.vgroup[w]].X[s.velem[w]]))
        else:
            insert_from(out, s.other, k, s.other_types[k])
    return out


def row_subtree_keys(s, keys) -> list:
    """The keys of the nodes of the smoother ``s``'s tree whose separator holds one of ``keys``
    (below them in the tree): what must be re-eliminated with ``keys`` ordered first for them to
    become leaves (GTSAM's fixed-lag smoother marks the same, clique by clique)."""
    tree, ipool = s.bf.tree, s.bf.pools.ipool
    vs = [s._var_of(k) for k in keys]
    held = np.zeros(s.bf.nv, dtype=bool)
    held[vs] = True
    out: set = set()
    # one search from all their children, pruned at a node whose separator holds none of them:
    # a node below it whose separator holds a key above it would put the key in its separator
    # too (the row subtree of a variable is connected), and a key below it starts its own
    stack = [c for v in set(vs) for c in _children(tree, v)]
    seen = set(stack)
    while stack:
        j = stack.pop()
        a = int(tree.sep_start[j])
        if held[ipool[a:a + int(tree.sep_len[j])]].any():
            out.add(s.keys[j])
            for c in _children(tree, j):
                if c not in seen:
                    seen.add(c)
                    stack.append(c)
    return sorted(out)


def _children(tree, v: int) -> list:
    out = []
    c = int(tree.first[v])
    while c >= 0:
        out.append(c)
        c = int(tree.nxt[c])
    return out
