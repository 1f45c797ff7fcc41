"""GTSAM's LAGO (``lago::initialize``, Carlone et al.) on arrays: Pose2 orientations, then positions.

The same result as GTSAM's on the graph the :class:`~lie_factors.posegraph.graph.PoseGraph`
describes (to ~1e-10; tests/initialization/test_relaxation.py), with no factor object: numpy and
CHOLMOD, no numba.

* A spanning tree: the odometric path k → k+1 by key (``findOdometricPath``), or
  Kruskal's tree over the factors in order (``findMinimumSpanningTree``).  LAGO's
  results depend on which: it stays GTSAM's exact tree.
* Each loop edge's angle moved by the multiple of 2π that closes its cycle along
  the tree; the linear least squares of the angles (anchor fixed at 0, weights
  1/σ_θ²); then the linear least squares of the positions with the angles fixed.

LAGO reads the sigmas of diagonal noise models: the information must be diagonal
within GTSAM's ``checkIfDiagonal`` tolerance (what makes ``Gaussian::Information``
a Diagonal model), and only its diagonal is used.  The anchor and priors as in
:mod:`lie_factors.initialization.anchor`.
"""

from __future__ import annotations

import numpy as np

from ..errors import InitializationError
from ..interop import pose2_matrices
from ..posegraph.graph import PoseGraph
from ..posegraph.topology import along_tree, bfs_tree, first_spanning_forest
from . import anchor, sparse

#: GTSAM's ``checkIfDiagonal``: an information matrix is diagonal when every entry above
#: the diagonal is at most this in absolute value.
GTSAM_DIAGONAL_TOL = 1e-9

#: lago's prior on the anchor pose in its position step (lago.cpp ``priorPose2Noise``).
_ANCHOR_VARIANCES = np.array([1e-6, 1e-6, 1e-8])


def odometric_path_complete(keys: np.ndarray, edge_keys: np.ndarray) -> bool:
    """Whether the edges k–(k+1) link every pose to the smallest key, as lago's odometric tree needs.

    ``keys`` (P,) sorted pose keys, ``edge_keys`` (E, 2) the between factors' keys.
    """
    # uint64, GTSAM's Key: differences are taken in both directions (no sign to overflow).
    keys = np.asarray(keys, dtype=np.uint64)
    edge_keys = np.asarray(edge_keys, dtype=np.uint64).reshape(-1, 2)
    if len(keys) == 0 or int(keys[-1] - keys[0]) != len(keys) - 1 or anchor.ANCHOR_KEY in set(keys.tolist()):
        return False
    a, b = edge_keys[:, 0], edge_keys[:, 1]
    consecutive = (a - b == 1) | (b - a == 1)
    lows = np.unique(np.minimum(a[consecutive], b[consecutive]))
    return bool(np.isin(keys[:-1], lows).all())


def check_diagonal(pg: PoseGraph) -> None:
    """Raise the one-line reason LAGO does not apply unless every information is diagonal."""
    for info, what in ((pg.information, "edge"), (pg.prior_information, "prior")):
        upper = np.triu(np.ones(info.shape[1:], dtype=bool), 1)
        full = np.flatnonzero(np.abs(info[:, upper]).max(axis=1, initial=0.0) > GTSAM_DIAGONAL_TOL)
        if full.size:
            k = full[0]
            where = (f"edge {pg.edge_keys[k, 0]}-{pg.edge_keys[k, 1]}" if what == "edge"
                     else f"the prior on {pg.prior_keys[k]}")
            raise InitializationError(f"LAGO needs diagonal noise models; {where} has a full covariance")


