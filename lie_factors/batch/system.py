"""The damped normal equations as one block-sparse symmetric matrix, assembled by numba.

For whitened factor rows ``A δ ≈ b`` (``b = −R·e``) the Gauss–Newton system is
``H δ = g`` with ``H = Σ_f w_f A_fᵀA_f`` and ``g = Σ_f w_f A_fᵀb_f``; LM adds
``λ·I`` (or ``λ·clamp(diag H, 1e-6, 1e32)`` with ``diagonalDamping``, GTSAM's
``LevenbergMarquardtParams`` min/max diagonal) to the diagonal.  ``w_f`` is a
per-factor weight (1 unless a robust/GNC scheme sets :attr:`LinearSystem.weights`):
it multiplies the factor's whole whitened contribution, i.e. scales its rows
by √w_f — GTSAM's robust reweighting.

Storage: :class:`lie_factors.sparse.pattern.Pattern`, computed once per graph
(the pattern and each factor's scatter map), assembled by its kernels.

Hard constraints that pin a variable (:mod:`lie_factors.batch.graph`) are imposed on the
system a solver factors (:meth:`LinearSystem.holding`): the pinned variables' rows and
columns of H become those of the identity and their right-hand side their steps, the
other rows' right-hand side less H's columns times those steps; the damped system
H + D of the free variables is then solved exactly as it is without them, and the
pinned variables take their steps, as GTSAM's elimination of a constrained factor gives.
"""

from __future__ import annotations

import contextlib
import time

import numpy as np

from ..sparse.pattern import (NativeBlocks, Pattern, add_blocks, add_factors, add_information, quadratic_change,
                              quadratic_form, set_diagonal)

#: Factors per batch of :meth:`LinearSystem.linearize_assemble`: its buffer (8192 SE(3) factors:
#: 5 MB) stays in cache between the linearization and the assembly that reads it.
BATCH = 8192

#: The second Jacobian blocks of one-variable factors (none), by dimension.
_NO_BLOCKS = {n: np.empty((0, n, n)) for n in range(1, 8)}


