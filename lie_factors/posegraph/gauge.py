"""Which variables a factor graph leaves undetermined, decided from its structure alone: exact,
whatever the rounding of the machine that factors the system.

Two rules, each of which proves the Gauss–Newton system singular in exact arithmetic:

* **Rows.**  A variable of dimension d whose factors have fewer than d rows in all (the sum
  of the dimensions of the factors on it; none, for a variable in no factor) has Jacobian
  columns of rank below d.
* **A free gauge.**  The variables joined by factors fall into connected components.  A
  factor is *relative* when its error does not change if every variable it touches moves by
  one change of frame, X ↦ G·X: the Between factors on the registered groups (Pose2, Pose3,
  Rot3, Similarity2, Similarity3), lie_factors' and GTSAM's (:func:`is_relative`).  A
  component whose factors are all relative keeps its error under a change of frame of all
  its variables: that motion is in the null space of its Jacobian, and the system is
  singular.  A prior anchors its component; a factor of any other kind (a GTSAM factor the
  batch solver leaves to GTSAM, a user's ``CustomFactor``, a landmark measurement) may or may
  not, so a component holding one is not decided here: the pivot rule
  (:mod:`lie_factors.sparse.pivots`) decides it.

Neither rule refuses a system that can be solved.  :func:`undetermined` applies both to a
graph given as index arrays (the batch solver's :class:`~lie_factors.batch.graph.Problem`,
:func:`of_pose_graph` a :class:`~lie_factors.posegraph.graph.PoseGraph`'s arrays), in numpy
with no loop per factor; :class:`Components` applies them update by update (the incremental
smoother), by union–find.  Numpy only (GTSAM and the factor classes are imported where a
factor object is classified).
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import numpy as np

from ..errors import IndeterminantLinearSystem
from ..kernels import registry
from .topology import components

__all__ = ["Components", "Undetermined", "free_gauge", "is_relative", "of_pose_graph", "short_rows",
           "too_few_rows", "undetermined"]


class Undetermined(NamedTuple):
    """A variable the structure leaves undetermined: its index (in the caller's numbering; None
    for a key outside it) and the reason, with ``{}`` where the variable's name goes."""

    variable: int | None
    reason: str

    def error(self, what: str, name: str) -> IndeterminantLinearSystem:
        """The one-line error ``what: reason``, the variable called ``name`` (GTSAM's spelling of
        its key), ``.variable`` its index."""
        return IndeterminantLinearSystem(f"{what}: {self.reason.format(name)}", self.variable)


def too_few_rows(variable: int | None, rows: int, dim: int) -> Undetermined:
    """A variable in factors of ``rows`` rows in all (0: in no factor), fewer than its ``dim``."""
    if rows == 0:
        return Undetermined(variable, "{} is in no factor: nothing determines it")
    return Undetermined(variable, f"{{}} has {rows} row{'s' if rows > 1 else ''} of factors for its {dim} "
                                  "dimensions: they cannot determine it")


def _free(variable: int, size: int) -> Undetermined:
    return Undetermined(variable, f"the component of {{}} ({size} variable{'s' if size > 1 else ''}) "
                                  "has no prior: its gauge is free")


@functools.lru_cache(maxsize=None)
def _relative_types() -> tuple:
    import gtsam

    from ..factors import BetweenFactor

    native = (getattr(gtsam, f"BetweenFactor{info.gtsam}", None) for info in registry.GROUPS.values())
    return (BetweenFactor,) + tuple(t for t in native if t is not None)


def is_relative(factor) -> bool:
    """Whether ``factor`` is known to be relative (its error unchanged by one change of frame of
    all its variables): a Between factor on a registered group, lie_factors' or GTSAM's, whatever
    its noise model."""
    return isinstance(factor, _relative_types())


def free_gauge(count: int, u: np.ndarray, v: np.ndarray, anchored: np.ndarray) -> np.ndarray:
    """(count,) bool: the variables of components with no anchoring factor.

    Variables 0 … count − 1; ``u``, ``v`` (K,): the pairs of variables some factor joins (every
    factor on several variables: at least a chain through them); ``anchored`` (A,): a variable
    of each factor that is not known to be relative.
    """
    return _labelled(count, u, v, anchored)[1]


def _labelled(count: int, u, v, anchored) -> tuple[np.ndarray, np.ndarray]:
    """(label, free) (count,): each variable's component (its smallest variable), and
    :func:`free_gauge`."""
    label = components(count, np.asarray(u, dtype=np.int64), np.asarray(v, dtype=np.int64))
    fixed = np.zeros(count, dtype=bool)
    fixed[label[np.asarray(anchored, dtype=np.int64)]] = True
    return label, ~fixed[label]