def _odometric_tree(keys, ii, jj, n):
    """lago's ``findOdometricPath``: parent[k + 1] = k along consecutive keys (first edge wins),
    the smallest such key (or the first factor's smaller key) hangs from the anchor (index n).
    Returns parent (n + 1,) with -1 where a pose has none."""
    parent = np.full(n + 1, -1, dtype=np.int64)
    kk = np.append(keys, -1)  # the anchor's key plays no part in "consecutive" (GTSAM's 99999999)
    ka, kb = kk[ii], kk[jj]
    lo = np.where(ka <= kb, ii, jj)
    hi = np.where(ka <= kb, jj, ii)
    anchor_edge = (ii == n) | (jj == n)
    # GTSAM takes min/max of the keys themselves; the anchor key 99999999 is the larger one.
    lo = np.where(anchor_edge, np.where(ii == n, jj, ii), lo)
    hi = np.where(anchor_edge, n, hi)
    consecutive = ~anchor_edge & (kk[hi] - kk[lo] == 1)
    idx = np.nonzero(consecutive)[0]
    first = idx[np.unique(hi[idx], return_index=True)[1]]  # emplace: the first edge per child wins
    parent[hi[first]] = lo[first]
    mins = [lo[0]] + ([lo[idx[np.argmin(kk[lo[idx]])]]] if idx.size else [])
    min_node = min(mins, key=lambda v: kk[v])
    if parent[min_node] < 0:
        parent[min_node] = n
    parent[n] = n
    return parent


def _kruskal_tree(ii, jj, n):
    """lago's ``findMinimumSpanningTree``: Kruskal over the factors in order (equal weights),
    then the tree rooted at the anchor (index n).  Returns parent (n + 1,)."""
    taken = first_spanning_forest(n + 1, ii, jj)
    return bfs_tree(n + 1, ii[taken], jj[taken], n)[0]


def _wrap(a: np.ndarray) -> np.ndarray:
    """Angles to (−π, π] as GTSAM's Rot2(θ).theta() does (atan2 of sin and cos)."""
    return np.arctan2(np.sin(a), np.cos(a))


def orientations(n, keys, ii, jj, dth, w, use_odometric_path) -> np.ndarray:
    """lago's ``computeOrientations`` on the anchored edges (anchor n): angles (n + 1,), anchor's 0.

    ``keys`` (n,) the poses' keys; ``ii``, ``jj`` (E,) the edges by index;
    ``dth`` (E,) the measured angles, ``w`` (E,) their weights 1/σ_θ².
    """
    N = n + 1

    # --- the spanning tree and each pose's angle along it from the anchor
    parent = _odometric_tree(keys, ii, jj, n) if use_odometric_path else _kruskal_tree(ii, jj, n)
    fwd = parent[jj] == ii  # edge i → j is the tree edge into j (tested second in GTSAM)
    bwd = parent[ii] == jj  # into i, tested first
    in_tree = bwd | fwd
    child = np.where(bwd, ii, jj)
    delta = np.where(bwd, -dth, dth)
    tree_edges = np.nonzero(in_tree)[0]
    first = tree_edges[np.unique(child[tree_edges], return_index=True)[1]]  # first edge per child wins
    step = np.full(N, np.nan)
    step[child[first]] = delta[first]
    step[n] = 0.0
    total, on_tree = along_tree(parent, step, n, np.add)
    theta_tree = np.where(on_tree, total, np.nan)
    if np.isnan(theta_tree).any():
        lost = int(np.nonzero(np.isnan(theta_tree))[0][0])
        where = f"pose {int(keys[lost])}" if lost < n else "the anchor"
        if use_odometric_path:  # GTSAM's lago throws (map::at) here
            raise InitializationError(f"LAGO's odometric path (consecutive keys, its first key hung from the "
                                      f"prior) does not reach {where}; use_odometric_path=False takes "
                                      "Kruskal's tree")
        raise InitializationError(f"LAGO's spanning tree does not reach {where}")

    # --- loop edges regularized by the multiple of 2π closing their cycle; angles by linear LS
    chord = ~in_tree
    k = np.round((dth + theta_tree[ii] - theta_tree[jj]) / (2 * np.pi))
    d_reg = np.where(chord, dth - 2 * k * np.pi, dth)
    # θ_j − θ_i = d, weight w; the anchor's θ is fixed at 0 (lago's prior has sigma 0).
    free = np.arange(N) != n
    idx_of = np.cumsum(free) - 1
    both = free[ii] & free[jj]
    diag = (np.bincount(ii[free[ii]], weights=w[free[ii]], minlength=N)
            + np.bincount(jj[free[jj]], weights=w[free[jj]], minlength=N))[free]
    g = (np.bincount(jj[free[jj]], weights=(w * d_reg)[free[jj]], minlength=N)
         - np.bincount(ii[free[ii]], weights=(w * d_reg)[free[ii]], minlength=N))[free]
    a, b = idx_of[ii[both]], idx_of[jj[both]]
    rows = np.concatenate([np.arange(n), np.maximum(a, b)])
    cols = np.concatenate([np.arange(n), np.minimum(a, b)])
    theta = sparse.solve(n, rows, cols, np.concatenate([diag, -w[both]]), g)
    return np.append(theta, 0.0)


