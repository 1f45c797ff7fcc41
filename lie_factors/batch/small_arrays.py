"""What :func:`lie_factors.batch.small_kernels.solve` takes and gives: the arrays of a small
problem as :mod:`lie_factors.batch.small` builds them (the kernels module's docstring says what
each holds), the columns of its tables and its outcome codes.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = ["Groups", "Variables", "Pools", "Losses", "Retraction", "Arena", "State", "G_COLUMNS", "P_COLUMNS",
           "S_COLUMNS", "BUFFERS", "OK", "FAULT", "SINGULAR", "NONFINITE_START", "NONFINITE_STEP"]

#: Columns of ``gtab``: the kernel's address, the position of ``jacobians`` in its descriptor,
#: factors, rows, variable slots, its first slot (in the slot tables), its first factor slot (in
#: ``fvar``), its first slot pair (in the assembly's targets), where its b rows start, its first
#: factor (in ``sqpool``/``stpool``/the losses).
G_COLUMNS = ("address", "jacobians", "F", "m", "nslot", "slot0", "fvar0", "pair0", "b0", "f0")
#: Entries of ``params``.
P_COLUMNS = ("lambda_initial", "lambda_factor", "lambda_upper", "lambda_lower", "min_model_fidelity",
             "relative_tol", "absolute_tol", "error_tol", "max_iterations", "diagonal_damping",
             "fixed_factor", "gauss_newton")
#: Entries of ``stats``: iterations, λ tried, converged (0/1), the outcome code, the group and
#: factor (within the group) of a fault or the scalar column of a refused pivot, the number of
#: errors recorded, the iterations at which LM gave up (λ reached its upper bound).
S_COLUMNS = ("iterations", "inner", "converged", "code", "group", "where", "recorded", "gave_up")
#: Outcome codes.
OK, FAULT, SINGULAR, NONFINITE_START, NONFINITE_STEP = range(5)
#: What a descriptor's entry holds, by its code: a number (``value``), or an element offset into
#: one of these arrays, which the solve turns into that element's address (so that Python reads no
#: address: each read costs it a microsecond or two).
BUFFERS = ("value", "best", "work", "delta", "offsets", "a", "b", "sq", "status", "floats", "ints")


class Groups(NamedTuple):
    """The factor groups (:mod:`~lie_factors.batch.small_kernels`): ``gtab`` (K,
    :data:`G_COLUMNS`), their descriptors as Python writes them, ``entries`` and ``codes`` (K, D:
    :data:`BUFFERS`), and as the solve resolves them, ``descs`` (K, D); per variable slot (S,):
    where its Jacobian block starts in the A pool, its strides between factors and rows, its
    dimension; ``fvar`` each factor slot's variable."""

    gtab: np.ndarray
    entries: np.ndarray
    codes: np.ndarray
    descs: np.ndarray
    astart: np.ndarray
    fstride: np.ndarray
    rstride: np.ndarray
    dim: np.ndarray
    fvar: np.ndarray


class Variables(NamedTuple):
    """The variables by index (V,): their ``dims`` and the ``pairs`` (Q, 2) that factors join."""

    dims: np.ndarray
    pairs: np.ndarray


class Pools(NamedTuple):
    """What the groups write: the A pool, the b pool, ‖b‖² and the status of each factor."""

    a: np.ndarray
    b: np.ndarray
    sq: np.ndarray
    status: np.ndarray


class Losses(NamedTuple):
    """Each factor's loss id, its parameter and its scale s
    (:mod:`~lie_factors.batch.small_kernels`)."""

    kind: np.ndarray
    k: np.ndarray
    scale: np.ndarray


class Retraction(NamedTuple):
    """Each value type's retraction entry (``address``; its descriptor as Python writes it,
    ``entries`` and ``codes``, and as the solve resolves it, ``descs``); ``var`` the variable of
    each value, block by block, and ``offsets`` where the solve writes each one's offset in δ."""

    address: np.ndarray
    entries: np.ndarray
    codes: np.ndarray
    descs: np.ndarray
    var: np.ndarray
    offsets: np.ndarray


class Arena(NamedTuple):
    """The problem's constants and indices that descriptors point at, gathered in one array of
    each type (codes ``floats`` and ``ints`` of :data:`BUFFERS`)."""

    floats: np.ndarray
    ints: np.ndarray


class State(NamedTuple):
    """The estimate ``best``, the values the groups read ``work``, and the step ``delta``."""

    best: np.ndarray
    work: np.ndarray
    delta: np.ndarray
