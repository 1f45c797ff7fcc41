"""Initial values for a pose graph: GTSAM's initializers on any graph of our factors.

Where Levenberg–Marquardt starts decides where it stops: on torus3D the
composed odometry of the file leads GTSAM's LM to a local minimum (error
29954 after 69 iterations) while GTSAM's chordal relaxation leads it to
12117.6 in 3.  Methods (:data:`METHODS`):

``chordal``
    ``gtsam.InitializePose3.initialize`` (Martinec–Pajdla chordal relaxation of
    the rotations, then one Gauss–Newton step on the full poses).  A 2-D graph
    is handed to the same initializer as a planar Pose3 graph (GTSAM has no
    chordal initializer for Pose2; see :func:`_planar_pose3_graph`).
``lago``
    ``gtsam.lago.initialize`` (Carlone et al., linear approximation of the
    Pose2 orientations).  2-D only; every noise model must be diagonal.
``spanning-tree``
    measurements composed along a breadth-first spanning tree from the anchor
    (:func:`spanning_tree_initial`).
``file``
    the values given (a g2o file's vertices, usually composed odometry).
``auto``
    3-D: chordal; 2-D: lago, then chordal; then file, then spanning-tree — the
    first that runs.  Given the known inliers (``inliers=``: odometry and the
    prior, for robust and GNC runs), from those factors alone: composed along
    them (the chordal/LAGO answer on a chain), then file, then spanning-tree.  Similarity3 graphs (Sim(3) g2o files): file, then
    spanning-tree (GTSAM's chordal and LAGO initializers are for Pose3/Pose2).
    Each method that cannot run is reported with a one-line reason in
    :attr:`Initialization.skipped`.  A graph with factors other than
    Between/Prior on Pose2/Pose3/Similarity3 (landmarks, ...) starts from the
    given values.

``chordal`` and ``lago`` run on arrays (:mod:`lie_factors.initialization.relaxation`: the same
results as GTSAM's to ~1e-10, numpy and CHOLMOD, no per-factor objects);
GTSAM's own initializers run, on a large-stack thread (:mod:`lie_factors.stack`),
where cvxopt is absent or a noise model's square-root information is not
upper triangular.

Anchor and priors, as GTSAM's initializers treat them (``InitializePose.h``):
every ``PriorFactor`` becomes a between factor from a fictitious pose at the
identity with key ``initialize::kAnchorKey`` = 99999999, which gets the only
prior.  A graph without any prior would leave the orientation system
singular, so :func:`initialize` then puts a prior at the identity on the
smallest key (as GTSAM's examples do), and every pose must be connected to
a prior.  A graph that uses the key 99999999 itself is renumbered for the
initializer and mapped back.
"""

from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass, field

import numpy as np

import gtsam

from .. import stack
from . import relaxation
from ..errors import PoseGraphError

#: ``--init`` choices, in the CLI's order.
METHODS = ("auto", "chordal", "lago", "spanning-tree", "file")

#: ``initialize::kAnchorKey`` in GTSAM's InitializePose.h (not exposed to Python).
ANCHOR_KEY = 99999999


class InitializationError(PoseGraphError):
    """An initializer cannot run on this graph; the message is the one-line reason."""


@dataclass
class Initialization:
    """Result of :func:`initialize`.

    ``values``: one Pose2/Pose3/Similarity3 per pose key; ``method``: the method that produced
    them; ``seconds``: its wall time (conversion included); ``skipped``: under
    ``auto``, ``(method, reason)`` for each method tried before it;
    ``inliers_only``: the method ran on the known inliers alone (``auto`` with
    ``inliers``, see :func:`initialize`).
    """

    values: gtsam.Values
    method: str
    seconds: float
    skipped: list[tuple[str, str]] = field(default_factory=list)
    inliers_only: bool = False


# --------------------------------------------------------------------------- #
# Our factors → GTSAM's own (what GTSAM's initializers recognise)
# --------------------------------------------------------------------------- #

@dataclass
class _PoseGraph:
    """The between and prior factors of a graph as GTSAM's own factor classes."""

    is3d: bool
    between: list  # gtsam.BetweenFactorPose2/3 (or Similarity3)
    priors: list  # gtsam.PriorFactorPose2/3 (or Similarity3)
    keys: list[int]  # sorted pose keys
    group: str = ""  # GTSAM type of the poses; Pose3/Pose2 by is3d if empty

    def __post_init__(self):
        if not self.group:
            self.group = "Pose3" if self.is3d else "Pose2"


