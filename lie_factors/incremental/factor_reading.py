"""Reading the block factor without changing it: δ, Λ⁻¹'s blocks, the conditionals' error, inspection.

:class:`FactorReading` is the part of
:class:`~lie_factors.incremental.cholesky.BlockFactor` that solves with the
factor and reads it: wildfire back-substitution (δ), marginal and joint
covariances from the paths of the columns to their roots, the error of the
conditionals and the products Dogleg needs (R·x, −Rᵀd), and, for tests and small
problems, the order, the entries and the dense Λ, η and L.
"""

from __future__ import annotations

import numpy as np

from ..kernels.jit import direct
from . import substitution
from .marking import factors_of
from .substitution import conditional_squares, gradient_at_zero, marginal_covariance, max_abs_blocks, solve_on_paths

back_substitute = direct(substitution.back_substitute)


class FactorReading:
    """What :class:`~lie_factors.incremental.cholesky.BlockFactor` answers from its state."""

    # ------------------------------------------------------------------ solving
    def solve(self, threshold: float = 0.0) -> int:
        """Bring ``delta`` up to date after updates (wildfire, see
        :func:`~lie_factors.incremental.substitution.back_substitute`); returns the nodes solved."""
        return int(back_substitute(float(threshold), self.tree, self.pools, self.delta, self.wildfire))

    def replace_all(self) -> None:
        """Count every node as re-eliminated: the next :meth:`solve` solves them all (exactly)."""
        self.wildfire.replaced[:self.nv] = 1

    def variable_delta(self, v: int) -> np.ndarray:
        o = int(self.tree.voff[v])
        return self.delta[o:o + int(self.tree.dim[v])]

    def largest_steps(self, delta: np.ndarray | None = None) -> np.ndarray:
        """(nv,): max_i |δ_v[i]| of every variable v (of ``delta``, default the factor's own)."""
        return max_abs_blocks(self.delta if delta is None else delta, self.tree.voff[:self.nv], self.tree.dim[:self.nv])

    def factors_of(self, variables: np.ndarray) -> np.ndarray:
        """The factors on any of ``variables``, each once, increasing."""
        return factors_of(variables, self.store, self.nf)

    def joint_covariance(self, variables) -> np.ndarray:
        """(Σd, Σd): the blocks of Λ⁻¹ of ``variables`` (distinct), in their order.  Λ⁻¹ = YᵀY
        with Y = R⁻ᵀ, whose column of a variable is nonzero only on the path from it to its root
        (:func:`~lie_factors.incremental.substitution.solve_on_paths`): each variable's columns,
        solved on its own path and scattered onto the union of the paths, give every block in
        one product.  (One solve of all their columns over the union, :meth:`projected_covariance`
        with B = I, would carry every column through every path: up to len(variables) times the
        work where the paths do not meet.)"""
        variables = [int(v) for v in variables]
        dim = self.tree.dim
        found = [solve_on_paths(np.array([v]), np.eye(int(dim[v])), self.tree, self.pools) for v in variables]
        nodes = np.unique(np.concatenate([path for path, _ in found]))
        first = np.concatenate([[0], np.cumsum(dim[nodes])]).astype(np.int64)
        Y = np.zeros((int(first[-1]), sum(int(dim[v]) for v in variables)))
        col = 0
        for path, Yv in found:
            d = np.asarray(dim[path], dtype=np.int64)
            at = first[np.searchsorted(nodes, path)]
            rows = np.repeat(at - np.concatenate([[0], np.cumsum(d)[:-1]]), d) + np.arange(int(d.sum()))
            Y[rows, col:col + Yv.shape[1]] = Yv
            col += Yv.shape[1]
        return Y.T @ Y

    def projected_covariance(self, variables, blocks: np.ndarray) -> np.ndarray:
        """(m, m): Bᵀ Λ⁻¹ B for B = Σ_i E_{v_i} B_i, ``blocks`` (Σ_i d_{v_i}, m) the B_i of
        ``variables`` (distinct) stacked in their order: A Σ Aᵀ of a Jacobian A = Bᵀ on those
        variables, Σ their joint marginal covariance, from one forward substitution over the
        union of their paths to their roots (:func:`~lie_factors.incremental.substitution.solve_on_paths`)."""
        variables = np.asarray(variables, dtype=np.int64)
        blocks = np.ascontiguousarray(blocks, dtype=np.float64)
        height = int(self.tree.dim[variables].sum())
        if blocks.shape[0] != height:
            raise ValueError(f"blocks has {blocks.shape[0]} rows; the variables' dimensions sum to {height}")
        _, Z = solve_on_paths(variables, blocks, self.tree, self.pools)
        return Z.T @ Z

    def conditional_error(self, x: np.ndarray) -> float:
        """½ Σ over the nodes of ‖R_j x_j + T_j x_S − d_j‖² at the scalars ``x`` (nscalar,): the
        error of the factor's conditionals (ISAM2's ``error(VectorValues)``, the Bayes tree as a
        Gaussian factor graph)."""
        return 0.5 * float(conditional_squares(np.ascontiguousarray(x, dtype=np.float64), True, self.nv,
                                               self.tree, self.pools))

    def r_squared(self, x: np.ndarray) -> float:
        """‖R x‖² summed over the nodes (the Cauchy step's denominator)."""
        return float(conditional_squares(np.ascontiguousarray(x, dtype=np.float64), False, self.nv,
                                         self.tree, self.pools))

    def gradient_at_zero(self) -> np.ndarray:
        """(nscalar,): −Rᵀd, the gradient at δ = 0 of the conditionals' error."""
        g = np.empty(self.nscalar)
        gradient_at_zero(self.nv, self.tree, self.pools, g)
        return g

    def marginal_covariance(self, v: int) -> np.ndarray:
        """(d, d): the block of Λ⁻¹ of variable ``v`` (only the path from ``v`` to its root is read)."""
        d = int(self.tree.dim[v])
        out = np.empty((d, d))
        marginal_covariance(int(v), self.tree, self.pools, out)
        return out

    # ------------------------------------------------------------------ inspection (tests, small problems)
    def ordering(self) -> np.ndarray:
        """Variable indices in elimination order (the variables taken out left out)."""
        order = np.argsort(self.tree.pos[:self.nv], kind="stable")
        return order[self.vdead[order] == 0] if self.ndead else order

    def nnz(self) -> int:
        """Entries of the factor's conditionals [R | T] (R upper triangular): Σ over the nodes of
        d(d + 1)/2 + d·s, the count of ISAM2's ``treeNnz``, whatever the cliques."""
        tree = self.tree
        live = tree.cond[:self.nv] >= 0
        d, s = tree.dim[:self.nv][live], tree.sep_dim[:self.nv][live]
        return int((d * (d + 1) // 2 + d * s).sum())

    def dense_system(self) -> tuple[np.ndarray, np.ndarray]:
        """(Λ, η) = (Σ AᵀA, Σ Aᵀb) as dense arrays in variable-offset order, from the stored Jacobians."""
        n = self.nscalar
        store, tree = self.store, self.tree
        H = np.zeros((n + 1, n + 1))
        for f in range(self.nf):
            if self.fremoved[f]:
                continue
            k, v0 = int(store.fnv[f]), int(store.fvstart[f])
            vs = store.fvars[v0:v0 + k]
            r, D1 = int(store.frows[f]), int(store.fcols[f])
            J = store.jac[int(store.fjstart[f]):int(store.fjstart[f]) + r * D1].reshape(r, D1)
            cols = np.concatenate([tree.voff[v] + np.arange(tree.dim[v]) for v in vs] + [[n]])
            H[np.ix_(cols, cols)] += J.T @ J
        return H[:n, :n], H[:n, n]

    def dense_factor(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(perm, L, y): the scalars of the live variables in elimination order, the
        lower-triangular L with L Lᵀ = Λ[perm][:, perm], and y = L⁻¹ η[perm], assembled from
        the nodes."""
        tree, (ipool, fpool) = self.tree, self.pools
        order = self.ordering()
        perm = np.concatenate([tree.voff[v] + np.arange(tree.dim[v]) for v in order] +
                              [np.zeros(0, dtype=np.int64)]).astype(np.int64)
        n = len(perm)
        where = np.full(self.nscalar, -1, dtype=np.int64)
        where[perm] = np.arange(n)
        L = np.zeros((n, n))
        y = np.zeros(n)
        for v in order:
            d = int(tree.dim[v])
            sep = ipool[int(tree.sep_start[v]):int(tree.sep_start[v]) + int(tree.sep_len[v])]
            s = int(tree.sep_dim[v])
            N = d + s + 1
            C = fpool[int(tree.cond[v]):int(tree.cond[v]) + d * N].reshape(d, N)
            rows = np.concatenate([where[tree.voff[w] + np.arange(tree.dim[w])] for w in [v, *sep]]).astype(np.int64)
            cols = where[tree.voff[v] + np.arange(d)]
            L[np.ix_(rows, cols)] = C[:, :d + s].T
            y[cols] = C[:, N - 1]
        return perm, L, y
