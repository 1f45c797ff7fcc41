"""Our chordal and LAGO initializers on arrays against GTSAM's own (InitializePose3, lago) on the same graphs."""

from __future__ import annotations

import dataclasses
import os
import subprocess
import sys

import gtsam
import mpmath
import numpy as np
import pytest

from lie_factors import initialization as LI
from lie_factors.g2o import read_pose_graph
from lie_factors.sparse import cholmod
from lie_factors.errors import InitializationError
from lie_factors.initialization import chordal, lago
from lie_factors.initialization.planar import planar_pose3
from lie_factors.interop import matrices_from_values
from lie_factors.posegraph.graph import PRIOR_VARIANCES, PoseGraph

ROOT = os.path.join(os.path.dirname(__file__), "..", "..")
DATA = os.path.join(ROOT, "data")


def _path(name):
    if os.path.exists(os.path.join(ROOT, "data", name)):
        return os.path.join(ROOT, "data", name)
    return gtsam.findExampleDataFile(name)


def _graph(name) -> PoseGraph:
    """A file's pose graph (no prior: the initializers put GTSAM's default on the smallest key)."""
    return read_pose_graph(_path(name) if "/" not in name else name)


def _gtsam(pg: PoseGraph) -> gtsam.NonlinearFactorGraph:
    """GTSAM's graph of ``pg`` with its priors, or GTSAM's default one on the smallest key."""
    return pg.anchored().factor_graph()


def _xytheta(X):
    """Pose2 matrices (n, 3, 3) → rows [x, y, θ]."""
    return np.stack([X[:, 0, 2], X[:, 1, 2], np.arctan2(X[:, 1, 0], X[:, 0, 0])], axis=1)


def _poses(values, pg):
    return matrices_from_values(values, pg.group, pg.keys)


def _gtsam_planar_chordal(pg):
    """GTSAM's InitializePose3 on the planar Pose3 graph of a Pose2 graph: (n, 3) [x, y, yaw]."""
    T = _poses(gtsam.InitializePose3.initialize(_gtsam(planar_pose3(pg.anchored()))), planar_pose3(pg))
    return np.stack([T[:, 0, 3], T[:, 1, 3], np.arctan2(T[:, 1, 0], T[:, 0, 0])], axis=1)


def _rel(ours, ref, angles=False):
    d = ours - ref
    if angles:
        d[:, 2] = np.arctan2(np.sin(d[:, 2]), np.cos(d[:, 2]))
    return np.max(np.abs(d)) / max(1.0, np.max(np.abs(ref)))


GRAPHS_3D = ["smallGrid3D.g2o", "pose3example.txt", "pose3example-grid.txt", "pose3example-offdiagonal.txt",
             "sphere2500.txt"]


@pytest.mark.parametrize("name", GRAPHS_3D)
def test_initialize_pose3_matches_gtsam(name):
    pg = _graph(name)
    assert pg.group == "Pose3"
    ref = gtsam.InitializePose3.initialize(_gtsam(pg))
    ours = chordal.initialize(pg)
    assert ours.shape == (len(pg.keys), 4, 4)
    assert _rel(ours, _poses(ref, pg)) < 1e-9


def test_chordal_rotations_match_gtsam():
    pg = _graph("smallGrid3D.g2o")
    pose3graph = gtsam.InitializePose3.buildPose3graph(_gtsam(pg))
    ref = gtsam.InitializePose3.computeOrientationsChordal(pose3graph)
    ours = chordal.rotations(pg)
    assert np.max(np.abs(ours - np.array([ref.atRot3(int(k)).matrix() for k in pg.keys]))) < 1e-12


def test_initialize_pose3_priors_and_keys_as_gtsam():
    """Two priors away from pose 0, not at the identity, full information."""
    pg = _graph("pose3example-grid.txt")
    rng = np.random.default_rng(1)
    for k in (3, 10):
        A = rng.normal(size=(6, 6))
        pg = pg.with_prior(int(pg.keys[k]), gtsam.Pose3.Expmap(rng.normal(size=6)).matrix(), A @ A.T + 6 * np.eye(6))
    ref = gtsam.InitializePose3.initialize(_gtsam(pg))
    assert _rel(chordal.initialize(pg), _poses(ref, pg)) < 1e-9