def _measurement_kind(value) -> str | None:
    if isinstance(value, gtsam.Pose3):
        return "3"
    if isinstance(value, gtsam.Pose2):
        return "2"
    if isinstance(value, gtsam.Similarity3):
        return "Similarity3"
    return None


#: measurement kind → GTSAM type name
_GROUP_OF_KIND = {"3": "Pose3", "2": "Pose2", "Similarity3": "Similarity3"}


def _noise(model):
    # The initializers are least-squares relaxations: a robust loss has no place
    # in them, its Gaussian part does.
    if isinstance(model, gtsam.noiseModel.Robust):
        return model.noise()
    return model


def _convert(graph: gtsam.NonlinearFactorGraph) -> _PoseGraph:
    """Between/Prior factors on Pose2/Pose3/Similarity3 — GTSAM's or lie_factors' — as GTSAM's own classes.

    Same measured value, same noise model (a robust model's Gaussian part).
    Raises :class:`InitializationError` for any other factor or a mix of 2-D and 3-D.
    """
    between, priors, kinds, keys = [], [], set(), set()
    for k in range(graph.size()):
        f = graph.at(k)
        if f is None:  # a removed factor leaves a null slot
            continue
        fkeys = list(f.keys())
        if len(fkeys) == 2 and hasattr(f, "measured"):
            kind = _measurement_kind(f.measured())
            if kind is not None:
                cls = getattr(gtsam, f"BetweenFactor{_GROUP_OF_KIND[kind]}")
                between.append(cls(fkeys[0], fkeys[1], f.measured(), _noise(f.noiseModel())))
                kinds.add(kind)
                keys.update(fkeys)
                continue
        if len(fkeys) == 1 and hasattr(f, "prior"):
            kind = _measurement_kind(f.prior())
            if kind is not None:
                cls = getattr(gtsam, f"PriorFactor{_GROUP_OF_KIND[kind]}")
                priors.append(cls(fkeys[0], f.prior(), _noise(f.noiseModel())))
                kinds.add(kind)
                keys.update(fkeys)
                continue
        raise InitializationError(
            f"factor {k} ({type(f).__name__}) is not a Between or Prior factor on Pose2/Pose3/Similarity3; "
            "the initializers handle pose graphs only"
        )
    if not between:
        raise InitializationError("the graph has no between factors on Pose2/Pose3/Similarity3")
    if len(kinds) > 1:
        raise InitializationError("the graph mixes " + " and ".join(sorted(_GROUP_OF_KIND[k] for k in kinds))
                                  + " factors")
    group = _GROUP_OF_KIND[kinds.pop()]
    return _PoseGraph(group != "Pose2", between, priors, sorted(keys), group)


def _check_anchored(pg: _PoseGraph) -> None:
    """Every pose must reach a prior through between factors (else the relaxation is singular)."""
    adj: dict[int, list[int]] = {}
    for f in pg.between:
        i, j = f.keys()
        adj.setdefault(i, []).append(j)
        adj.setdefault(j, []).append(i)
    roots = [f.keys()[0] for f in pg.priors]
    seen = set(roots)
    queue = deque(roots)
    while queue:
        for nb in adj.get(queue.popleft(), ()):
            if nb not in seen:
                seen.add(nb)
                queue.append(nb)
    if len(seen) < len(pg.keys):
        lost = next(k for k in pg.keys if k not in seen)
        raise InitializationError(
            f"graph is not connected: pose {lost} has no path to a prior "
            f"({len(pg.keys) - len(seen)} of {len(pg.keys)} poses unreachable)"
        )


def _anchored(pg: _PoseGraph) -> _PoseGraph:
    """``pg`` with a prior at the identity on the smallest key if it has none."""
    if pg.priors:
        return pg
    # The variances of the prior GTSAM's Pose2/Pose3SLAMExample_g2o.py use (and lago's own).
    if pg.group == "Similarity3":
        noise = gtsam.noiseModel.Diagonal.Variances(np.array([1e-6, 1e-6, 1e-6, 1e-4, 1e-4, 1e-4, 1e-6]))
        prior = gtsam.PriorFactorSimilarity3(pg.keys[0], gtsam.Similarity3(), noise)
    elif pg.is3d:
        noise = gtsam.noiseModel.Diagonal.Variances(np.array([1e-6, 1e-6, 1e-6, 1e-4, 1e-4, 1e-4]))
        prior = gtsam.PriorFactorPose3(pg.keys[0], gtsam.Pose3(), noise)
    else:
        noise = gtsam.noiseModel.Diagonal.Variances(np.array([1e-6, 1e-6, 1e-8]))
        prior = gtsam.PriorFactorPose2(pg.keys[0], gtsam.Pose2(), noise)
    return _PoseGraph(pg.is3d, pg.between, [prior], pg.keys, pg.group)