class LinearSystem:
    """``H``, ``g`` of a :class:`~lie_factors.batch.graph.Problem`, in :class:`Pattern` storage.

    ``weights`` (one per graph factor, index = position in the
    NonlinearFactorGraph, 1.0 by default) multiply each factor's
    contribution at the next :meth:`assemble`: the hook for robust
    reweighting (IRLS) and GNC.  ``data`` holds H, damped in place by
    :meth:`damp` (the undamped diagonal is kept: :meth:`hessian_diagonal`), which
    is what the linear solvers factor.
    """

    def __init__(self, problem, order: np.ndarray | None = None):
        self.problem = problem
        P = problem
        pairs = [np.stack([g.v1, g.v2], axis=1) for g in P.groups if g.kind == "between"]
        pairs += [kg.pairs() for kg in P.kinds]
        pairs += [P.native_pairs]
        self.pattern = pat = Pattern(P.var_dims, np.concatenate(pairs) if pairs else np.zeros((0, 2)), order)
        self.n = pat.n
        self.data = np.zeros(pat.nnz)
        self.rhs = np.zeros(pat.n)
        self.weights = np.ones(P.graph_size)
        self._diagonal = None  # diag(H) of the last assembly, in δ's order
        self._damped = False
        #: each factor group's scatter map (pattern.scatter)
        self._scatter = {g: pat.scatter(g.v1, g.v2 if g.kind == "between" else None) for g in P.groups}
        self._kinds = [self._kind_scatter(kg) for kg in P.kinds]
        self._native = None
        nat = P.native_arrays
        if nat is not None:
            kv = nat.key_var
            # Every ordered key pair (p, q) of each native factor, flattened factor by factor.
            pa, pb = [], []
            for f in range(len(nat.size)):
                ks = kv[nat.key_start[f]:nat.key_start[f + 1]]
                pa.append(np.repeat(ks, len(ks)))
                pb.append(np.tile(ks, len(ks)))
            pa = np.concatenate(pa)
            pb = np.concatenate(pb)
            base, stride, a_is_row = pat.lookup(pa, pb)
            # nat.info is the array the native linearization writes into, in place
            self._native = NativeBlocks(nat.info, nat.info_start, nat.size, nat.key_start, nat.key_local,
                                        nat.key_dim, pat.offsets[kv], nat.pair_start,
                                        np.where(a_is_row.astype(bool), base, -1), stride)
        self._pins = _Pins(pat, P) if P.pins else None

    def _kind_scatter(self, kg) -> tuple:
        """Where a kind's factors' blocks go: (col (k,), dim (k,), o (F, k), base, stride, row
        (F, k, k)) for :func:`~lie_factors.sparse.pattern.add_blocks`."""
        pat = self.pattern
        k, F = len(kg.var), kg.E
        base = np.zeros((F, k, k), dtype=np.int64)
        stride = np.zeros((F, k, k), dtype=np.int64)
        row = np.zeros((F, k, k), dtype=np.int64)
        for p in range(k):
            for q in range(p, k):
                base[:, p, q], stride[:, p, q], row[:, p, q] = pat.lookup(kg.var[p], kg.var[q])
        o = np.stack([pat.offsets[v] for v in kg.var], axis=1) if k else np.zeros((F, 0), dtype=np.int64)
        col = np.array(kg.kind.offsets, dtype=np.int64)
        dim = np.array([t.dim for t in kg.kind.variables], dtype=np.int64)
        return col, dim, np.ascontiguousarray(o), base, stride, row

    def _add_kinds(self) -> None:
        for kg, (col, dim, o, base, stride, row) in zip(self.problem.kinds, self._kinds):
            if kg.E:
                add_blocks(kg.A, kg.b, self.weights[kg.fidx], col, dim, o, base, stride, row, self.data, self.rhs)

    def assemble(self) -> None:
        """H and g of the current linearization (``problem.linearize`` must have run)."""
        self.data[:] = 0.0
        self.rhs[:] = 0.0
        for g in self.problem.groups:
            self._add(g, 0, g.E, g.A1, g.A2, g.b)
        self._add_kinds()
        self._add_native()

    def linearize_assemble(self) -> tuple[float, float, float]:
        """Linearize the problem and assemble H and g, :data:`BATCH` factors at a time through one
        buffer: the graph's Jacobians never exist all at once (``A1``, ``A2``, ``b`` of the
        groups stay unset; ``sq`` is set).  The same numbers as ``problem.linearize()`` then
        :meth:`assemble`.  Returns (the error ½·Σ sq at δ = 0, seconds linearizing, seconds
        assembling)."""
        P = self.problem
        self.data[:] = 0.0
        self.rhs[:] = 0.0
        total = seconds_lin = seconds_asm = 0.0
        for g in P.groups:
            X = P.blocks[g.spec.name].X
            n = g.spec.dim
            size = min(g.E, BATCH)
            A1, b = np.empty((size, n, n)), np.empty((size, n))
            A2 = np.empty((size, n, n)) if g.kind == "between" else None
            for start in range(0, g.E, BATCH):
                stop = min(g.E, start + BATCH)
                k = stop - start
                t0 = time.perf_counter()
                g.linearize_range(X, start, stop, A1[:k], None if A2 is None else A2[:k], b[:k])
                t1 = time.perf_counter()
                self._add(g, start, stop, A1[:k], None if A2 is None else A2[:k], b[:k])
                seconds_lin += t1 - t0
                seconds_asm += time.perf_counter() - t1
            total += 0.5 * float(g.sq.sum())
        t0 = time.perf_counter()
        total += P.linearize_kinds()
        t1 = time.perf_counter()
        self._add_kinds()
        t2 = time.perf_counter()
        total += P.linearize_native()
        t3 = time.perf_counter()
        self._add_native()
        return total, seconds_lin + (t1 - t0) + (t3 - t2), seconds_asm + (t2 - t1) + time.perf_counter() - t3

    def _add(self, g, start: int, stop: int, A1, A2, b) -> None:
        """Add factors ``start:stop`` of group ``g`` (their blocks ``A1``, ``A2``, ``b``) to H and g."""
        s = slice(start, stop)
        w = self.weights[g.fidx[s]]
        at = self._scatter[g]
        if start or stop < g.E:
            at = at.part(s)
        add_factors(A1, A2 if A2 is not None else _NO_BLOCKS[A1.shape[1]], b, w, at, self.data, self.rhs)

    def _add_native(self) -> None:
        """Add the natively linearized factors, and keep H's undamped diagonal."""
        nat = self.problem.native_arrays
        if nat is not None:
            add_information(self._native, self.weights[nat.fidx], self.data, self.rhs)
        self._diagonal = self.data[self.pattern.diagpos]
        self._damped = False

    def hessian_diagonal(self) -> np.ndarray:
        """GTSAM's ``hessianDiagonal`` of the last linearization, shape (n,), in δ's order (not to be
        modified): diag(H), where the rows of a hard constraint count with weight 1 (GTSAM's
        whitening leaves them as they are) rather than μ."""
        diagonal = self.data[self.pattern.diagpos] if self._diagonal is None else self._diagonal
        correction = self.problem.constrained_diagonal
        return diagonal if correction is None else diagonal + correction

    @contextlib.contextmanager
    def holding(self, data: np.ndarray, rhs: np.ndarray):
        """Within the block, ``data`` (H or H + D, as :meth:`damp` left it) and ``rhs`` (g in the
        matrix's order, a copy) impose the pins' steps (module docstring); ``data`` is as it
        was after.  Nothing changes where no variable is pinned."""
        if self._pins is None:
            yield
            return
        with self._pins.imposed(data, rhs, self.problem.pin_steps):
            yield

    def damp(self, scale: np.ndarray | None) -> np.ndarray:
        """``data`` = H + diag(``scale``) (δ's order; None: H itself), in place; returns ``data``."""
        if scale is None:
            if self._damped:
                set_diagonal(self.data, self.pattern.diagpos, self._diagonal, np.zeros(self.n))
                self._damped = False
        else:
            if self._diagonal is None:
                self._diagonal = self.data[self.pattern.diagpos]
            set_diagonal(self.data, self.pattern.diagpos, self._diagonal, np.asarray(scale, dtype=np.float64))
            self._damped = True
        return self.data

    def variable_at(self, column: int | None) -> int | None:
        """The variable (its index in the problem's ``var_keys``) of the matrix's ``column``, as a
        factorization reports it; None for None or a column out of range."""
        if column is None or not 0 <= column < self.pattern.n:
            return None
        return int(np.searchsorted(self.problem.var_offsets, self.pattern.scalar_order[column], side="right") - 1)

    def in_matrix_order(self, v: np.ndarray) -> np.ndarray:
        """A vector (n, ...) in δ's order, reordered as the matrix's rows."""
        return v[self.pattern.scalar_order]

    def from_matrix_order(self, x: np.ndarray) -> np.ndarray:
        """A vector (n, ...) in the matrix's row order, reordered as δ."""
        out = np.empty_like(x)
        out[self.pattern.scalar_order] = x
        return out

    def linear_change(self, delta: np.ndarray) -> float:
        """Decrease of the (weighted) linearized error from δ = 0 to ``delta``."""
        p = self.pattern
        self.damp(None)
        return float(quadratic_change(p.colptr, p.rowind, self.data, self.in_matrix_order(self.rhs),
                                      self.in_matrix_order(delta)))

    def curvature(self, v: np.ndarray) -> float:
        """vᵀHv (H undamped; ``v`` in δ's order)."""
        p = self.pattern
        self.damp(None)
        return float(quadratic_form(p.colptr, p.rowind, self.data, self.in_matrix_order(v)))

    def free(self, v: np.ndarray) -> np.ndarray:
        """``v`` (δ's order) with the pinned variables' entries 0 (``v`` itself where none is pinned)."""
        if self._pins is None:
            return v
        out = v.copy()
        out[self._pins.scalars] = 0.0
        return out

    def to_dense(self, values: np.ndarray | None = None) -> np.ndarray:
        """The full symmetric H (or H with ``values``) as a dense (n, n) array in δ's order, for
        checks on small graphs."""
        p = self.pattern
        if values is None:
            self.damp(None)
            values = self.data
        rows = p.scalar_order[p.rowind]
        cols = p.scalar_order[p.colind()]
        L = np.zeros((p.n, p.n))
        np.add.at(L, (rows, cols), values)
        return L + L.T - np.diag(np.diag(L))