def test_gauss_newton_step_linearizes_as_gtsam():
    """The pose step is one Gauss–Newton iteration of our between factors: at the chordal
    rotations their whitened linearization is GTSAM's (LogmapDerivative(e) = dlog(−e))."""
    from lie_factors.batch.graph import Problem
    from lie_factors.initialization.anchor import anchored_edges

    pg = _graph("smallGrid3D.g2o").anchored()
    n, ii, jj, Z, info = anchored_edges(pg)
    X = np.zeros((n + 1, 4, 4))
    X[:n, :3, :3] = chordal.rotations(pg)
    X[n] = np.eye(4)
    X[:, 3, 3] = 1.0
    anchored = PoseGraph("Pose3", np.arange(n + 1), np.stack([ii, jj], 1), Z, info, None, None)
    problem = Problem.from_pose_graph(anchored, X)
    problem.linearize()
    g = problem.groups[0]
    lin = anchored.factor_graph().linearize(matrices_to_values(X))
    for k in range(0, len(ii), 7):
        A, b = lin.at(k).jacobian()
        ref = np.concatenate([A, b[:, None]], axis=1)
        ours = np.concatenate([g.A1[k], g.A2[k], g.b[k][:, None]], axis=1)
        assert np.max(np.abs(ours - ref)) <= 1e-12 * max(1.0, np.max(np.abs(ref)))


def matrices_to_values(X):
    from lie_factors.interop import values_from_matrices

    return values_from_matrices("Pose3", np.arange(len(X)), X)


@pytest.mark.parametrize("name,odometric", [("noisyToyGraph.txt", True), ("pose2example.txt", True),
                                             ("pose2example.txt", False), ("w100_30.g2o", False)])
def test_lago_matches_gtsam(name, odometric):
    pg = _graph(name)
    assert pg.group == "Pose2"
    ref = gtsam.lago.initialize(_gtsam(pg), odometric)
    ours = lago.initialize_pose2(pg, odometric)
    assert ours.shape == (len(pg.keys), 3, 3)
    assert _rel(_xytheta(ours), _xytheta(_poses(ref, pg)), angles=True) < 1e-9


def test_lago_orientations_exact_where_gtsam_rounds():
    """w100_30 with its odometric path: GTSAM's own orientations are 1.4e-9 from the exact least-squares
    solution (the 1e8 prior weight against unit weights); ours are checked against that solution,
    computed with mpmath at 40 digits from the regularized measurements."""
    pg = _graph("w100_30.g2o")
    keys = pg.keys
    n = len(keys)
    idx = pg.index(pg.edge_keys.reshape(-1)).reshape(-1, 2)
    ii, jj = np.append(idx[:, 0], n), np.append(idx[:, 1], 0)
    dth = np.append(_xytheta(pg.measured)[:, 2], 0.0)
    w = np.append(pg.information[:, 2, 2], 1.0 / PRIOR_VARIANCES["Pose2"][2])
    th = lago.orientations(n, keys, ii, jj, dth, w, True)
    # Regularization from the tree: recomputed here by walking each node up to the anchor.
    parent = lago._odometric_tree(keys, ii, jj, n)
    delta = {}
    for e in range(ii.size):
        a, b = int(ii[e]), int(jj[e])
        if parent[a] == b:
            delta.setdefault(a, -dth[e])
        elif parent[b] == a:
            delta.setdefault(b, dth[e])

    def to_root(v):
        s = 0.0
        while v != n:
            s += delta[v]
            v = int(parent[v])
        return s

    tree = [to_root(v) for v in range(n)] + [0.0]
    with mpmath.workdps(40):  # local: the module-level precision is lie_factors.testing.reference's
        M, B = mpmath.zeros(n, n), mpmath.zeros(n, 1)
        for e in range(ii.size):
            a, b = int(ii[e]), int(jj[e])
            chord = not (parent[a] == b or parent[b] == a)
            d = dth[e] - (2 * round((dth[e] + tree[a] - tree[b]) / (2 * np.pi)) * np.pi if chord else 0.0)
            we, de = mpmath.mpf(w[e]), mpmath.mpf(d)
            if a < n:
                M[a, a] += we
                B[a, 0] -= we * de
            if b < n:
                M[b, b] += we
                B[b, 0] += we * de
            if a < n and b < n:
                M[a, b] -= we
                M[b, a] -= we
        exact = np.array([float(v) for v in mpmath.lu_solve(M, B)])
    assert np.max(np.abs(th[:n] - exact)) < 1e-12
    ref = gtsam.lago.initializeOrientations(_gtsam(pg), True)
    gtsam_err = np.max(np.abs(np.array([ref.at(int(k))[0] for k in keys]) - exact))
    assert np.max(np.abs(th[:n] - exact)) <= gtsam_err


