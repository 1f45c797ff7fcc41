"""The block factor's state: namedtuples of arrays, and the small kernels every pass shares.

The factor is a tree of block columns (an elimination tree with one node per
variable, ISAM2's Bayes tree at the granularity of variables).  Node ``j`` holds

- its *separator* ``S_j``: the variables after ``j`` in the elimination order
  whose rows of ``L`` are nonzero in column ``j`` (ids in the int pool, sorted
  by position);
- its *conditional* ``[R_j | T_j | d_j]`` (d × (d + s + 1), row-major in the
  float pool): ``R_j δ_j + T_j δ_S = d_j``, with ``R_jᵀ`` the diagonal block of
  ``L`` and ``T_jᵀ`` the block column below it (``L = Rᵀ``);
- its *update matrix* ``U_j`` ((s + 1) × (s + 1), augmented with the right-hand
  side, stored as its upper triangle row by row, :func:`packed` floats): the
  Schur complement its subtree passes to its ancestors, the multifrontal update
  matrix (Duff and Reid, "The multifrontal solution of indefinite sparse
  symmetric linear equations", ACM TOMS 1983; ISAM2's cached marginal factor,
  Kaess et al., "iSAM2", IJRR 2012, Alg. 4).  It is kept where a later update
  can re-eliminate the parent without the node: the subtree below is then not
  visited again.

Positions are increasing integers: an update gives the re-eliminated variables
positions after every other, so a node's ancestors always come after it.

Factors are stored as whitened Jacobians ``[A_1 … A_k | b]`` (r × (D + 1),
row-major), the rows ``A δ ≈ b`` of one factor; a factor enters the frontal
matrix of its first variable in the order.

The kernels take these structures whole.  numba passes a namedtuple of arrays
as the arrays it holds (by reference: a kernel writes into them), but cannot
rebind a field: an array that grows is reallocated by the Python caller, which
then builds the tuple again (:class:`~lie_factors.incremental.cholesky.BlockFactor`
keeps one of each).  Shapes: ``V`` variable capacity, ``F`` factor capacity.

Why the kernels bind the fields they read to locals once, at their top: in numba every
field read, and every array handed to an inlined helper (a structure: each of its
arrays), takes a reference count of its own, which numba drops only where nothing between
its start and its end releases an array: no buffer reassigned as it grows, no call to
another compiled kernel (its error exit releases everything), no array that dies on one
side of a branch only.  So a helper called in a loop takes arrays (or a structure it reads
at its top, where nothing in it releases one), buffers filled in a loop are sized once per
call to never grow, and the dense kernels are called from the top of a pass.
"""

from __future__ import annotations

import math
from collections import namedtuple

import numpy as np

from ..kernels.jit import kernel

#: Status codes of :func:`lie_factors.incremental.elimination.reeliminate` and its passes.
OK, NEED_INT, NEED_FLOAT, NOT_POSITIVE = 0, 1, 2, 3

#: The tree of block columns, one node per variable: (V,) arrays but ``roots`` (1,).
#: ``dim``: block dimension; ``voff``: offset of the block in δ; ``pos``: position in the
#: elimination order; ``parent`` (−1: a root); ``first``: first child and ``nxt``: next
#: sibling (the roots are linked through ``nxt`` from ``roots[0]``), −1 for none; ``nchild``;
#: ``sep_start``, ``sep_len``: the separator in the int pool; ``sep_dim``: its scalars;
#: ``cond``: the conditional in the float pool (−1: never eliminated); ``ustart``: the update
#: matrix in the float pool (−1: none kept).
Tree = namedtuple("Tree", ["dim", "voff", "pos", "parent", "first", "nxt", "nchild", "sep_start", "sep_len",
                           "sep_dim", "cond", "ustart", "roots"])

#: The fields of :data:`Tree` with one entry per variable, and what a new entry holds.
TREE_FILL = {"dim": 0, "voff": 0, "pos": 0, "parent": -1, "first": -1, "nxt": -1, "nchild": 0, "sep_start": 0,
             "sep_len": 0, "sep_dim": 0, "cond": -1, "ustart": -1}

#: The factors: per factor (F,) ``fnv`` (variables), ``fvstart`` (first entry in ``fvars``),
#: ``frows``, ``fcols`` (r, D + 1), ``fjstart`` (first entry in ``jac``), ``fstamp`` (the last
#: ordering graph that took it); ``fvars`` its variables, one entry per (factor, variable);
#: ``jac`` the Jacobians; and each variable's adjacency list: ``ahead`` (V,) its first entry
#: (−1: none), ``anext`` the next entry and ``afac`` the entry's factor (parallel to ``fvars``).
FactorStore = namedtuple("FactorStore", ["fnv", "fvstart", "frows", "fcols", "fjstart", "fstamp", "fvars", "jac",
                                         "ahead", "anext", "afac"])

#: The per-factor fields of :data:`FactorStore`, the per-(factor, variable) ones.
FACTOR_FIELDS = ("fnv", "fvstart", "frows", "fcols", "fjstart", "fstamp")
ENTRY_FIELDS = ("fvars", "anext", "afac")

#: The pools the nodes point into: ``ipool`` (separators, int64) and ``fpool`` (conditionals
#: and update matrices, float64).  Entries of re-eliminated nodes are freed, not reused, until
#: the pools are compacted.
Pools = namedtuple("Pools", ["ipool", "fpool"])