def _native_graph(pg: _PoseGraph, rename: dict[int, int] | None = None) -> gtsam.NonlinearFactorGraph:
    """The factors as one NonlinearFactorGraph, keys renamed through ``rename`` if given."""
    graph = gtsam.NonlinearFactorGraph()
    if rename is None:
        for f in pg.between + pg.priors:
            graph.add(f)
        return graph
    B = gtsam.BetweenFactorPose3 if pg.is3d else gtsam.BetweenFactorPose2
    P = gtsam.PriorFactorPose3 if pg.is3d else gtsam.PriorFactorPose2
    for f in pg.between:
        i, j = f.keys()
        graph.add(B(rename[i], rename[j], f.measured(), f.noiseModel()))
    for f in pg.priors:
        graph.add(P(rename[f.keys()[0]], f.prior(), f.noiseModel()))
    return graph


def _run_gtsam(pg: _PoseGraph, call) -> gtsam.Values:
    """``call(native graph)``, keys renumbered around GTSAM's anchor key if one collides with it."""
    rename = None
    if ANCHOR_KEY in pg.keys:
        rename = {k: n for n, k in enumerate(pg.keys)}
    try:
        # GTSAM's elimination recurses once per level: a long chain needs more than 8 MiB of stack.
        values = stack.call(call, _native_graph(pg, rename))
    except (RuntimeError, ValueError, IndexError) as exc:  # e.g. IndeterminantLinearSystemException
        text = str(exc).strip().splitlines()
        raise InitializationError(f"GTSAM failed: {text[0] if text else type(exc).__name__}") from None
    if rename is None:
        return values
    back = gtsam.Values()
    for k, n in rename.items():
        back.insert(k, values.atPose3(n) if pg.is3d else values.atPose2(n))
    return back


# --------------------------------------------------------------------------- #
# The methods
# --------------------------------------------------------------------------- #

def _check_values(values: gtsam.Values, pg: _PoseGraph, what: str) -> gtsam.Values:
    at = getattr(values, f"at{pg.group}")
    for k in pg.keys:
        if not values.exists(k):
            raise InitializationError(f"{what} has no value for pose {k}")
        try:
            at(k)
        except RuntimeError:
            raise InitializationError(
                f"{what}: pose {k} is not a {pg.group}") from None
    return values


def _arrays(pg: _PoseGraph):
    """The graph as :mod:`lie_factors.initialization.relaxation`'s arrays (n, i, j, Z, information, prior index, Z, information),
    or None where GTSAM's own initializers must run: CHOLMOD (cvxopt) absent, or a noise model whose
    square-root information is not upper triangular (GTSAM weighs the chordal rows by its (0, 0) entry,
    which equals √information[0, 0] only for the upper-triangular factor) or is singular (constrained)."""
    if not relaxation.cholmod_available():
        return None
    index = {k: n for n, k in enumerate(pg.keys)}
    as_array = (lambda p: p.matrix()) if pg.is3d else (lambda p: (p.x(), p.y(), p.theta()))

    def collect(factors, nkeys):
        if not factors:
            d = 6 if pg.is3d else 3
            return np.zeros((0, nkeys), dtype=np.int64), np.zeros((0, 4, 4) if pg.is3d else (0, 3)), np.zeros((0, d, d))
        R = np.array([f.noiseModel().R() for f in factors])
        lower = np.tril(np.ones(R.shape[1:], dtype=bool), -1)
        if (np.any(R[:, lower]) or not np.all(np.isfinite(R))
                or np.any(np.diagonal(R, axis1=1, axis2=2) <= 0)):
            return None
        idx = np.array([[index[k] for k in f.keys()] for f in factors], dtype=np.int64)
        Z = np.array([as_array(f.measured() if nkeys == 2 else f.prior()) for f in factors])
        return idx, Z, np.swapaxes(R, 1, 2) @ R

    between, priors = collect(pg.between, 2), collect(pg.priors, 1)
    if between is None or priors is None:
        return None
    return (len(pg.keys), between[0][:, 0], between[0][:, 1], between[1], between[2],
            priors[0][:, 0], priors[1], priors[2])


