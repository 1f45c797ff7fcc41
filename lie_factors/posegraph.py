"""Pose-graph optimization of g2o files with GTSAM, native or lie_factors factors.

Pipeline (each step a function, the CLI and the benchmark just chain them):

1. :func:`resolve_dataset` — a path, or the name of a file shipped with GTSAM
   (``sphere2500.txt``) found with ``gtsam.findExampleDataFile``.
2. :func:`check_g2o` — our own line-by-line check, so a bad file gives
   ``file:line: what was expected`` instead of GTSAM silently skipping lines
   (``readG2o`` drops every edge after a ``#`` comment, for instance).
3. :func:`load` — ``gtsam.readG2o(path, is3D)``; poses without a vertex line
   are initialized by composing measurements along a BFS spanning tree.
4. :func:`build_graph` — the between factors re-created with the chosen
   backend's constructors, plus a prior on the first pose.
5. :func:`optimize` — Levenberg–Marquardt driven one ``iterate()`` at a time
   from Python, with GTSAM's own stopping rule, reporting each iteration.

Supported records (g2o, and the TORO-style ``EDGE3``/``VERTEX3`` GTSAM ships):

=================  ====  ====================================================
tag                dim   fields after the tag
=================  ====  ====================================================
VERTEX_SE2         2     id x y θ
EDGE_SE2           2     id1 id2 x y θ + 6 upper-triangular information
VERTEX_SE3:QUAT    3     id x y z qx qy qz qw
EDGE_SE3:QUAT      3     id1 id2 x y z qx qy qz qw + 21 information
VERTEX3            3     id x y z roll pitch yaw
EDGE3              3     id1 id2 x y z roll pitch yaw + 21 information
=================  ====  ====================================================

Information ordering: g2o writes SE(3) information as [t, R]; GTSAM's Pose3
tangent is [ω, v], and ``readG2o`` permutes the blocks of ``EDGE_SE3:QUAT``
information accordingly (checked: a file diag(100·I₃, 25·I₃) yields the noise
model diag(25·I₃, 100·I₃)).  ``EDGE3`` information is taken by ``readG2o`` as
is (no permutation).  SE(2) information is [x, y, θ] in both.  We never touch
the noise models: both backends get exactly the ones ``readG2o`` built.
"""

from __future__ import annotations

import dataclasses
import math
import os
import tempfile
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

import gtsam


class PoseGraphError(Exception):
    """A user-facing problem (bad file, unknown backend, ...): one clear line."""


# --------------------------------------------------------------------------- #
# Dataset resolution and checking
# --------------------------------------------------------------------------- #

def resolve_dataset(name: str) -> str:
    """Return a readable file path for ``name``: an existing path, else a GTSAM example.

    Raises :class:`PoseGraphError` if it is neither.
    """
    if os.path.isdir(name):
        raise PoseGraphError(f"{name}: is a directory, expected a g2o file")
    if os.path.isfile(name):
        return name
    # Only bare names are looked up among GTSAM's examples: a path with a
    # directory that does not exist is a typo, not a dataset name.
    if os.path.dirname(name) == "":
        try:
            return gtsam.findExampleDataFile(name)
        except (RuntimeError, OSError):  # the Python wrapper raises FileNotFoundError
            pass
        raise PoseGraphError(
            f"{name}: no such file, and not a dataset shipped with GTSAM "
            f"(gtsam.findExampleDataFile)"
        )
    raise PoseGraphError(f"{name}: no such file")


@dataclass(frozen=True)
class _Record:
    kind: str  # "vertex" or "edge"
    dim: int  # 2 or 3
    ids: int
    pose: int
    info: int
    pose_desc: str

    @property
    def nfields(self) -> int:
        return self.ids + self.pose + self.info


_RECORDS = {
    "VERTEX_SE2": _Record("vertex", 2, 1, 3, 0, "x y θ"),
    "EDGE_SE2": _Record("edge", 2, 2, 3, 6, "x y θ"),
    "VERTEX_SE3:QUAT": _Record("vertex", 3, 1, 7, 0, "x y z qx qy qz qw"),
    "EDGE_SE3:QUAT": _Record("edge", 3, 2, 7, 21, "x y z qx qy qz qw"),
    "VERTEX3": _Record("vertex", 3, 1, 6, 0, "x y z roll pitch yaw"),
    "EDGE3": _Record("edge", 3, 2, 6, 21, "x y z roll pitch yaw"),
}

