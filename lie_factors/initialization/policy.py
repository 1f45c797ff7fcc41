"""Which initialization runs, and the one loop that tries them: :func:`initialize`.

The methods, the ``auto`` order and the two implementations are described in
:mod:`lie_factors.initialization`.
"""

from __future__ import annotations

import time

import numpy as np

from ..sparse import cholmod
from ..errors import InitializationError, InputError
from ..interop import matrices_from_values, values_from_matrices
from ..posegraph.graph import PoseGraph
from . import anchor, lago, spanning_tree, with_gtsam

#: ``--init`` choices, in the CLI's order.
METHODS = ("auto", "chordal", "lago", "spanning-tree", "odometry", "file")

#: Implementations of ``chordal`` and ``lago``: ours on arrays, or GTSAM's own (no numba).
ENGINES = ("lie_factors", "gtsam")

#: The step of the ``auto`` order that starts from the known inliers alone.
KNOWN_INLIERS = "known inliers"


class Initialization:
    """Result of :func:`initialize`.

    ``method``: the method that produced the start; ``seconds``: its wall time
    (conversions included); ``skipped``: under ``auto``, ``(method, reason)``
    for each method tried before it; ``inliers_only``: it ran on the known
    inliers alone; ``engine``: whose chordal or LAGO initializer ran
    (:data:`ENGINES`; None for the others).  ``poses`` (P, m, m): the start in the order of ``keys``
    (of ``group``); ``values``: the same as ``gtsam.Values``, built on first
    use (or the values given, for ``file``; for a graph that is not a pose
    graph ``poses`` is None and ``values`` the given ones).
    """

    def __init__(self, method: str, seconds: float = 0.0, skipped=None, inliers_only: bool = False,
                 poses: np.ndarray | None = None, keys: np.ndarray | None = None, group: str | None = None,
                 values=None, engine: str | None = None):
        self.method, self.seconds, self.inliers_only, self.engine = method, seconds, inliers_only, engine
        self.skipped: list[tuple[str, str]] = [] if skipped is None else skipped
        self.poses, self.keys, self.group = poses, keys, group
        self._values = values

    @property
    def values(self):
        """The start as ``gtsam.Values`` (built from :attr:`poses` on first use)."""
        if self._values is None and self.poses is not None:
            self._values = values_from_matrices(self.group, self.keys, self.poses)
        return self._values

    def __repr__(self) -> str:
        return (f"Initialization(method={self.method!r}, seconds={self.seconds:.3g}, skipped={self.skipped!r}, "
                f"inliers_only={self.inliers_only}, engine={self.engine!r}, "
                f"poses={len(self.keys) if self.keys is not None else None})")


def auto_order(group: str, have_file: bool, known_inliers: bool = False) -> list[str]:
    """The methods ``auto`` tries, in order.

    Given the known inliers, first their own start (:data:`KNOWN_INLIERS`);
    else Pose3: chordal; Pose2: lago, then chordal; Similarity3: none of them
    (GTSAM's chordal and LAGO initializers are for Pose3/Pose2).  Then file,
    then spanning-tree.
    """
    head = ([KNOWN_INLIERS] if known_inliers else [] if group == "Similarity3"
            else ["chordal"] if group == "Pose3" else ["lago", "chordal"])
    return head + (["file"] if have_file else []) + ["spanning-tree"]