def undetermined(dims: np.ndarray, rows: np.ndarray, u: np.ndarray, v: np.ndarray,
                 anchored: np.ndarray) -> Undetermined | None:
    """The first variable the structure leaves undetermined (module docstring), or None.

    ``dims`` (V,): the variables' dimensions; ``rows`` (V,): the rows of the factors on each
    (a factor's dimension counted once for each variable it touches); ``u``, ``v``,
    ``anchored``: as :func:`free_gauge` takes them.  A variable with too few rows first; else
    the component with the smallest variable among those with no anchor, named by that
    variable.
    """
    dims = np.asarray(dims, dtype=np.int64)
    short = np.flatnonzero(np.asarray(rows) < dims)
    if short.size:
        k = int(short[0])
        return too_few_rows(k, int(rows[k]), int(dims[k]))
    label, free = _labelled(len(dims), u, v, anchored)
    if not free.any():
        return None
    first = int(np.argmax(free))
    return _free(first, int(np.count_nonzero(label == label[first])))


def of_pose_graph(pg) -> Undetermined | None:
    """:func:`undetermined` of a :class:`~lie_factors.posegraph.graph.PoseGraph` from its arrays,
    variables numbered as ``pg.keys``: its edges are relative, its priors anchor, and each
    factor has the group's dimension in rows."""
    P, n = len(pg.keys), pg.info.dim
    ij = pg.index(np.asarray(pg.edge_keys).reshape(-1)).reshape(-1, 2)
    prior = pg.index(np.asarray(pg.prior_keys).reshape(-1))
    rows = n * (np.bincount(ij.reshape(-1), minlength=P) + np.bincount(prior, minlength=P))
    return undetermined(np.full(P, n), rows, ij[:, 0], ij[:, 1], prior)


def short_rows(first: int, dims, rows) -> Undetermined | None:
    """The first of the variables ``first``, ``first`` + 1, … whose ``rows`` (their factors'
    rows) are fewer than ``dims`` (their dimensions), or None: a new variable of an update."""
    for q, (d, r) in enumerate(zip(dims, rows)):
        if r < d:
            return too_few_rows(first + q, int(r), int(d))
    return None


class Components:
    """The components of a growing graph, update by update: a union–find over variables 0, 1, …
    (each root the smallest variable of its component), with a flag per root, "holds a factor
    not known to be relative", and its size.

    :meth:`join` computes what an update would make of them without changing anything (a
    refused update leaves them as they were); :meth:`commit` keeps it.  Python lists: an update
    of one or two factors costs a few list reads.
    """

    def __init__(self):
        self.parent: list[int] = []
        self.anchored: list[bool] = []
        self.size: list[int] = []

    def __len__(self) -> int:
        return len(self.parent)

    def _root(self, a: int) -> int:
        parent = self.parent
        while parent[a] != a:
            parent[a] = parent[parent[a]]  # path halving: the partition is unchanged
            a = parent[a]
        return a

    def join(self, new: int, u, v, anchored, touched) -> tuple:
        """What adding ``new`` variables (numbered from ``len(self)``) and factors would make of
        the components: ``u``, ``v`` the pairs of variables the factors join, ``anchored`` a
        variable of each factor not known to be relative, ``touched`` every variable of the
        update (sequences of ints).  Returns (plan, finding): the plan for :meth:`commit`, and
        the first touched component with no anchor (:class:`Undetermined`) or None."""
        n0 = len(self.parent)
        up: dict = {}  # an old root → the root it is joined under
        flag: dict = {}
        size: dict = {}

        def root(a):
            if a < n0:
                a = self._root(a)
            r = a
            while r in up:
                r = up[r]
            while a in up and up[a] != r:  # compress the update's own links
                up[a], a = r, up[a]
            return r

        def fixed(r):
            return flag[r] if r in flag else r < n0 and self.anchored[r]

        def count(r):
            return size[r] if r in size else self.size[r] if r < n0 else 1

        for a, b in zip(u, v):
            ra, rb = root(a), root(b)
            if ra != rb:
                lo, hi = (ra, rb) if ra < rb else (rb, ra)
                up[hi] = lo
                flag[lo] = fixed(lo) or fixed(hi)
                size[lo] = count(lo) + count(hi)
        for a in anchored:
            flag[root(a)] = True
        free = None
        for a in touched:
            r = root(a)
            if not fixed(r) and (free is None or r < free):
                free = r
        return (n0, new, up, flag, size), None if free is None else _free(free, count(free))

    def commit(self, plan: tuple) -> None:
        """Keep what :meth:`join` computed (nothing may have changed in between)."""
        n0, new, up, flag, size = plan
        self.parent.extend(range(n0, n0 + new))
        self.anchored.extend([False] * new)
        self.size.extend([1] * new)
        for hi, lo in up.items():
            self.parent[hi] = lo
        for r, f in flag.items():
            self.anchored[r] = f
        for r, s in size.items():
            self.size[r] = s