@pytest.mark.parametrize("name", ["noisyToyGraph.txt", "w100_30.g2o"])
def test_chordal_pose2_is_initialize_chordal(name):
    """The README's rule: a 2-D graph goes through the chordal initializer as a planar Pose3 graph."""
    pg = _graph(name)
    assert _rel(_xytheta(chordal.initialize(pg)), _gtsam_planar_chordal(pg), angles=True) < 1e-9


def test_full_covariance_2d_is_rejected_by_lago_and_taken_by_chordal():
    pg = _graph("noisyToyGraph.txt")
    info = pg.information.copy()
    info[:, 0, 2] = info[:, 2, 0] = 0.1
    pg = dataclasses.replace(pg, information=info)
    with pytest.raises(InitializationError, match="diagonal"):
        lago.initialize_pose2(pg)
    assert _rel(_xytheta(chordal.initialize(pg)), _gtsam_planar_chordal(pg), angles=True) < 1e-9


@pytest.mark.parametrize("name,method", [("intel.g2o", "chordal2"), ("city10000.g2o", "lago"),
                                         ("parking-garage.g2o", "chordal3")])
def test_benchmark_graphs(name, method):
    pg = _graph(os.path.join(DATA, name))
    g = _gtsam(pg)
    if method == "chordal3":
        ours, ref = chordal.initialize(pg), _poses(gtsam.InitializePose3.initialize(g), pg)
    elif method == "lago":
        ours = _xytheta(lago.initialize_pose2(pg))
        ref = _xytheta(_poses(gtsam.lago.initialize(g, True), pg))
    else:
        ours, ref = _xytheta(chordal.initialize(pg)), _gtsam_planar_chordal(pg)
    assert _rel(ours, ref, angles=pg.group == "Pose2") < 1e-9


# --------------------------------------------------------------------------- #
# Bad input
# --------------------------------------------------------------------------- #

def test_disconnected_graph_is_reported():
    pg = _graph("pose3example.txt")
    pg = dataclasses.replace(pg, keys=np.append(pg.keys, pg.keys[-1] + 1), vertices=None)
    with pytest.raises(InitializationError, match="not connected: pose 5 has no path to a prior"):
        chordal.initialize(pg)


def test_bad_arrays_raise():
    """The initializers check their arrays (PoseGraph.validate; every case in tests/posegraph/test_pose_graph.py)."""
    pg = _graph("pose3example.txt")
    Z = pg.measured.copy()
    Z[0, 0, 0] = np.nan
    for run in (chordal.initialize, chordal.rotations):
        with pytest.raises(ValueError, match="NaN"):
            run(dataclasses.replace(pg, measured=Z))
    with pytest.raises(InitializationError, match="LAGO is for Pose2 graphs; this one is Pose3"):
        lago.initialize_pose2(pg)


def test_numba_free_initializers_do_not_import_numba():
    """GTSAM's initializers on our graph, our LAGO and the spanning tree: no numba (the native
    backend and the input check use them); our chordal initializer runs the batch loops."""
    code = ("import sys, numpy as np\n"
            "from lie_factors.initialization import initialize\n"
            "from lie_factors.posegraph.graph import PoseGraph\n"
            "X = np.eye(3)[None]\n"
            "pg = PoseGraph('Pose2', np.array([0, 1]), np.array([[0, 1]]), X, np.eye(3)[None], None, None)\n"
            "for method in ('lago', 'spanning-tree'):\n"
            "    initialize(pg, method)\n"
            "initialize(pg, 'chordal', engine='gtsam')\n"
            "assert 'numba' not in sys.modules, 'numba imported'\n"
            "initialize(pg, 'chordal')\n"
            "assert 'numba' in sys.modules\n")
    subprocess.run([sys.executable, "-c", code], check=True)