def initialize(graph, method: str = "auto", initial=None, inliers=None,
               engine: str = "lie_factors") -> Initialization:
    """Initial poses for a pose graph: the first method of the order that runs.

    ``graph``: a :class:`~lie_factors.posegraph.graph.PoseGraph`, or a
    ``gtsam.NonlinearFactorGraph`` of Between/Prior factors on Pose2, Pose3 or
    Similarity3 (GTSAM's own or lie_factors.factors', :meth:`PoseGraph.from_gtsam`);
    ``method``: one of :data:`METHODS`; ``initial``: the poses ``file`` returns,
    ``gtsam.Values`` or (P, m, m) in key order (default: the PoseGraph's
    vertices); ``engine``: ``chordal`` and ``lago`` by ours (``"lie_factors"``:
    numpy, the batch solver's kernels, CHOLMOD) or by GTSAM's own initializers
    (``"gtsam"``: no numba; also where cvxopt is missing).  Raises
    :class:`~lie_factors.errors.InitializationError` (one-line reason) if the
    method cannot run; under ``auto`` only if none can.

    ``inliers``: the edges known to be right (the odometry of a graph whose loop
    closures may be false, as GNC's known inliers), as factor indices of a GTSAM
    graph or edge indices of a PoseGraph; the priors are always kept.  ``auto``
    then starts from them alone, because a relaxation over every edge is bent
    by the false ones; named methods still use every edge.

    A GTSAM graph with other factors (landmarks, ...) can only start from
    ``initial``: ``file`` and ``auto`` return it as it is.
    """
    if method not in METHODS:
        raise InitializationError(f"unknown initialization {method!r} (choose from {', '.join(METHODS)})")
    if engine not in ENGINES:
        raise InputError(f"engine must be one of {', '.join(ENGINES)}, got {engine!r}")
    t0 = time.perf_counter()
    if isinstance(graph, PoseGraph):
        pg = graph
        edges = None if inliers is None else _edge_indices(inliers, len(pg.edge_keys))
    else:
        try:
            pg = PoseGraph.from_gtsam(graph)
        except InputError as exc:
            if method == "file" and initial is not None:
                return Initialization("file", time.perf_counter() - t0, values=initial)
            if method != "auto" or initial is None:
                raise InitializationError(f"{method}: {exc}") from None
            return Initialization("file", time.perf_counter() - t0, [("chordal", str(exc))], values=initial)
        edges = None if inliers is None else _slots_to_edges(inliers, graph.size(), pg.lines)
    if engine == "lie_factors" and not cholmod.available():
        engine = "gtsam"
    file = _File(pg, pg.vertices if initial is None else initial)
    order = auto_order(pg.group, file.given, edges is not None) if method == "auto" else [method]

    def run(name):
        if name == KNOWN_INLIERS:
            return _from_known_inliers(pg.with_edges(edges), engine)
        return _run(name, pg, engine, file)

    name, poses, skipped = _first(order, run, strict=method != "auto")
    if name is None:
        reasons = "; ".join(f"{m}: {r}" for m, r in skipped)
        raise InitializationError(f"no initialization method applies ({reasons})")
    inliers_only = name == KNOWN_INLIERS
    if inliers_only:
        name, poses, inner = poses
        skipped += inner
    return Initialization(name, time.perf_counter() - t0, skipped, inliers_only, poses, pg.keys, pg.group,
                          file.values if name == "file" else None, engine if name in ("chordal", "lago") else None)


class _NoneRan(InitializationError):
    """A nested order (the known inliers') in which no method ran; ``skipped``: its reasons."""

    def __init__(self, skipped: list[tuple[str, str]]):
        super().__init__("; ".join(f"{m}: {r}" for m, r in skipped))
        self.skipped = skipped


def _first(order: list[str], run, strict: bool, suffix: str = ""):
    """The one loop: (name, ``run(name)``, skipped) for the first name in ``order`` that runs.

    Each failure before it is in skipped as ``(name + suffix, reason)``; with
    ``strict`` the first failure raises instead, prefixed by its name.  Name
    and result are None if none runs.
    """
    skipped: list[tuple[str, str]] = []
    for name in order:
        try:
            return name, run(name), skipped
        except _NoneRan as exc:
            skipped += exc.skipped
        except InitializationError as exc:
            if strict:
                raise InitializationError(f"{name}: {exc}") from None
            skipped.append((name + suffix, str(exc)))
    return None, None, skipped