class _Pins:
    """Where the pinned variables sit in H's storage (computed once per graph): their scalar
    indices (δ's order) and matrix rows, H's entries in their rows or columns, and for each
    entry joining a pinned row to a free one, both."""

    def __init__(self, pattern: Pattern, problem):
        P = problem
        self.scalars = np.concatenate([P.var_offsets[v] + np.arange(P.var_dims[v]) for _, v in P.pins])
        row_of = np.empty(pattern.n, dtype=np.int64)  # δ index → matrix row
        row_of[pattern.scalar_order] = np.arange(pattern.n)
        self.rows = row_of[self.scalars]
        pinned = np.zeros(pattern.n, dtype=bool)
        pinned[self.rows] = True
        r, c = pattern.rowind.astype(np.int64), pattern.colind().astype(np.int64)
        touched = np.flatnonzero(pinned[r] | pinned[c])
        self.touched = touched
        self.diagonal = touched[r[touched] == c[touched]]
        cross = touched[pinned[r[touched]] != pinned[c[touched]]]
        self.cross = cross
        row_pinned = pinned[r[cross]]
        self.cross_free = np.where(row_pinned, c[cross], r[cross])
        self.cross_pinned = np.where(row_pinned, r[cross], c[cross])
        self._n = pattern.n

    @contextlib.contextmanager
    def imposed(self, data: np.ndarray, rhs: np.ndarray, steps: list):
        step = np.zeros(self._n)
        step[self.rows] = np.concatenate(steps)
        saved = data[self.touched]
        np.subtract.at(rhs, self.cross_free, data[self.cross] * step[self.cross_pinned])
        rhs[self.rows] = step[self.rows]
        data[self.touched] = 0.0
        data[self.diagonal] = 1.0
        try:
            yield
        finally:
            data[self.touched] = saved