#: Largest accepted | ‖q‖ − 1 | for a g2o quaternion.  Files print 6–7 digits
#: (the shared datasets deviate by ≤ 2e-6); GTSAM does not renormalize, so a
#: clearly non-unit quaternion would become a non-orthogonal "rotation".
QUAT_NORM_TOL = 1e-3


def _plural(n: int, word: str) -> str:
    return f"{n} {word}" if n == 1 else f"{n} {word}s"


def _expects(tag: str, rec: _Record) -> str:
    parts = [_plural(rec.ids, "id"), _plural(rec.pose, "pose value")]
    if rec.info:
        parts.append(_plural(rec.info, "information value"))
    text = ", ".join(parts[:-1]) + " and " + parts[-1]
    return f"{tag} expects {text} ({rec.nfields} fields)"


def _upper_to_symmetric(values: np.ndarray, n: int) -> np.ndarray:
    """Row-major upper triangle, shape (n(n+1)/2,) → symmetric (n, n)."""
    M = np.zeros((n, n))
    M[np.triu_indices(n)] = values
    return M + np.triu(M, 1).T


@dataclass
class G2oSummary:
    """What :func:`check_g2o` learned about a file.

    ``vertices``: id → line number; ``edges``: list of (id1, id2, line number);
    ``is3d``: SE(3) file; ``has_comments``: lines GTSAM's reader mishandles.
    """

    path: str
    is3d: bool
    vertices: dict[int, int]
    edges: list[tuple[int, int, int]]
    has_comments: bool = False

    @property
    def pose_ids(self) -> list[int]:
        ids = set(self.vertices)
        for i, j, _ in self.edges:
            ids.add(i)
            ids.add(j)
        return sorted(ids)


def check_g2o(path: str) -> G2oSummary:
    """Validate a g2o file line by line; raise :class:`PoseGraphError` on the first problem.

    Checks: known tag, field count, integer ids, numeric and finite values,
    one dimension (2-D or 3-D) per file, unit quaternions, positive-definite
    information, no duplicate vertex, no self-loop, edges only between known
    vertices (when the file has vertices), at least one edge, and a connected
    graph (a second component would have no prior: its gauge is free and the
    linear system singular).
    """
    name = os.path.basename(path)
    try:
        with open(path, "r", encoding="utf-8", errors="replace") as fh:
            lines = fh.read().splitlines()
    except OSError as exc:
        raise PoseGraphError(f"{path}: cannot read ({exc.strerror})") from None

    dim = None
    dim_line = 0
    vertices: dict[int, int] = {}
    edges: list[tuple[int, int, int]] = []
    has_comments = False
    for lineno, line in enumerate(lines, start=1):
        tokens = line.split()
        if not tokens:
            continue
        if tokens[0].startswith("#"):
            has_comments = True
            continue
        tag, fields = tokens[0], tokens[1:]
        where = f"{name}:{lineno}"
        rec = _RECORDS.get(tag)
        if rec is None:
            known = ", ".join(_RECORDS)
            raise PoseGraphError(f"{where}: unknown tag {tag!r} (expected one of {known})")
        if dim is None:
            dim, dim_line = rec.dim, lineno
        elif rec.dim != dim:
            raise PoseGraphError(
                f"{where}: {tag} is a {rec.dim}-D record but line {dim_line} made this a "
                f"{dim}-D file"
            )
        if len(fields) != rec.nfields:
            raise PoseGraphError(f"{where}: {_expects(tag, rec)}, got {len(fields)} fields")
        ids = []
        for k in range(rec.ids):
            try:
                ids.append(int(fields[k]))
            except ValueError:
                raise PoseGraphError(
                    f"{where}: field {k + 2} ({fields[k]!r}) should be an integer id"
                ) from None
            if ids[-1] < 0:
                raise PoseGraphError(f"{where}: field {k + 2}: negative id {ids[-1]}")
        values = np.empty(rec.pose + rec.info)
        for k, tok in enumerate(fields[rec.ids:]):
            try:
                values[k] = float(tok)
            except ValueError:
                raise PoseGraphError(
                    f"{where}: field {rec.ids + k + 2} ({tok!r}) is not a number"
                ) from None
            if not math.isfinite(values[k]):
                raise PoseGraphError(f"{where}: field {rec.ids + k + 2} ({tok!r}) is not finite")
        pose = values[: rec.pose]
        if tag.endswith(":QUAT"):
            qnorm = float(np.linalg.norm(pose[3:7]))
            if abs(qnorm - 1.0) > QUAT_NORM_TOL:
                raise PoseGraphError(
                    f"{where}: quaternion qx qy qz qw has norm {qnorm:.6g}, expected 1"
                )
        if rec.kind == "vertex":
            (vid,) = ids
            if vid in vertices:
                raise PoseGraphError(
                    f"{where}: vertex {vid} already defined on line {vertices[vid]}"
                )
            vertices[vid] = lineno
            continue
        i, j = ids
        if i == j:
            raise PoseGraphError(f"{where}: edge connects vertex {i} to itself")
        n = 3 if dim == 2 else 6
        info = _upper_to_symmetric(values[rec.pose:], n)
        eig_min = float(np.linalg.eigvalsh(info)[0])
        # Relative threshold: a PSD-but-singular matrix printed with rounding
        # can show −1e-17; that is still not usable as a noise model.
        if not eig_min > 1e-12 * max(1.0, float(np.max(np.abs(info)))):
            raise PoseGraphError(
                f"{where}: information matrix is not positive definite "
                f"(smallest eigenvalue {eig_min:.3g})"
            )
        edges.append((i, j, lineno))

    if dim is None:
        raise PoseGraphError(f"{name}: empty graph (no vertices and no edges)")
    if not edges:
        raise PoseGraphError(f"{name}: empty graph (no edges, nothing to optimize)")
    if vertices:
        for i, j, lineno in edges:
            for v in (i, j):
                if v not in vertices:
                    raise PoseGraphError(f"{name}:{lineno}: edge {i}-{j} refers to unknown vertex {v}")
    summary = G2oSummary(path, dim == 3, vertices, edges, has_comments)
    _check_connected(summary, name)
    return summary


