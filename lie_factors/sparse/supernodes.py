"""A sparse Cholesky factor as CHOLMOD lays out a supernodal one: what
:meth:`lie_factors.sparse.cholmod.Cholesky.supernodes` hands over and
:mod:`lie_factors.sparse.selinv` reads."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = ["Supernodes"]


class Supernodes(NamedTuple):
    """A factor P·A·Pᵀ = L·Lᵀ by supernodes, CHOLMOD's layout: ``perm`` (n,) with (P·x)[k] =
    x[perm[k]]; supernode t holds L's columns ``first[t]:first[t+1]``, their rows are
    ``rows[rowptr[t]:rowptr[t+1]]`` (ascending; its own columns first), and its entries a dense
    column-major block (rows × columns) from ``values[valptr[t]]``.  A simplicial factor is the
    same with one column per supernode (:meth:`from_lower`)."""

    perm: np.ndarray
    first: np.ndarray
    rowptr: np.ndarray
    valptr: np.ndarray
    rows: np.ndarray
    values: np.ndarray

    @classmethod
    def from_lower(cls, perm, colptr, rowind, values, d) -> "Supernodes":
        """One supernode per column of the unit L·diag(d)·Lᵀ of :meth:`Cholesky.lower`, as L·Lᵀ."""
        col = np.repeat(np.arange(len(colptr) - 1), np.diff(colptr))
        first = np.arange(len(colptr), dtype=np.int64)
        return cls(perm, first, colptr, colptr, rowind, values * np.sqrt(d)[col])
