"""False loop closures planted in a pose graph, of the kinds robust pose-graph papers test with
(Sünderhauf and Protzel's Vertigo set them): a graph's own test of a false-closure rejection.
:func:`corrupt` plants them (what ``lie-factors corrupt`` runs); :func:`write_corruption` writes
the corrupted graph and the list of what was planted.

**How many.**  round(``fraction`` × the input's loop closures), a loop closure
being an edge between poses whose keys are not consecutive: 0.2 plants one
false closure for every five true ones (as robust-PGO papers count an outlier
rate against the inlier closures).  Each planted closure carries the
information matrix of one of the input's loop closures, drawn at random, so that
its noise model looks like a real one; a run (below) draws one for all its
members.  Planted closures join poses whose keys are at least 2 apart and that
no edge already joins, and no pair twice.

**Kinds.**

* ``uniform``: random pose pairs, each with a random relative pose;
* ``local``: pose pairs at most :data:`LOCAL_SPAN` poses apart along the
  trajectory, each with a random relative pose;
* ``group``: runs of :data:`RUN_LENGTH` consecutive false closures i+k → j+k
  between two random places, all agreeing with one wrong relative pose M of
  place j seen from place i (perceptual aliasing): Z_k = X_{i+k}⁻¹·X_i·M·X_j⁻¹·X_{j+k};
* ``near``: such runs whose relation is the true one moved by δ at the run's
  middle closure c (M = X_i⁻¹·X_{j+c}·Exp(δ)·X_{j+c}⁻¹·X_j), each member then off
  its true relation by −Ad(X_{j+k}⁻¹·X_{j+c})·δ; δ is scaled so that every
  member's offset, whitened by the run's information Ω (√(eᵀΩe)), lies in
  :data:`NEAR_SIGMAS`: each closure looks plausible alone.

X are the reference poses, the input's least-squares optimum
(:func:`lie_factors.optimize`, the default command): the input is taken as free
of false closures, so its optimum is the best truth it knows.

A random relative pose has a rotation uniform on SO(2) or SO(3) and a
translation uniform in the box of the input's loop closures' translations
(per axis, the largest magnitude): what a place-recognition front end could
have reported.  Measurements are exact (no noise added): a planted closure is
false by its relation, not by its noise.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from . import quaternion
from .errors import InputError
from .posegraph.graph import PoseGraph, is_loop_closure
from .util.atomic import check_writable, replace_atomically

__all__ = ["KINDS", "LOCAL_SPAN", "RUN_LENGTH", "NEAR_SIGMAS", "Corruption", "corrupt", "plant",
           "write_corruption", "planted_path"]

#: The kinds of false closures (module docstring).
KINDS = ("uniform", "local", "group", "near")

#: ``local``: the most poses, along the trajectory, between a planted closure's ends.
LOCAL_SPAN = 20

#: ``group`` and ``near``: the length of a run, uniform in this range (inclusive).
RUN_LENGTH = (8, 12)

#: ``near``: how far each member of a run is from its true relation, in whitened norm.
NEAR_SIGMAS = (5.0, 15.0)

#: Tries per planted closure before the graph is declared too small for the request.
_TRIES = 200

#: ``near``: directions of δ tried per run (the second half without rotation, whose lever arm
#: along the run can spread the members' offsets beyond NEAR_SIGMAS' ratio).
_NEAR_DIRECTIONS = 100


@dataclass
class Corruption:
    """A pose graph with false loop closures planted.

    ``graph``: a :class:`~lie_factors.posegraph.graph.PoseGraph`, the input's edges
    (E of them, in their order) then the k planted ones; ``planted`` (k,) int64:
    the planted edges' indices in ``graph`` (E … E + k − 1); ``kind``, ``fraction``,
    ``seed``: what was asked."""

    graph: PoseGraph
    planted: np.ndarray
    kind: str
    fraction: float
    seed: int

    def planted_keys(self) -> np.ndarray:
        """(k, 2) int64: the keys each planted closure joins, in its direction."""
        return self.graph.edge_keys[self.planted]


def corrupt(graph: "PoseGraph | str", *, fraction: float, kind: str = "uniform", seed: int = 0) -> Corruption:
    """``graph`` (a :class:`~lie_factors.posegraph.graph.PoseGraph` or a g2o path) with
    round(``fraction`` × its loop closures) false ones of ``kind`` (``uniform``, ``local``,
    ``group``, ``near``; module docstring) appended, drawn from ``seed``: a :class:`Corruption`.

    The same ``fraction``, ``kind`` and ``seed`` on the same graph plant the same closures.
    Raises :class:`~lie_factors.errors.InputError` for a request that cannot be met.
    """
    if isinstance(graph, str):
        from .files import read_g2o

        graph = read_g2o(graph)
    if not isinstance(graph, PoseGraph):
        raise InputError(f"corrupt: expected a PoseGraph or a g2o path, got {type(graph).__name__}")
    if graph.landmarks is not None:
        raise InputError("corrupt: a graph with landmarks is not a pose graph to plant closures in")
    _check_request(graph, fraction, kind, seed)
    reference = None
    if _needs_reference(kind):
        from .solve import optimize

        reference = optimize(graph).poses
    return plant(graph, fraction=fraction, kind=kind, seed=seed, reference=reference)


def _needs_reference(kind: str) -> bool:
    return kind in ("group", "near")


def _check_request(pg: PoseGraph, fraction, kind: str, seed) -> int:
    """The number of closures to plant; :class:`InputError` for a request that cannot be met."""
    if kind not in KINDS:
        raise InputError(f"kind must be one of {', '.join(KINDS)}, got {kind!r}")
    if isinstance(fraction, bool) or not isinstance(fraction, (int, float, np.floating, np.integer)) \
            or not np.isfinite(fraction) or not 0.0 < float(fraction) <= 10.0:
        raise InputError(f"fraction must be a number in (0, 10] (of the graph's loop closures), got {fraction!r}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise InputError(f"seed must be a non-negative integer, got {seed!r}")
    if pg.group not in ("Pose2", "Pose3"):
        raise InputError(f"false closures are planted in Pose2 and Pose3 graphs, not {pg.group}")
    closures = int(pg.loop_closures().size)
    if closures == 0:
        raise InputError(f"{pg.name or 'the graph'} has no loop closures: a fraction of them is none")
    count = int(round(float(fraction) * closures))
    if count == 0:
        raise InputError(f"fraction {fraction:g} of {closures} loop closures rounds to no closure")
    return count


def plant(pg: PoseGraph, *, fraction: float, kind: str = "uniform", seed: int = 0,
          reference: np.ndarray | None = None) -> Corruption:
    """:func:`corrupt` with the reference poses given: ``reference`` (P, m, m), the poses in key
    order the ``group`` and ``near`` runs take their relations from (needed for those kinds only)."""
    count = _check_request(pg, fraction, kind, seed)
    if _needs_reference(kind):
        if reference is None:
            raise InputError(f"kind {kind!r} needs reference poses")
        reference = np.asarray(reference, dtype=np.float64)
        if reference.shape != (pg.pose_count, pg.info.mat, pg.info.mat):
            raise InputError(f"reference: expected shape {(pg.pose_count, pg.info.mat, pg.info.mat)}, "
                             f"got {reference.shape}")
    rng = np.random.default_rng(int(seed))
    lc = pg.loop_closures()
    planter = _Planter(pg, rng, pg.information[lc], _translation_box(pg, lc))
    if kind in ("uniform", "local"):
        planter.singles(count, LOCAL_SPAN if kind == "local" else None)
    else:
        planter.runs(count, reference, near=kind == "near")
    keys = np.array(planter.keys, dtype=np.int64).reshape(-1, 2)
    E = pg.edge_count
    graph = dataclasses.replace(
        pg, edge_keys=np.concatenate([pg.edge_keys, keys]),
        measured=np.concatenate([pg.measured, np.array(planter.measured).reshape(-1, *pg.measured.shape[1:])]),
        information=np.concatenate([pg.information,
                                    np.array(planter.information).reshape(-1, *pg.information.shape[1:])]),
        lines=None)
    return Corruption(graph, np.arange(E, E + len(keys), dtype=np.int64), kind, float(fraction), int(seed))


def _translation_box(pg: PoseGraph, lc: np.ndarray) -> np.ndarray:
    """(d,) the largest translation magnitude per axis among the loop closures (1 where all are 0)."""
    d = pg.info.mat - 1
    box = np.max(np.abs(pg.measured[lc][:, :d, d]), axis=0)
    return np.where(box > 0.0, box, 1.0)


def _random_rotation(rng, d: int) -> np.ndarray:
    """A rotation uniform on SO(d) (d = 2, 3): an angle uniform on the circle, or a unit
    quaternion uniform on the 3-sphere (a normalized Gaussian 4-vector)."""
    if d == 2:
        t = rng.uniform(-np.pi, np.pi)
        return np.array([[np.cos(t), -np.sin(t)], [np.sin(t), np.cos(t)]])
    q = rng.normal(size=4)
    return np.asarray(quaternion.to_rotation(q / np.linalg.norm(q)))


def _lie(group: str):
    from . import se2, se3

    return se2 if group == "Pose2" else se3


class _Planter:
    """Draws planted closures into ``keys``/``measured``/``information``, never on an existing pair."""

    def __init__(self, pg: PoseGraph, rng, closure_information: np.ndarray, box: np.ndarray):
        self.pg, self.rng, self.pool, self.box = pg, rng, closure_information, box
        self.P = pg.pose_count
        ends = pg.index(pg.edge_keys.reshape(-1)).reshape(-1, 2)
        self.taken = {(int(min(a, b)), int(max(a, b))) for a, b in ends.tolist()}
        self.keys: list = []
        self.measured: list = []
        self.information: list = []

    def _free(self, a: int, b: int) -> bool:
        if not (0 <= a < self.P and 0 <= b < self.P) or a == b:
            return False
        ka, kb = self.pg.keys[a], self.pg.keys[b]
        return bool(is_loop_closure(ka, kb)) and (min(a, b), max(a, b)) not in self.taken

    def _add(self, a: int, b: int, Z: np.ndarray, info: np.ndarray) -> None:
        self.taken.add((min(a, b), max(a, b)))
        self.keys.append((int(self.pg.keys[a]), int(self.pg.keys[b])))
        self.measured.append(Z)
        self.information.append(info)

    def random_pose(self) -> np.ndarray:
        m = self.pg.info.mat
        d = m - 1
        Z = np.eye(m)
        Z[:d, :d] = _random_rotation(self.rng, d)
        Z[:d, d] = self.rng.uniform(-self.box, self.box)
        return Z

    def _information(self) -> np.ndarray:
        return self.pool[self.rng.integers(len(self.pool))]

    def singles(self, count: int, span: int | None) -> None:
        """``count`` closures between random pairs (within ``span`` poses if given)."""
        for _ in range(count * _TRIES):
            if len(self.keys) == count:
                return
            a = int(self.rng.integers(self.P))
            b = (int(self.rng.integers(self.P)) if span is None
                 else a + int(self.rng.choice([-1, 1])) * int(self.rng.integers(2, span + 1)))
            if self._free(a, b):
                self._add(a, b, self.random_pose(), self._information())
        if len(self.keys) < count:
            raise InputError(f"could not place {count} false closures in {self.P} poses without repeating a pair")

    def near_offset(self, X: np.ndarray, j: int, s: int, info: np.ndarray) -> np.ndarray | None:
        """δ (n,) at the middle closure c = s//2 such that every member's offset
        −Ad(X_{j+k}⁻¹·X_{j+c})·δ has a whitened norm in :data:`NEAR_SIGMAS`; None if no
        direction tried allows it."""
        lie, inv = _lie(self.pg.group), np.linalg.inv
        c = s // 2
        L = np.linalg.cholesky(info)  # Ω = L·Lᵀ: ‖Lᵀe‖ is e's whitened norm
        Ads = [np.asarray(lie.Ad(inv(X[j + k]) @ X[j + c])) for k in range(s)]
        lo, hi = NEAR_SIGMAS
        rot = slice(0, 3) if self.pg.group == "Pose3" else slice(2, 3)
        for t in range(_NEAR_DIRECTIONS):
            delta = np.linalg.solve(L.T, self.rng.normal(size=info.shape[0]))
            if t >= _NEAR_DIRECTIONS // 2:
                delta[rot] = 0.0
            r = np.array([np.linalg.norm(L.T @ (A @ delta)) for A in Ads])
            if not r.min() > 0.0 or lo / r.min() > hi / r.max():
                continue
            return delta * self.rng.uniform(lo / r.min(), hi / r.max())
        return None

    def runs(self, count: int, X: np.ndarray, near: bool) -> None:
        """``count`` closures in runs i+k → j+k agreeing on one relation (module docstring)."""
        inv = np.linalg.inv
        lie = _lie(self.pg.group)
        for _ in range(count * _TRIES):
            left = count - len(self.keys)
            if left == 0:
                return
            s = min(int(self.rng.integers(RUN_LENGTH[0], RUN_LENGTH[1] + 1)), left)
            i, j = (int(v) for v in self.rng.integers(0, self.P - s + 1, size=2))
            if abs(i - j) < s + 1 or not all(self._free(i + k, j + k) for k in range(s)):
                continue
            info = self._information()
            if near:
                delta = self.near_offset(X, j, s, info)
                if delta is None:
                    continue
                c = s // 2
                wrong = inv(X[i]) @ X[j + c] @ np.asarray(lie.exp(delta)) @ inv(X[j + c]) @ X[j]
            else:
                wrong = self.random_pose()
            for k in range(s):
                self._add(i + k, j + k, inv(X[i + k]) @ X[i] @ wrong @ inv(X[j]) @ X[j + k], info)
        if len(self.keys) < count:
            raise InputError(f"could not place {count} false closures in runs in {self.P} poses")


def planted_path(path: str) -> str:
    """Where ``lie-factors corrupt`` writes the planted list by default: OUT's name with its
    extension replaced by ``.planted.txt`` (``bad.g2o`` → ``bad.planted.txt``)."""
    import os

    return os.path.splitext(path)[0] + ".planted.txt"


def write_corruption(corruption: Corruption, path: str, planted: str | None = None) -> None:
    """Write the corrupted graph to ``path`` (g2o, at the input's start) and the planted closures to
    ``planted`` (default :func:`planted_path`), each atomically: after a ``#`` header, one line per
    planted closure, ``edge key1 key2`` — the edge's index among the file's edges (from 0, in the
    file's order) and the keys it joins."""
    import os

    from .files import write_g2o

    planted = planted_path(path) if planted is None else planted
    if os.path.abspath(planted) == os.path.abspath(path):
        raise InputError(f"{path}: the planted list and the graph must be different files")
    source = corruption.graph.path
    for out in (path, planted):
        if source and os.path.exists(out) and os.path.exists(source) and os.path.samefile(out, source):
            raise InputError(f"{out}: would overwrite the input graph")
    check_writable(path)
    check_writable(planted)
    pg = corruption.graph
    rows = np.column_stack([corruption.planted, corruption.planted_keys()])

    def write_list(tmp: str) -> None:
        header = (f"false loop closures planted: kind {corruption.kind}, fraction {corruption.fraction:g} "
                  f"of the loop closures, seed {corruption.seed}\nedge key1 key2")
        np.savetxt(tmp, rows, fmt="%d", header=header)

    write_g2o(pg, path)
    replace_atomically(planted, write_list)