def _run_arrays(func, arrays, **kwargs) -> np.ndarray:
    try:
        return func(*arrays, **kwargs)
    except (relaxation.RelaxationError, ValueError) as exc:
        raise InitializationError(str(exc)) from None


def _from_arrays(pg: _PoseGraph, poses: np.ndarray) -> gtsam.Values:
    values = gtsam.Values()
    if pg.is3d:
        for k, T in zip(pg.keys, poses):
            values.insert(k, gtsam.Pose3(T))
    else:
        for k, (x, y, th) in zip(pg.keys, poses.tolist()):
            values.insert(k, gtsam.Pose2(x, y, th))
    return values


def _chordal(pg: _PoseGraph) -> gtsam.Values:
    if pg.group == "Similarity3":
        raise InitializationError("GTSAM's chordal initializer is for Pose2/Pose3 graphs; this one is Similarity3")
    arrays = _arrays(pg)
    if arrays is not None:
        func = relaxation.initialize_pose3 if pg.is3d else relaxation.chordal_pose2
        return _from_arrays(pg, _run_arrays(func, arrays))
    if pg.is3d:
        return _check_values(_run_gtsam(pg, gtsam.InitializePose3.initialize), pg, "chordal initializer")
    planar = _planar_pose3_graph(pg)
    values3 = _run_gtsam(planar, gtsam.InitializePose3.initialize)
    values = gtsam.Values()
    for k in pg.keys:
        T = values3.atPose3(k)
        values.insert(k, gtsam.Pose2(T.x(), T.y(), T.rotation().yaw()))
    return values


def _pose2_info_to_pose3(model) -> np.ndarray:
    """6×6 information on Pose3's [ω, v] for a planar edge with Pose2 information on [x, y, θ].

    In-plane block as given ([x, y, θ] → [v_x, v_y, ω_z]); the out-of-plane
    components (ω_x, ω_y, v_z) decoupled, with θ's and x's information.
    InitializePose3 weights each rotation block by the ω_x entry of the
    whitened first column, so ω_x gets θ's information: the chordal weights
    are then the edge's rotation precision, as for a 3-D graph.
    """
    R = model.R()
    return relaxation.pose2_information_to_pose3(R.T @ R)


def _planar_pose3_graph(pg: _PoseGraph) -> _PoseGraph:
    """A Pose2 graph as the planar Pose3 graph GTSAM's chordal initializer takes.

    For planar measurements and a decoupled out-of-plane noise, the chordal
    relaxation keeps every rotation about z and the Gauss–Newton step keeps
    z = 0, so the Pose3 result read back as (x, y, yaw) is the chordal
    initialization of the Pose2 graph.
    """
    between = []
    for f in pg.between:
        i, j = f.keys()
        noise = gtsam.noiseModel.Gaussian.Information(_pose2_info_to_pose3(f.noiseModel()))
        between.append(gtsam.BetweenFactorPose3(i, j, gtsam.Pose3(f.measured()), noise))
    priors = []
    for f in pg.priors:
        noise = gtsam.noiseModel.Gaussian.Information(_pose2_info_to_pose3(f.noiseModel()))
        priors.append(gtsam.PriorFactorPose3(f.keys()[0], gtsam.Pose3(f.prior()), noise))
    return _PoseGraph(True, between, priors, pg.keys)


def _lago(pg: _PoseGraph) -> gtsam.Values:
    if pg.is3d:
        raise InitializationError(f"LAGO is for Pose2 graphs; this one is {pg.group}")
    for f in pg.between + pg.priors:
        if not isinstance(f.noiseModel(), gtsam.noiseModel.Diagonal):
            where = (f"edge {f.keys()[0]}-{f.keys()[1]}" if len(f.keys()) == 2
                     else f"the prior on {f.keys()[0]}")
            raise InitializationError(
                f"LAGO needs diagonal noise models; {where} has a full covariance")
    # The odometric path (edges between consecutive keys) is LAGO's own spanning
    # tree; where it does not reach every pose, its minimum spanning tree.
    path = _odometric_path_complete(pg)
    arrays = _arrays(pg)
    if arrays is not None:
        return _from_arrays(pg, _run_arrays(relaxation.lago_pose2, arrays, keys=np.asarray(pg.keys, dtype=np.int64),
                                            use_odometric_path=path))
    return _check_values(_run_gtsam(pg, lambda g: gtsam.lago.initialize(g, path)), pg, "LAGO")


