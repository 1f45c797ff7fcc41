"""The batch solver's arrays of one group: its variables (:class:`VarBlock`) and its factors of one
kind (:class:`FactorGroup`), and the constants they hold: whitening matrices, one per distinct
noise model or information matrix (:func:`noise_whitening`, :func:`whitening`,
:func:`unique_rows`).  :class:`lie_factors.batch.graph.Problem` builds them from a graph.
"""

from __future__ import annotations

import gtsam
import numpy as np

from ..kernels.jit import kernel
from ..util.arrays import sorted_unique
from .loops import GroupLoops, whiten_all


def noise_whitening(noise_model):
    """Upper-triangular R with ‖R e‖² = Mahalanobis², or None if GTSAM must linearize."""
    if isinstance(noise_model, (gtsam.noiseModel.Robust, gtsam.noiseModel.Constrained)):
        return None
    if not isinstance(noise_model, gtsam.noiseModel.Gaussian):
        return None
    return noise_model.R()


def whitening(information: np.ndarray) -> np.ndarray:
    """R (..., n, n) upper triangular with RᵀR = Λ for information matrices Λ (..., n, n).

    ``noiseModel.Gaussian.Information``'s square root (the Cholesky factor,
    :func:`~lie_factors.batch.loops.upper_cholesky`); ``numpy.linalg.LinAlgError`` if some Λ
    is not positive definite.
    """
    A = np.ascontiguousarray(information, dtype=np.float64)
    if A.ndim < 2 or A.shape[-1] != A.shape[-2]:
        raise np.linalg.LinAlgError(f"information matrices must be square, got shape {A.shape}")
    flat = A.reshape(-1, A.shape[-1], A.shape[-1])
    R = np.empty_like(flat)
    if whiten_all(flat, R) >= 0:
        raise np.linalg.LinAlgError("an information matrix is not positive definite")
    return R.reshape(A.shape)