def _adjacency(pairs) -> dict[int, list[int]]:
    adj: dict[int, list[int]] = {}
    for i, j in pairs:
        adj.setdefault(i, []).append(j)
        adj.setdefault(j, []).append(i)
    return adj


def _check_connected(summary: G2oSummary, name: str) -> None:
    ids = summary.pose_ids
    adj = _adjacency((i, j) for i, j, _ in summary.edges)
    seen = {ids[0]}
    queue = deque([ids[0]])
    while queue:
        for nb in adj.get(queue.popleft(), ()):
            if nb not in seen:
                seen.add(nb)
                queue.append(nb)
    if len(seen) != len(ids):
        lost = next(v for v in ids if v not in seen)
        raise PoseGraphError(
            f"{name}: graph is not connected: pose {lost} cannot be reached from pose {ids[0]} "
            f"({len(ids) - len(seen)} of {len(ids)} poses unreachable; only pose {ids[0]} gets a prior)"
        )


# --------------------------------------------------------------------------- #
# Loading
# --------------------------------------------------------------------------- #

@dataclass
class PoseGraph:
    """A checked g2o file read by GTSAM.

    ``between``: native GTSAM graph of BetweenFactorPose2/3 exactly as
    ``readG2o`` built it (no prior) — also what :func:`write_g2o` writes;
    ``initial``: Values with every pose; ``first_key``: smallest id, gets the prior.
    """

    path: str
    name: str
    is3d: bool
    between: gtsam.NonlinearFactorGraph
    initial: gtsam.Values
    first_key: int
    initialized_from_edges: bool

    @property
    def poses(self) -> int:
        return int(self.initial.size())

    @property
    def edges(self) -> int:
        return int(self.between.size())


def _read_g2o(path: str, summary: G2oSummary):
    if not summary.has_comments:
        return gtsam.readG2o(path, summary.is3d)
    # GTSAM's reader stops reading edges after a comment line; give it a copy without them.
    fd, tmp = tempfile.mkstemp(suffix=".g2o")
    try:
        with os.fdopen(fd, "w") as out, open(path, encoding="utf-8", errors="replace") as src:
            for line in src:
                if not line.lstrip().startswith("#"):
                    out.write(line)
        return gtsam.readG2o(tmp, summary.is3d)
    finally:
        os.unlink(tmp)