def odometric_path_complete(keys: np.ndarray, edge_keys: np.ndarray) -> bool:
    """Whether the edges k–(k+1) link every pose to the smallest key, as lago's odometric tree needs.

    ``keys`` (P,) sorted pose keys, ``edge_keys`` (E, 2) the between factors' keys.
    """
    # uint64, GTSAM's Key: differences are taken in both directions (no sign to overflow).
    keys = np.asarray(keys, dtype=np.uint64)
    edge_keys = np.asarray(edge_keys, dtype=np.uint64).reshape(-1, 2)
    if len(keys) == 0 or int(keys[-1] - keys[0]) != len(keys) - 1 or ANCHOR_KEY in set(keys.tolist()):
        return False
    a, b = edge_keys[:, 0], edge_keys[:, 1]
    consecutive = (a - b == 1) | (b - a == 1)
    lows = np.unique(np.minimum(a[consecutive], b[consecutive]))
    return bool(np.isin(keys[:-1], lows).all())


def _odometric_path_complete(pg: _PoseGraph) -> bool:
    return odometric_path_complete(pg.keys, [f.keys() for f in pg.between])


def spanning_tree_initial(graph: gtsam.NonlinearFactorGraph, is3d: bool, root: int,
                          root_pose=None) -> gtsam.Values:
    """Initial poses from composing measurements along a BFS tree rooted at ``root``.

    ``graph``: between factors (anything with ``keys()`` and ``measured()``);
    the root gets ``root_pose`` (default: the identity).  BFS (rather than
    plain odometry order) reaches every pose of a connected graph even when ids
    are not a chain, and takes each pose through the fewest measurements, so
    drift stays smallest.  Edge i→j with measurement Z means x_j = x_i·Z,
    hence x_i = x_j·Z⁻¹.
    """
    if root_pose is None:
        root_pose = gtsam.Pose3() if is3d else gtsam.Pose2()
    adj: dict[int, list[tuple[int, object, bool]]] = {}
    for k in range(graph.size()):
        f = graph.at(k)
        if f is None or len(f.keys()) != 2:
            continue
        i, j = f.keys()
        Z = f.measured()
        adj.setdefault(i, []).append((j, Z, True))
        adj.setdefault(j, []).append((i, Z, False))
    poses = {root: root_pose}
    queue = deque([root])
    while queue:
        i = queue.popleft()
        for j, Z, forward in adj.get(i, ()):
            if j not in poses:
                poses[j] = poses[i].compose(Z if forward else Z.inverse())
                queue.append(j)
    values = gtsam.Values()
    for key in sorted(poses):
        values.insert(key, poses[key])
    return values


def _spanning_tree(pg: _PoseGraph) -> gtsam.Values:
    prior = pg.priors[0]
    root = prior.keys()[0]
    graph = gtsam.NonlinearFactorGraph()
    for f in pg.between:
        graph.add(f)
    values = spanning_tree_initial(graph, pg.is3d, root, prior.prior())
    if values.size() < len(pg.keys):
        lost = next(k for k in pg.keys if not values.exists(k))
        raise InitializationError(
            f"graph is not connected: pose {lost} cannot be reached from pose {root}")
    return values


# --------------------------------------------------------------------------- #
# Entry point
# --------------------------------------------------------------------------- #

def auto_order(is3d: bool, have_values: bool, group: str | None = None) -> list[str]:
    """The methods ``auto`` tries, in order."""
    order = [] if group == "Similarity3" else ["chordal"] if is3d else ["lago", "chordal"]
    return order + (["file"] if have_values else []) + ["spanning-tree"]