def unique_rows(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(table (U, k), index (N,)): rows of ``a`` (N, k) float64 with ``a == table[index]`` bit
    for bit, equal rows sharing one entry (graphs with one information matrix for every edge
    keep one).  Rows are told apart by a hash of their bits, then compared."""
    N = a.shape[0]
    if N and a.strides[0] == 0:  # one row broadcast (the reader shares a matrix every edge states)
        return np.array(a[:1], dtype=np.float64), np.zeros(N, dtype=np.int64)
    a = np.ascontiguousarray(a, dtype=np.float64)
    if N == 0:
        return a[:0].copy(), np.zeros(0, dtype=np.int64)
    if np.array_equal(a.view(np.uint64), np.broadcast_to(a[:1].view(np.uint64), a.shape)):
        return a[:1].copy(), np.zeros(N, dtype=np.int64)
    words = a.view(np.uint64)
    order = np.argsort(_row_hashes(words), kind="stable")
    index, first = _group_rows(words, order)
    return a[first].copy(), index


@kernel
def _row_hashes(words):
    """A 64-bit hash of each row's bits (FNV-1a over its words)."""
    out = np.empty(words.shape[0], dtype=np.uint64)
    for r in range(words.shape[0]):
        h = np.uint64(14695981039346656037)
        for w in words[r]:
            h = (h ^ w) * np.uint64(1099511628211)
        out[r] = h
    return out


@kernel
def _group_rows(words, order):
    """Rows in hash order: each run of equal rows gets one table entry; (index (N,), the first
    row of each entry (U,))."""
    N = words.shape[0]
    index = np.empty(N, dtype=np.int64)
    first = np.empty(N, dtype=np.int64)
    U = 0
    prev = -1
    for q in range(N):
        r = order[q]
        same = prev >= 0
        if same:
            for k in range(words.shape[1]):
                if words[r, k] != words[prev, k]:
                    same = False
                    break
        if not same:
            first[U] = r
            U += 1
        index[r] = U - 1
        prev = r
    return index, first[:U]


class VarBlock:
    """The variables of one group: keys, element matrices ``X`` (N, m, m), offsets into δ."""

    def __init__(self, spec):
        self.spec = spec
        self.loops = GroupLoops(spec)
        self.keys: list[int] = []
        self.index: dict[int, int] = {}
        self.X: np.ndarray | None = None
        self.offsets: np.ndarray | None = None
        self._key_arrays: list = []  # key columns of this group's factors, numbered by number_keys

    def use_keys(self, keys: np.ndarray) -> None:
        """Add factor keys (uint64) to those :meth:`number_keys` numbers."""
        self._key_arrays.append(keys)

    def number_keys(self) -> None:
        """``keys`` (sorted) and ``index`` (key → local element index) of every key a factor uses."""
        ks = (sorted_unique(np.concatenate(self._key_arrays)) if self._key_arrays
              else np.zeros(0, dtype=np.uint64))
        self._sorted = ks
        self.keys = ks.tolist()
        self.index = dict(zip(self.keys, range(len(self.keys))))

    def local(self, keys: np.ndarray) -> np.ndarray:
        """Local element indices of ``keys`` (uint64, all in :attr:`keys`)."""
        return np.searchsorted(self._sorted, keys).astype(np.int64)


class FactorGroup:
    """All lie_factors factors of one (kind, group) with Gaussian noise.

    Arrays (F = factor count, n = group dimension): ``fidx`` graph positions,
    ``i1``/``i2`` element indices, ``v1``/``v2`` variable (column block)
    indices, ``o1``/``o2`` scalar offsets, ``C`` M⁻¹ or P⁻¹; the whitening of
    factor f is ``R[ridx[f]]`` (``R`` (U, n, n): one per distinct noise model);
    outputs of a linearization ``A1``, ``A2``, ``b``, ``sq``.  Ad(M⁻¹) is computed
    where a linearization needs it, from ``C``.
    """

    def __init__(self, kind, spec):
        self.kind, self.spec = kind, spec
        self.rows: list = []  # (graph index, key1, key2 | None, constant, R)
        self.columns: tuple = ()  # the rows transposed, by close_rows

    def close_rows(self, block: VarBlock) -> None:
        """Transpose the rows read into columns and hand their keys to ``block`` for numbering.

        Factors that share a noise model share its whitening R (one table entry)."""
        fidx, k1, k2, C, R = tuple(zip(*self.rows)) if self.rows else ((),) * 5
        self.rows = None
        k1 = np.array(k1, dtype=np.uint64)
        block.use_keys(k1)
        if self.kind == "between":
            k2 = np.array(k2, dtype=np.uint64)
            block.use_keys(k2)
        entry: dict = {}
        ridx = np.array([entry.setdefault(id(r), len(entry)) for r in R], dtype=np.int64)
        table = list({id(r): r for r in R}.values())
        self.columns = (fidx, k1, k2, C, (table, ridx))

    def finalize(self, block: VarBlock):
        n = self.spec.dim
        fidx, k1, k2, C, (R, ridx) = self.columns
        E = len(fidx)
        self.E = E
        self.loops = block.loops
        self.fidx = np.asarray(fidx, dtype=np.int64)
        self.i1 = block.local(k1)
        m = self.spec.mat
        # asarray: the array reader's columns are used as they are (no second copy)
        self.C = np.ascontiguousarray(C, dtype=np.float64).reshape(E, m, m)
        self.R = np.ascontiguousarray(R, dtype=np.float64).reshape(-1, n, n)
        self.ridx = np.asarray(ridx, dtype=np.int64)
        if self.kind == "between":
            self.i2 = block.local(k2)
        self.A1 = self.A2 = self.b = None  # allocated by the first linearization
        self.sq = np.empty(E)
        self.columns = ()

    def linearize(self, X):
        """Every factor's whitened Jacobians and right-hand side into ``A1``, ``A2``, ``b`` (allocated
        by the first call), ``sq``."""
        if self.b is None:
            n = self.spec.dim
            self.A1, self.b = np.empty((self.E, n, n)), np.empty((self.E, n))
            if self.kind == "between":
                self.A2 = np.empty((self.E, n, n))
        self.linearize_range(X, 0, self.E, self.A1, self.A2, self.b)

    def linearize_range(self, X, start: int, stop: int, A1, A2, b):
        """Factors ``start:stop`` into ``A1``, ``A2``, ``b`` (stop − start, ...), and ``sq[start:stop]``."""
        s = slice(start, stop)
        if self.kind == "between":
            self.loops.between_lin(X, self.i1[s], self.i2[s], self.C[s], self.R, self.ridx[s], A1, A2, b,
                                   self.sq[s])
        else:
            self.loops.prior_lin(X, self.i1[s], self.C[s], self.R, self.ridx[s], A1, b, self.sq[s])

    def evaluate(self, X, sq):
        if self.kind == "between":
            self.loops.between_err(X, self.i1, self.i2, self.C, self.R, self.ridx, sq)
        else:
            self.loops.prior_err(X, self.i1, self.C, self.R, self.ridx, sq)