def load(dataset: str) -> PoseGraph:
    """Resolve, check and read ``dataset``; raise :class:`PoseGraphError` if unusable."""
    path = resolve_dataset(dataset)
    summary = check_g2o(path)
    graph, initial = _read_g2o(path, summary)
    if graph.size() != len(summary.edges):
        # Our checker and GTSAM's reader disagree: refuse rather than optimize half a file.
        raise PoseGraphError(
            f"{os.path.basename(path)}: gtsam.readG2o read {graph.size()} edges, "
            f"the file has {len(summary.edges)}"
        )
    from_edges = not summary.vertices
    if from_edges:
        # readG2o leaves 3-D edge-only files (sphere2500.txt) without Values; for
        # 2-D it chains odometry itself.  Do the same thing for both: a spanning tree.
        initial = spanning_tree_initial(graph, summary.is3d, summary.pose_ids[0])
    return PoseGraph(
        path=path,
        name=os.path.basename(path),
        is3d=summary.is3d,
        between=graph,
        initial=initial,
        first_key=summary.pose_ids[0],
        initialized_from_edges=from_edges,
    )


def spanning_tree_initial(graph: gtsam.NonlinearFactorGraph, is3d: bool, root: int) -> gtsam.Values:
    """Initial poses from composing measurements along a BFS tree rooted at ``root``.

    The root is the identity.  BFS (rather than plain odometry order) reaches
    every pose of a connected graph even when ids are not a chain, and takes
    each pose through the fewest measurements, so drift stays smallest.
    Edge i→j with measurement Z means x_j = x_i·Z, hence x_i = x_j·Z⁻¹.
    """
    identity = gtsam.Pose3() if is3d else gtsam.Pose2()
    adj: dict[int, list[tuple[int, object, bool]]] = {}
    for k in range(graph.size()):
        f = graph.at(k)
        i, j = f.keys()
        Z = f.measured()
        adj.setdefault(i, []).append((j, Z, True))
        adj.setdefault(j, []).append((i, Z, False))
    poses = {root: identity}
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


# --------------------------------------------------------------------------- #
# Backends: name → where the factor constructors come from
# --------------------------------------------------------------------------- #

def _native_factors():
    return gtsam


def _custom_factors():
    # Imported here, not at module top, so that `native` works without it.
    from lie_factors import factors

    return factors


@dataclass(frozen=True)
class Backend:
    """``factors()`` returns an object with GTSAM-named constructors
    (BetweenFactorPose2/3, PriorFactorPose2/3); ``optimize`` runs LM on the graph."""

    factors: Callable[[], object]
    optimize: Callable[..., "OptimizeResult"] = None  # type: ignore[assignment]
    description: str = ""


#: Add a backend here (e.g. "batch") — the CLI's --backend choices come from this table.
BACKENDS: dict[str, Backend] = {}


def get_backend(name: str) -> Backend:
    try:
        return BACKENDS[name]
    except KeyError:
        raise PoseGraphError(
            f"unknown backend {name!r} (choose from {', '.join(BACKENDS)})"
        ) from None


def load_factors(backend: str):
    """The factor-constructor namespace for ``backend``; clear error if unavailable."""
    b = get_backend(backend)
    try:
        return b.factors()
    except ImportError as exc:
        raise PoseGraphError(f"backend {backend!r} is not available: {exc}") from None


def prior_noise(is3d: bool) -> gtsam.noiseModel.Base:
    """The prior GTSAM's Pose2/Pose3SLAMExample_g2o.py put on the first pose."""
    if is3d:
        return gtsam.noiseModel.Diagonal.Variances(np.array([1e-6, 1e-6, 1e-6, 1e-4, 1e-4, 1e-4]))
    return gtsam.noiseModel.Diagonal.Variances(np.array([1e-6, 1e-6, 1e-8]))