def initialize(graph: gtsam.NonlinearFactorGraph, method: str = "auto",
               initial: gtsam.Values | None = None, inliers=None) -> Initialization:
    """Initial values for a pose graph of Between/Prior factors on Pose2, Pose3 or Similarity3.

    ``graph``: GTSAM's own factors or lie_factors.factors' (converted to GTSAM's
    with the same measured value and noise model, since GTSAM's initializers
    only recognise their own classes); ``method``: one of :data:`METHODS`;
    ``initial``: the values ``file`` returns (e.g. a g2o file's vertices).
    Raises :class:`InitializationError` (one-line reason) if the method cannot
    run; under ``auto`` only if none can.

    ``inliers``: slots of the factors known to be right (the odometry edges
    and the prior of a graph whose loop closures may be false, as GNC's known
    inliers).  ``auto`` then starts from them alone (:func:`_auto_from_inliers`),
    because a relaxation over every edge is bent by the false ones; named
    methods still use every factor.
    """
    if method not in METHODS:
        raise InitializationError(f"unknown initialization {method!r} (choose from {', '.join(METHODS)})")
    t0 = time.perf_counter()
    try:
        pg = _convert(graph)
    except InitializationError as exc:
        # Not a pure pose graph (landmarks, ...): only the given values can start it.
        if method == "file" and initial is not None:
            return Initialization(initial, "file", time.perf_counter() - t0)
        if method != "auto" or initial is None:
            raise InitializationError(f"{method}: {exc}") from None
        return Initialization(initial, "file", time.perf_counter() - t0, [("chordal", str(exc))])
    skipped: list[tuple[str, str]] = []
    if method == "auto" and inliers is not None:
        values, name, skipped = _auto_from_inliers(graph, pg, inliers)
        if values is not None:
            return Initialization(values, name, time.perf_counter() - t0, skipped, inliers_only=True)
        # The known inliers do not reach every pose: the file, then a tree over every edge.
        order = (["file"] if initial is not None else []) + ["spanning-tree"]
    else:
        order = auto_order(pg.is3d, initial is not None, pg.group) if method == "auto" else [method]
    for name in order:
        try:
            values = _METHOD_FUNCS[name](pg, initial)
        except InitializationError as exc:
            if method != "auto":
                raise InitializationError(f"{name}: {exc}") from None
            skipped.append((name, str(exc)))
            continue
        return Initialization(values, name, time.perf_counter() - t0, skipped)
    reasons = "; ".join(f"{m}: {r}" for m, r in skipped)
    raise InitializationError(f"no initialization method applies ({reasons})")


def _auto_from_inliers(graph: gtsam.NonlinearFactorGraph, pg: _PoseGraph, inliers):
    """``auto`` on the factors at slots ``inliers`` of ``graph`` alone: (values, method, skipped).

    When they form a tree over every pose (an odometry chain and a prior: the
    usual case), the measurements composed along it (``spanning-tree``): the
    chordal relaxation and LAGO have zero residual on a tree and return exactly
    that, and GTSAM's chordal step fails as an indeterminate system on long
    planar chains (intel's 1727 odometry edges).  Otherwise (parallel odometry
    edges, ...) the usual relaxations, then a spanning tree, on the inliers.
    ``values`` is None, with the reasons in ``skipped``, if the inliers do not
    connect every pose to the prior.
    """
    keep = sorted({int(k) for k in inliers})
    sub = gtsam.NonlinearFactorGraph()
    for k in keep:
        if not 0 <= k < graph.size():
            raise InitializationError(f"known inlier {k} is not a factor slot (0..{graph.size() - 1})")
        if graph.at(k) is not None:
            sub.add(graph.at(k))
    where = "on the known inliers"
    try:
        known = _convert(sub)
    except InitializationError as exc:
        return None, "", [(f"auto {where}", str(exc))]
    known = _anchored(_PoseGraph(pg.is3d, known.between, known.priors, pg.keys, pg.group))
    try:
        _check_anchored(known)
    except InitializationError as exc:
        return None, "", [(f"auto {where}", str(exc))]
    tree = len(known.between) == len(known.keys) - 1
    order = ["spanning-tree"] if tree else auto_order(pg.is3d, False, pg.group)
    skipped = []
    for name in order:
        try:
            return _METHOD_FUNCS[name](known, None), name, skipped
        except InitializationError as exc:
            skipped.append((f"{name} {where}", str(exc)))
    return None, "", skipped


def _file(pg: _PoseGraph, initial) -> gtsam.Values:
    if initial is None:
        raise InitializationError("no initial values given (the file has no vertices)")
    return _check_values(initial, pg, "the initial values")


def _graph_method(func):
    def run(pg: _PoseGraph, _initial):
        anchored = _anchored(pg)
        _check_anchored(anchored)
        return func(anchored)
    return run


_METHOD_FUNCS = {
    "chordal": _graph_method(_chordal),
    "lago": _graph_method(_lago),
    "spanning-tree": _graph_method(_spanning_tree),
    "file": _file,
}
