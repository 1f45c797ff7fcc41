"""Every factor of a kind in a graph evaluated in one kernel call, for a ``Values`` an optimizer holds.

For GTSAM's algorithms run by our drop-in optimizers (:mod:`lie_factors.optimizers`), which hold
the ``Values`` GTSAM linearizes at::

    plan = KindPlan(graph)
    with plan.prepared(values):            # reads each variable once, evaluates every factor
        linear = graph.linearize(values)   # each kind factor's callback returns its row

Inside the ``with``, a factor's callback, when GTSAM hands it that very ``values`` object,
returns its rows of the results (the same kernel, on the same values) instead of fetching its
variables and calling the kernel itself; for any other object it evaluates as usual.  The
values must not change inside the ``with``.  If reading the variables fails (a missing key, a
wrong type), nothing is prepared and the callbacks raise their usual errors.
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from ..factors import PlanBase
from . import kind as _kind
from .kind import KindFactor, check_statuses, fetch


class _KindEvaluation:
    """The factors of one kind in a graph: their keys per variable slot, constants stacked, and
    the results of the last evaluation (unwhitened, as a CustomFactor's callback returns them,
    unless :meth:`whiten` gave each factor's whitening)."""

    def __init__(self, kind, members: list):
        self.kind = kind
        self.members = members
        F = len(members)
        self.slot_keys = []
        self.index = []
        for j in range(len(kind.variables)):
            # each slot's distinct keys, first seen first (a dictionary: np.unique's sort costs
            # more on the few factors of an update)
            place: dict = {}
            self.index.append(np.fromiter((place.setdefault(int(f._keys_[j]), len(place)) for f in members),
                                          dtype=np.int64, count=F))
            self.slot_keys.append(list(place))
        self.C = [np.ascontiguousarray(np.array([f._constants[c] for f in members])) for c in range(len(kind.constants))]
        m = kind.dim
        self.e = np.zeros((F, m))
        self.A = np.zeros((F, m, kind.columns))
        self._R = np.eye(m)[None]
        self._ridx = np.zeros(F, dtype=np.int64)
        self.b = np.zeros((F, m))
        self._sq = np.zeros(F)
        self.status = np.zeros(F, dtype=np.int64)

    def whiten(self, R: list) -> None:
        """Whiten the results by each factor's R (RᵀR = its information): A = R·J, b = −R·e."""
        table = {id(r): r for r in R}
        entry = {k: i for i, k in enumerate(table)}
        self._R = np.ascontiguousarray(np.array(list(table.values()), dtype=np.float64))
        self._ridx = np.array([entry[id(r)] for r in R], dtype=np.int64)

    def evaluate(self, values) -> None:
        kind = self.kind
        args = list(kind.tags)
        name = _factor_name(self.members[0])
        for j, t in enumerate(kind.variables):
            X = np.empty((len(self.slot_keys[j]),) + t.shape)
            for i, key in enumerate(self.slot_keys[j]):
                X[i] = fetch(values, key, t, name)
            args += [X, self.index[j]]
        args += self.C
        args += [self._R, self._ridx, self.e, self.A, self.b, self._sq, self.status, 0, len(self.members), True]
        kind.evaluate(*args)
        check_statuses(self.members, self.status)

    def rows(self, f: int) -> tuple:
        kind = self.kind
        return self.e[f], [self.A[f, :, o:end] for o, end in kind.blocks]


class KindPlan(PlanBase):
    """Every kind factor of ``graph``, evaluated one kind at a time (module docstring)."""

    def __init__(self, graph):
        members: dict = {}
        for i in range(graph.size()):
            f = graph.at(i)
            if isinstance(f, KindFactor):
                members.setdefault(id(f.kind), []).append(f)
        self.groups = [_KindEvaluation(fs[0].kind, fs) for fs in members.values()]
        self.slots: dict = {}
        for group in self.groups:
            self.slots.update((f, (group, k)) for k, f in enumerate(group.members))
        self.values = None
        self.last = None

    def _activate(self, plan) -> None:
        _kind.active_plan = plan


class KindRows:
    """Stored factors of one kind, evaluated by index: each factor's keys, constants and
    whitening R (RᵀR its information) are read once, into a slot (:meth:`add`); :meth:`rows`
    then linearizes any set of slots with one kernel call, gathering the constants and
    whitenings by index and reading each distinct variable once (an incremental smoother
    relinearizes the same factors again and again)."""

    def __init__(self, kind):
        self.kind = kind
        self.members: list = []  # each slot's factor (its statuses and names)
        self.keys = np.empty((8, len(kind.variables)), dtype=np.uint64)
        self.C = [np.empty((8,) + t.shape) for t in kind.constants]
        self.ridx = np.empty(8, dtype=np.int64)
        self._R_stack = np.empty((4, kind.dim, kind.dim))  # the distinct whitenings, by first use
        self._R_slot: dict = {}  # R's bytes → its place in _R_stack (equal whitenings share one)

    def add(self, f, R: np.ndarray) -> int:
        """Store the factor ``f`` (``_keys_``, ``_constants``: a kind's factor, or a twin's row)
        whitened by ``R``; returns its slot."""
        n = len(self.members)
        if n == self.keys.shape[0]:
            self.keys, self.ridx = (np.concatenate([a, np.empty_like(a)]) for a in (self.keys, self.ridx))
            self.C = [np.concatenate([C, np.empty_like(C)]) for C in self.C]
        self.keys[n] = [int(k) for k in f._keys_]
        for C, c in zip(self.C, f._constants):
            C[n] = c
        R = np.ascontiguousarray(R, dtype=np.float64)
        r = self._R_slot.get(R.tobytes())
        if r is None:  # (a user may give each factor its own noise model object, all equal)
            r = len(self._R_slot)
            if r == self._R_stack.shape[0]:
                self._R_stack = np.concatenate([self._R_stack, np.empty_like(self._R_stack)])
            self._R_stack[r] = R
            self._R_slot[R.tobytes()] = r
        self.ridx[n] = r
        self.members.append(f)
        return n

    @property
    def whitenings(self) -> int:
        """How many distinct whitenings the stored factors use."""
        return len(self._R_slot)

    def rows(self, slots: np.ndarray, values) -> np.ndarray:
        """[A | b] (F, m, Σd + 1) of the factors in ``slots`` (F,) at ``values``: the Jacobians
        whitened by each factor's R and b = −R·e, what GTSAM's linearization of the factor gives.
        Numbers that are not finite raise ``InputError`` naming the factor's class."""
        kind = self.kind
        F = len(slots)
        members = self.members
        name = _factor_name(members[slots[0]])
        args = list(kind.tags)
        keys = self.keys[slots]
        for j, t in enumerate(kind.variables):
            place: dict = {}  # each distinct key's place, first seen first (np.unique sorts: slower here)
            index = np.fromiter((place.setdefault(k, len(place)) for k in keys[:, j].tolist()), dtype=np.int64,
                                count=F)
            X = np.empty((len(place),) + t.shape)
            for i, key in enumerate(place):
                X[i] = fetch(values, key, t, name)
            args += [X, index]
        args += [C[slots] for C in self.C]
        m = kind.dim
        A, b, status = np.zeros((F, m, kind.columns)), np.zeros((F, m)), np.zeros(F, dtype=np.int64)
        args += [self._R_stack, self.ridx[slots], np.zeros((F, m)), A, b, np.zeros(F), status, 0, F, True]
        kind.evaluate(*args)
        if status.any():
            check_statuses([members[s] for s in slots.tolist()], status)
        Ab = np.concatenate([A, b[:, :, None]], axis=2)
        finite = np.isfinite(Ab).all(axis=(1, 2))
        if not finite.all():
            raise InputError(f"{_factor_name(members[slots[int(np.argmin(finite))]])} linearized to "
                             "non-finite numbers")
        return Ab


def _factor_name(f) -> str:
    """The class a user knows ``f`` by: GTSAM's, for a twin's row (:mod:`lie_factors.expressions.twins`)."""
    return type(f.factor if hasattr(f, "twin") else f).__name__