def _from_known_inliers(known: PoseGraph, engine: str):
    """``auto`` on the known inliers' graph: (method, poses, skipped), or :class:`_NoneRan`.

    When they form a tree over every pose (an odometry chain and a prior: the
    usual case), the measurements composed along it (``spanning-tree``): the
    chordal relaxation and LAGO have zero residual on a tree and return exactly
    that, and GTSAM's chordal step fails as an indeterminate system on long
    planar chains (intel's 1727 odometry edges).  Otherwise (parallel odometry
    edges, ...) the usual relaxations, then a spanning tree.
    """
    where = " on the known inliers"
    try:
        if not len(known.edge_keys):
            raise InitializationError("the graph has no between factors on Pose2/Pose3/Similarity3")
        anchor.prepared(known)
    except (InitializationError, ValueError) as exc:
        raise _NoneRan([("auto" + where, str(exc))]) from None
    tree = len(known.edge_keys) == len(known.keys) - 1
    order = ["spanning-tree"] if tree else auto_order(known.group, False)
    name, poses, skipped = _first(order, lambda m: _run(m, known, engine, None), False, where)
    if name is None:
        raise _NoneRan(skipped)
    return name, poses, skipped


def _run(name: str, pg: PoseGraph, engine: str, file) -> np.ndarray:
    """The poses (P, m, m) of method ``name``; :class:`InitializationError` if it cannot run."""
    try:
        if name == "file":
            poses = file.poses()
        elif name == "spanning-tree":
            poses = spanning_tree.initialize(pg)
        elif name == "odometry":
            # dead reckoning: the edges between consecutive keys composed from the prior
            poses = spanning_tree.initialize(pg.with_edges(np.setdiff1d(np.arange(len(pg.edge_keys)),
                                                                        pg.loop_closures())))
        elif engine == "gtsam":
            poses = (with_gtsam.chordal if name == "chordal" else with_gtsam.lago)(pg)
        elif name == "chordal":
            from . import chordal  # the group kernels (numba): loaded only by our chordal initializer

            poses = chordal.initialize(pg)
        else:
            poses = lago.initialize_pose2(pg, lago.odometric_path_complete(pg.keys, pg.edge_keys))
    except ValueError as exc:  # malformed arrays (PoseGraph.validate)
        raise InitializationError(str(exc)) from None
    if not np.isfinite(poses).all():
        raise InitializationError("the result is not finite")
    return poses


class _File:
    """The ``file`` method's poses: ``initial`` (Values or (P, m, m)) checked against ``pg``'s keys."""

    def __init__(self, pg: PoseGraph, initial):
        self.pg, self.initial = pg, initial
        self.given = initial is not None
        self.values = initial if initial is not None and not isinstance(initial, np.ndarray) else None

    def poses(self) -> np.ndarray:
        pg = self.pg
        if self.initial is None:
            raise InitializationError("no initial values given (the file has no vertices)")
        if isinstance(self.initial, np.ndarray):
            m = pg.info.mat
            if self.initial.shape != (len(pg.keys), m, m):
                raise InitializationError(f"the initial poses have shape {self.initial.shape}, "
                                          f"not ({len(pg.keys)}, {m}, {m})")
            return self.initial
        try:
            return matrices_from_values(self.initial, pg.group, pg.keys)
        except KeyError as exc:
            raise InitializationError(f"the initial values has no value for pose {exc.args[0]}") from None
        except TypeError as exc:
            raise InitializationError(f"the initial values: pose {exc.args[0]} is not a {pg.group}") from None


def _edge_indices(inliers, E: int) -> np.ndarray:
    idx = np.unique(np.asarray(list(inliers), dtype=np.int64))
    bad = idx[(idx < 0) | (idx >= E)]
    if bad.size:
        raise InitializationError(f"known inlier {int(bad[0])} is not an edge (0..{E - 1})")
    return idx


def _slots_to_edges(inliers, size: int, slots: np.ndarray) -> np.ndarray:
    """The edges (indices into the PoseGraph) at factor slots ``inliers`` of a graph of ``size`` factors."""
    keep = np.unique(np.asarray(list(inliers), dtype=np.int64))
    bad = keep[(keep < 0) | (keep >= size)]
    if bad.size:
        raise InitializationError(f"known inlier {int(bad[0])} is not a factor slot (0..{size - 1})")
    return np.flatnonzero(np.isin(slots, keep))