def build_graph(pg: PoseGraph, backend: str) -> gtsam.NonlinearFactorGraph:
    """Graph of ``pg.edges`` between factors + 1 prior, built with ``backend``'s constructors.

    The prior pins the first pose at its initial value (identity for edge-only
    files), fixing the gauge.
    """
    F = load_factors(backend)
    Between = F.BetweenFactorPose3 if pg.is3d else F.BetweenFactorPose2
    Prior = F.PriorFactorPose3 if pg.is3d else F.PriorFactorPose2
    graph = gtsam.NonlinearFactorGraph()
    for k in range(pg.between.size()):
        f = pg.between.at(k)
        i, j = f.keys()
        graph.add(Between(i, j, f.measured(), f.noiseModel()))
    first = pg.initial.atPose3(pg.first_key) if pg.is3d else pg.initial.atPose2(pg.first_key)
    graph.add(Prior(pg.first_key, first, prior_noise(pg.is3d)))
    return graph


# --------------------------------------------------------------------------- #
# Optimization, one iteration at a time
# --------------------------------------------------------------------------- #

@dataclass
class IterationInfo:
    """One LM iteration: number (1-based), error after it, λ after it, wall seconds."""

    iteration: int
    error: float
    lambda_: float
    seconds: float


@dataclass
class OptimizeResult:
    values: gtsam.Values
    iterations: int
    initial_error: float
    final_error: float
    seconds: float
    converged: bool
    history: list[IterationInfo] = field(default_factory=list)


def optimize(
    graph: gtsam.NonlinearFactorGraph,
    initial: gtsam.Values,
    max_iterations: int = 100,
    progress: Callable[[IterationInfo], None] | None = None,
    params: gtsam.LevenbergMarquardtParams | None = None,
) -> OptimizeResult:
    """Levenberg–Marquardt, stepped from Python exactly like ``optimizer.optimize()``.

    GTSAM's ``NonlinearOptimizer::defaultOptimize``: stop at once if the error
    is already ≤ errorTol; otherwise ``iterate()`` while iterations <
    maxIterations, ``checkConvergence(relTol, absTol, errorTol, current, new)``
    is false and the error is finite.  (``max_iterations=0`` runs none; GTSAM
    would still run one.)  ``seconds`` covers building the optimizer (it
    evaluates the initial error) and the iterations.
    """
    if params is None:
        params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(max_iterations)
    t_start = time.perf_counter()
    try:
        opt = gtsam.LevenbergMarquardtOptimizer(graph, initial, params)
        initial_error = new_error = float(opt.error())
        converged = new_error <= params.getErrorTol()
        history = []
        while not converged and opt.iterations() < max_iterations:
            current_error = new_error
            t0 = time.perf_counter()
            opt.iterate()
            new_error = float(opt.error())
            info = IterationInfo(int(opt.iterations()), new_error, float(opt.lambda_()),
                                 time.perf_counter() - t0)
            history.append(info)
            if progress is not None:
                progress(info)
            converged = gtsam.checkConvergence(params, current_error, new_error)
            if not math.isfinite(current_error):
                break
        values = opt.values()
    except RuntimeError as exc:
        # e.g. IndeterminantLinearSystemException: report it, don't dump a traceback.
        raise PoseGraphError(f"optimization failed: {str(exc).strip().splitlines()[0]}") from None
    seconds = time.perf_counter() - t_start
    return OptimizeResult(values, int(opt.iterations()), initial_error, new_error, seconds,
                          bool(converged), history)


def _optimize_batch(graph, initial, max_iterations=100, progress=None, params=None) -> OptimizeResult:
    # Imported on use: lie_factors.batch compiles its loops, which native/custom never need.
    from lie_factors.batch import run_batch

    return run_batch(graph, initial, max_iterations, progress, params)


BACKENDS.update(
    native=Backend(_native_factors, optimize, "GTSAM's own BetweenFactor/PriorFactor (reference)"),
    custom=Backend(_custom_factors, optimize, "lie_factors.factors (closed-form Jacobians)"),
    batch=Backend(_custom_factors, _optimize_batch, "lie_factors factors, vectorized LM driven from Python"),
)


def format_iteration(info: IterationInfo) -> str:
    """One progress line, in the spirit of GTSAM's SUMMARY verbosity."""
    return (f"iter {info.iteration:4d}  error {info.error:.6e}  lambda {info.lambda_:.2e}  "
            f"time {info.seconds:.3f} s")


# --------------------------------------------------------------------------- #
# Results and output files
# --------------------------------------------------------------------------- #