#: Scratch of the marking and re-elimination kernels, reused by every update.  (V,): ``aidx``
#: (a variable's index in the update's order, −1 on entry and return), ``mark`` (the
#: symbolic pass's stamps), ``loc`` (a variable's first column in the current front),
#: ``chead``/``cnext`` (the children lists being built), ``flag`` (zero on entry and return);
#: ``stamps`` (1,): the last stamp used in ``mark``; ``stats`` (8,): the counts
#: :func:`~lie_factors.incremental.elimination.reeliminate` adds to.
Workspace = namedtuple("Workspace", ["aidx", "mark", "loc", "chead", "cnext", "flag", "stamps", "stats"])

#: The (V,) fields of :data:`Workspace`, and what a new entry holds.
WORKSPACE_FILL = {"aidx": -1, "mark": 0, "loc": 0, "chead": -1, "cnext": -1, "flag": 0}

#: Back-substitution's flags, (V,): ``replaced`` (re-eliminated since the last solve),
#: ``changed`` (moved during this solve), ``visited`` (scratch).
Wildfire = namedtuple("Wildfire", ["replaced", "changed", "visited"])

#: What re-elimination computes for the K variables of its order (index k: ``order[k]``),
#: written to the tree only once every pivot has passed: ``old_pos`` (to restore),
#: ``parent``, ``sep_start``, ``sep_len``, ``sep_dim``, ``cond``, ``ustart``, ``nchild`` (K,);
#: ``fstart`` (K + 1,): where each variable's factors start in the list of factors to assemble;
#: ``orphan_parent`` (orphans,): the node each orphan subtree hangs from; ``roots`` (1,): the
#: first new root.
Columns = namedtuple("Columns", ["old_pos", "parent", "sep_start", "sep_len", "sep_dim", "cond", "ustart",
                                 "nchild", "fstart", "orphan_parent", "roots"])


@kernel
def packed(S1):
    """Entries of an update matrix of side ``S1`` stored as its upper triangle, row by row."""
    return S1 * (S1 + 1) // 2


@kernel
def push(buf, n, v):
    """buf[n] = v, in ``buf`` or in a copy of twice its size when it is full (the caller keeps
    the array returned)."""
    if n == buf.shape[0]:
        grown = np.empty(2 * n + 16, dtype=buf.dtype)
        for i in range(n):  # not grown[:n] = buf: numba's shape-mismatch message costs a first run seconds
            grown[i] = buf[i]
        buf = grown
    buf[n] = v
    return buf


def grow(a: np.ndarray, n: int, fill=None) -> np.ndarray:
    """``a`` with room for at least ``n`` entries along its first axis (capacity doubles)."""
    if a.shape[0] >= n:
        return a
    cap = max(n, 2 * a.shape[0], 16)
    out = np.empty((cap,) + a.shape[1:], dtype=a.dtype)
    out[:a.shape[0]] = a
    if fill is not None:
        out[a.shape[0]:] = fill
    return out


#: When a re-elimination finds a pool short, the pool is left with room for this many times
#: what is live in it plus what was asked: the next shortage comes only after half the live
#: entries' size more is written, so compactions move at most two entries per entry written
#: (:func:`pool_plan`), for a pool at most 1.5 times what it holds after a shortage.
POOL_ROOM = 1.5


def pool_plan(top: int, freed: int, capacity: int, size: int, room: float = POOL_ROOM) -> tuple:
    """What to do for a re-elimination that asked a pool of ``capacity`` entries, filled to
    ``top`` (``freed`` of them by nodes since replaced), for ``size`` entries in all: returns
    (compact, capacity to grow to).  Compacted when more than half of what is filled is freed;
    grown, to ``room`` × (what is then live + what was asked), when that does not fit ``room``
    times in it."""
    compact = 2 * freed > top
    live = top - freed if compact else top
    want = live + (size - top)
    return compact, math.ceil(room * want) if capacity < room * want else capacity


def grow_pool(a: np.ndarray, n: int) -> np.ndarray:
    """The pool ``a`` with room for ``n`` entries, its entries kept.  Pools are most of the
    factor's memory: they grow in place (``ndarray.resize``: a large block is remapped, not
    copied, so the old and the new pool are never both in memory); no view of a pool
    outlives a call."""
    if a.shape[0] >= n:
        return a
    a.resize(n, refcheck=False)
    return a


def grown(structure, n: int, fill: dict):
    """``structure`` (a namedtuple of arrays) with its fields named in ``fill`` grown to at least
    ``n`` entries (new entries set to ``fill[name]``); the other fields as they are."""
    return structure._replace(**{name: grow(getattr(structure, name), n, value) for name, value in fill.items()})


def child_outside(tree: Tree, vs, inside: np.ndarray):
    """The first (v, c) with ``c`` a child of a node ``v`` of ``vs`` that is not ``inside`` (a
    mask over the nodes), or None: then ``vs`` are whole subtrees (every node below one of them
    is one of them)."""
    for v in vs:
        c = int(tree.first[v])
        while c >= 0:
            if not inside[c]:
                return v, c
            c = int(tree.nxt[c])
    return None


def empty_tree() -> Tree:
    return Tree(*(np.zeros(0, dtype=np.int64) for _ in TREE_FILL), np.full(1, -1, dtype=np.int64))


def empty_store() -> FactorStore:
    return FactorStore(*(np.zeros(0, dtype=np.int64) for _ in FactorStore._fields[:7]), np.zeros(0),
                       *(np.zeros(0, dtype=np.int64) for _ in range(3)))


def empty_workspace() -> Workspace:
    return Workspace(*(np.zeros(0, dtype=np.int64) for _ in WORKSPACE_FILL), np.zeros(1, dtype=np.int64),
                     np.zeros(8, dtype=np.int64))


def empty_wildfire() -> Wildfire:
    return Wildfire(*(np.zeros(0, dtype=np.int64) for _ in Wildfire._fields))