def initialize_pose2(pg: PoseGraph, use_odometric_path: bool = True) -> np.ndarray:
    """GTSAM's ``lago.initialize(graph, useOdometricPath)``: the poses (P, 3, 3) of a Pose2 graph.

    With ``use_odometric_path`` the path k → k+1 must reach every pose from the
    one on the first factor (or the smallest key joined by a consecutive edge),
    which hangs from a prior; else Kruskal's tree.  Raises ``ValueError`` for
    malformed arrays, :class:`~lie_factors.errors.InitializationError` for a
    graph LAGO does not take (3-D, full covariances, a pose the tree or a prior
    does not reach).
    """
    anchor.require(pg, ("Pose2",), "LAGO")
    pg = anchor.prepared(pg)
    check_diagonal(pg)
    n, ii, jj, Z, info = anchor.anchored_edges(pg)
    N = n + 1
    # [x, y, θ] of each measurement, θ = Pose2::theta() = atan2(s, c)
    dx, dy, dth = Z[:, 0, 2], Z[:, 1, 2], np.arctan2(Z[:, 1, 0], Z[:, 0, 0])
    L = np.einsum("kii->ki", info)[:, :, None] * np.eye(3)  # what Diagonal::Precisions keeps: Λ = diag(1/σ²)
    th = orientations(n, pg.keys, ii, jj, dth, L[:, 2, 2], use_odometric_path)

    # --- positions (and angle corrections) by linear LS with the angles fixed
    s1, c1 = np.sin(th[ii]), np.cos(th[ii])
    b = np.stack([c1 * dx - s1 * dy, s1 * dx + c1 * dy, _wrap(th[jj] - th[ii] - dth)], axis=1)
    J1 = np.broadcast_to(-np.eye(3), (ii.size, 3, 3)).copy()
    J1[:, 0, 2] = s1 * dx + c1 * dy
    J1[:, 1, 2] = -c1 * dx + s1 * dy
    Hii = np.swapaxes(J1, 1, 2) @ L @ J1
    Hji = L @ J1  # J2ᵀ Λ J1 with J2 = I: block (j, i)
    D = sparse.scatter_add(ii, Hii, N) + sparse.scatter_add(jj, L, N)
    D[n] += np.diag(1.0 / _ANCHOR_VARIANCES)
    Lb = np.einsum("kab,kb->ka", L, b)
    rhs = sparse.scatter_add(ii, np.einsum("kba,kb->ka", J1, Lb), N) + sparse.scatter_add(jj, Lb, N)
    r0, c0, v0 = sparse.diag_lower_triplets(D, 3)
    r1, c1_, v1 = sparse.lower_block_triplets(jj, ii, Hji, 3)
    x = sparse.solve(3 * N, np.concatenate([r0, r1]), np.concatenate([c0, c1_]), np.concatenate([v0, v1]),
                     rhs.ravel()).reshape(N, 3)
    return pose2_matrices(np.stack([x[:n, 0], x[:n, 1], _wrap(th[:n] + x[:n, 2])], axis=1))