# --------------------------------------------------------------------------- #
# lie_factors.initialization: ours where cvxopt is there, GTSAM's own elsewhere
# --------------------------------------------------------------------------- #

def _small_graph_with(noise_of):
    pg = _graph("smallGrid3D.g2o")
    g = gtsam.NonlinearFactorGraph()
    for (a, b), z, info in zip(pg.edge_keys.tolist(), pg.measured, pg.information):
        g.add(gtsam.BetweenFactorPose3(a, b, gtsam.Pose3(z), noise_of(info)))
    g.add(gtsam.PriorFactorPose3(int(pg.keys[0]), gtsam.Pose3(),
                                 gtsam.noiseModel.Diagonal.Variances(PRIOR_VARIANCES["Pose3"])))
    return g, pg


def test_a_noise_model_is_read_as_its_information():
    """A GTSAM graph is initialized as its PoseGraph: a model's square root R (here lower
    triangular) counts by its information RᵀR, GTSAM's initializer on the graph built from it is
    the reference.  (GTSAM's own on the given graph would weigh each chordal row by R[0, 0].)"""
    rng = np.random.default_rng(4)
    L = np.tril(rng.normal(size=(6, 6))) + 4 * np.eye(6)
    g, pg = _small_graph_with(lambda info: gtsam.noiseModel.Gaussian.SqrtInformation(L, False))
    rebuilt = PoseGraph.from_gtsam(g).factor_graph()
    np.testing.assert_allclose(rebuilt.at(0).noiseModel().information(), L.T @ L, rtol=1e-13)
    ref = _poses(gtsam.InitializePose3.initialize(rebuilt), pg)
    assert np.max(np.abs(_poses(LI.initialize(g, "chordal").values, pg) - ref)) < 1e-9
    assert np.max(np.abs(_poses(LI.initialize(g, "chordal", engine="gtsam").values, pg) - ref)) == 0.0


def test_initialize_without_cholmod_runs_gtsams(monkeypatch):
    g, pg = _small_graph_with(gtsam.noiseModel.Gaussian.Information)
    ours = _poses(LI.initialize(g, "chordal").values, pg)
    monkeypatch.setattr(cholmod, "available", lambda: False)

    def not_called(*args, **kwargs):
        raise AssertionError("our initializer runs without CHOLMOD")

    monkeypatch.setattr(chordal, "initialize", not_called)
    ref = _poses(gtsam.InitializePose3.initialize(PoseGraph.from_gtsam(g).factor_graph()), pg)
    fallback = _poses(LI.initialize(g, "chordal").values, pg)
    assert np.max(np.abs(fallback - ref)) == 0.0
    assert 0.0 < np.max(np.abs(ours - fallback)) < 1e-9  # ours differs by rounding only


def test_lago_odometric_path_without_a_prior_on_its_root_fails_as_gtsams():
    """The odometric path hangs its first key from the anchor; with the prior elsewhere GTSAM throws (map::at)."""
    Z = gtsam.Pose2(1, 0, 0.5).matrix()[None]
    pg = PoseGraph("Pose2", np.array([0, 1]), np.array([[0, 1]]), Z, np.eye(3)[None], None, None)
    pg = pg.with_prior(1, np.eye(3), 100 * np.eye(3))
    g = pg.factor_graph()
    with pytest.raises(IndexError):
        gtsam.lago.initialize(g, True)
    with pytest.raises(InitializationError, match="odometric path"):
        lago.initialize_pose2(pg)
    ours = lago.initialize_pose2(pg, use_odometric_path=False)
    assert _rel(_xytheta(ours), _xytheta(_poses(gtsam.lago.initialize(g, False), pg)), angles=True) < 1e-12