@dataclass
class RunRecord:
    """What ``lie-factors posegraph --json`` prints (``to_dict``).

    ``factors`` counts the optimized graph: the file's edges + 1 prior;
    ``seconds`` is optimization only (LM construction + iterations, not loading);
    ``initial_error``/``final_error`` are GTSAM's 0.5·Σ‖whitened residual‖².
    """

    backend: str
    dataset: str
    dimension: int
    poses: int
    factors: int
    iterations: int
    initial_error: float
    final_error: float
    seconds: float
    converged: bool

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


def run(
    dataset: str | PoseGraph,
    backend: str = "native",
    max_iterations: int = 100,
    progress: Callable[[IterationInfo], None] | None = None,
) -> tuple[RunRecord, OptimizeResult, PoseGraph]:
    """Load (unless given a :class:`PoseGraph`), build with ``backend``, optimize."""
    pg = load(dataset) if isinstance(dataset, str) else dataset
    graph = build_graph(pg, backend)
    opt = get_backend(backend).optimize or optimize
    result = opt(graph, pg.initial, max_iterations=max_iterations, progress=progress)
    record = RunRecord(
        backend=backend,
        dataset=pg.name,
        dimension=3 if pg.is3d else 2,
        poses=pg.poses,
        factors=int(graph.size()),
        iterations=result.iterations,
        initial_error=result.initial_error,
        final_error=result.final_error,
        seconds=result.seconds,
        converged=result.converged,
    )
    return record, result, pg


def check_writable(path: str) -> None:
    """Raise :class:`PoseGraphError` unless a file can be created next to ``path``.

    Called before optimizing, so a long run is not wasted on a typo.  We create
    (and remove) a probe file instead of trusting ``os.access``, which says yes
    to root on read-only mounts.
    """
    if os.path.isdir(path):
        raise PoseGraphError(f"{path}: is a directory, expected a file name")
    directory = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(directory):
        raise PoseGraphError(f"{path}: directory {directory} does not exist")
    try:
        fd, probe = tempfile.mkstemp(dir=directory, prefix=".lie-factors-probe-")
    except OSError as exc:
        raise PoseGraphError(f"{path}: cannot write to {directory} ({exc.strerror})") from None
    os.close(fd)
    os.unlink(probe)


def replace_atomically(path: str, write: Callable[[str], None], suffix: str = "") -> None:
    """Call ``write(tmp)`` on a temporary file next to ``path``, then ``os.replace`` it.

    An existing ``path`` is untouched if ``write`` fails.
    """
    directory = os.path.dirname(os.path.abspath(path))
    try:
        fd, tmp = tempfile.mkstemp(dir=directory, prefix=".lie-factors-", suffix=suffix)
    except OSError as exc:
        raise PoseGraphError(f"{path}: cannot write to {directory} ({exc.strerror})") from None
    os.close(fd)
    try:
        write(tmp)
        if not os.path.exists(tmp) or os.path.getsize(tmp) == 0:
            raise PoseGraphError(f"{path}: writing produced an empty file")
        # mkstemp creates 0600; give the result the mode a plain open() would
        # (or keep the mode of the file being replaced).
        if os.path.exists(path):
            mode = os.stat(path).st_mode & 0o777
        else:
            umask = os.umask(0)
            os.umask(umask)
            mode = 0o666 & ~umask
        os.chmod(tmp, mode)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def write_g2o(path: str, between: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> None:
    """``gtsam.writeG2o`` via a temporary file.

    ``between`` must be the native graph: writeG2o only recognises GTSAM's own
    BetweenFactor classes, so custom factors would silently lose the edges.
    """
    replace_atomically(path, lambda tmp: gtsam.writeG2o(between, values, tmp), suffix=".g2o")


def positions(values: gtsam.Values, is3d: bool) -> np.ndarray:
    """Translations of the poses in ``values`` in key order, shape (N, 3) (z = 0 in 2-D)."""
    keys = sorted(values.keys())
    if is3d:
        return np.array([values.atPose3(k).translation() for k in keys]).reshape(-1, 3)
    out = np.zeros((len(keys), 3))
    for n, k in enumerate(keys):
        p = values.atPose2(k)
        out[n, :2] = (p.x(), p.y())
    return out
