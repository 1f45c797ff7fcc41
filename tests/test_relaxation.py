"""lie_factors.initialization.relaxation against GTSAM's own initializers (InitializePose3, lago) on the same graphs."""

from __future__ import annotations

import os
import subprocess
import sys

import gtsam
import mpmath
import numpy as np
import pytest

from lie_factors.initialization import relaxation as rx
from lie_factors import initialization as LI
from lie_factors.app.run import load

ROOT = os.path.join(os.path.dirname(__file__), "..")
DATA = os.path.join(ROOT, "data")


def _path(name):
    if os.path.exists(os.path.join(ROOT, "data", name)):
        return os.path.join(ROOT, "data", name)
    return gtsam.findExampleDataFile(name)


def _arrays(name):
    """(keys, i, j, measured, information) of a file's between factors, measured as 4×4 (3-D) or [x, y, θ]."""
    pg = load(_path(name) if "/" not in name else name)
    g = pg.between
    keys = sorted({k for f in range(g.size()) for k in g.at(f).keys()})
    idx = {k: n for n, k in enumerate(keys)}
    I, J, Z, INFO = [], [], [], []
    for k in range(g.size()):
        f = g.at(k)
        a, b = f.keys()
        I.append(idx[a])
        J.append(idx[b])
        m = f.measured()
        Z.append(m.matrix() if pg.is3d else [m.x(), m.y(), m.theta()])
        R = f.noiseModel().R()
        INFO.append(R.T @ R)
    return pg.is3d, np.array(keys), np.array(I), np.array(J), np.array(Z), np.array(INFO)


def _gtsam_graph(is3d, keys, I, J, Z, INFO, priors=None):
    """GTSAM's graph of the arrays: the between factors, then the priors (default: identity on keys[0])."""
    g = gtsam.NonlinearFactorGraph()
    P = gtsam.Pose3 if is3d else gtsam.Pose2
    B = gtsam.BetweenFactorPose3 if is3d else gtsam.BetweenFactorPose2
    Prior = gtsam.PriorFactorPose3 if is3d else gtsam.PriorFactorPose2
    for a, b, z, info in zip(I, J, Z, INFO):
        g.add(B(int(keys[a]), int(keys[b]), P(z) if is3d else P(*z), gtsam.noiseModel.Gaussian.Information(info)))
    if priors is None:
        var = rx.DEFAULT_PRIOR_VARIANCES_3D if is3d else rx.DEFAULT_PRIOR_VARIANCES_2D
        g.add(Prior(int(keys[0]), P(), gtsam.noiseModel.Diagonal.Variances(var)))
    else:
        for p, z, info in zip(*priors):
            g.add(Prior(int(keys[p]), P(z) if is3d else P(*z), gtsam.noiseModel.Gaussian.Information(info)))
    return g


def _pose3s(values, keys):
    return np.array([values.atPose3(int(k)).matrix() for k in keys])


def _pose2s(values, keys):
    return np.array([[values.atPose2(int(k)).x(), values.atPose2(int(k)).y(), values.atPose2(int(k)).theta()]
                     for k in keys])


def _gtsam_planar_chordal(graph, keys):
    """GTSAM's InitializePose3 on the planar Pose3 graph lie_factors.initialization builds: (n, 3) [x, y, yaw]."""
    planar = LI._native_graph(LI._planar_pose3_graph(LI._convert(graph)))
    values = gtsam.InitializePose3.initialize(planar)
    return np.array([[values.atPose3(int(k)).x(), values.atPose3(int(k)).y(),
                      values.atPose3(int(k)).rotation().yaw()] for k in keys])


def _rel(ours, ref, angles=False):
    d = ours - ref
    if angles:
        d[:, 2] = np.arctan2(np.sin(d[:, 2]), np.cos(d[:, 2]))
    return np.max(np.abs(d)) / max(1.0, np.max(np.abs(ref)))


GRAPHS_3D = ["smallGrid3D.g2o", "pose3example.txt", "pose3example-grid.txt", "pose3example-offdiagonal.txt",
             "sphere2500.txt"]


@pytest.mark.parametrize("name", GRAPHS_3D)
def test_initialize_pose3_matches_gtsam(name):
    is3d, keys, I, J, Z, INFO = _arrays(name)
    assert is3d
    ref = gtsam.InitializePose3.initialize(_gtsam_graph(is3d, keys, I, J, Z, INFO))
    ours = rx.initialize_pose3(len(keys), I, J, Z, INFO)
    assert ours.shape == (len(keys), 4, 4)
    assert _rel(ours, _pose3s(ref, keys)) < 1e-9


def test_chordal_rotations_match_gtsam():
    is3d, keys, I, J, Z, INFO = _arrays("smallGrid3D.g2o")
    pose3graph = gtsam.InitializePose3.buildPose3graph(_gtsam_graph(is3d, keys, I, J, Z, INFO))
    ref = gtsam.InitializePose3.computeOrientationsChordal(pose3graph)
    ours = rx.chordal_rotations(len(keys), I, J, Z, INFO)
    assert np.max(np.abs(ours - np.array([ref.atRot3(int(k)).matrix() for k in keys]))) < 1e-12


def test_initialize_pose3_priors_and_keys_as_gtsam():
    """Two priors away from pose 0, not at the identity, full information; keys that include GTSAM's anchor."""
    is3d, keys, I, J, Z, INFO = _arrays("pose3example-grid.txt")
    rng = np.random.default_rng(1)
    pZ = np.array([gtsam.Pose3.Expmap(rng.normal(size=6)).matrix() for _ in range(2)])
    A = rng.normal(size=(2, 6, 6))
    pinfo = A @ np.swapaxes(A, 1, 2) + 6 * np.eye(6)
    pidx = np.array([3, 10])
    ref = gtsam.InitializePose3.initialize(_gtsam_graph(is3d, keys, I, J, Z, INFO, (pidx, pZ, pinfo)))
    ours = rx.initialize_pose3(len(keys), I, J, Z, INFO, pidx, pZ, pinfo)
    assert _rel(ours, _pose3s(ref, keys)) < 1e-9


@pytest.mark.parametrize("name,odometric", [("noisyToyGraph.txt", True), ("pose2example.txt", True),
                                             ("pose2example.txt", False), ("w100_30.g2o", False)])
def test_lago_matches_gtsam(name, odometric):
    is3d, keys, I, J, Z, INFO = _arrays(name)
    assert not is3d
    ref = gtsam.lago.initialize(_gtsam_graph(is3d, keys, I, J, Z, INFO), odometric)
    ours = rx.lago_pose2(len(keys), I, J, Z, INFO, keys=keys, use_odometric_path=odometric)
    assert ours.shape == (len(keys), 3)
    assert _rel(ours, _pose2s(ref, keys), angles=True) < 1e-9


def test_lago_orientations_exact_where_gtsam_rounds():
    """w100_30 with its odometric path: GTSAM's own orientations are 1.4e-9 from the exact least-squares
    solution (the 1e8 prior weight against unit weights); ours are checked against that solution,
    computed with mpmath at 40 digits from the regularized measurements."""
    is3d, keys, I, J, Z, INFO = _arrays("w100_30.g2o")
    n = len(keys)
    ii, jj = np.append(I, n), np.append(J, 0)
    dth = np.append(Z[:, 2], 0.0)
    w = np.append(INFO[:, 2, 2], 1.0 / rx.DEFAULT_PRIOR_VARIANCES_2D[2])
    th = rx._lago_orientations(n, keys, ii, jj, dth, w, True)
    # Regularization from the tree: recomputed here by walking each node up to the anchor.
    parent = rx._odometric_tree(keys, ii, jj, n)
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
    ref = gtsam.lago.initializeOrientations(_gtsam_graph(is3d, keys, I, J, Z, INFO), True)
    gtsam_err = np.max(np.abs(np.array([ref.at(int(k))[0] for k in keys]) - exact))
    assert np.max(np.abs(th[:n] - exact)) <= gtsam_err


@pytest.mark.parametrize("name", ["noisyToyGraph.txt", "w100_30.g2o"])
def test_chordal_pose2_is_initialize_chordal(name):
    """The README's rule: a 2-D graph goes through the chordal initializer as a planar Pose3 graph."""
    is3d, keys, I, J, Z, INFO = _arrays(name)
    ref = _gtsam_planar_chordal(_gtsam_graph(is3d, keys, I, J, Z, INFO), keys)
    ours = rx.chordal_pose2(len(keys), I, J, Z, INFO)
    assert _rel(ours, ref, angles=True) < 1e-9


def test_full_covariance_2d_is_rejected_by_lago_and_taken_by_chordal():
    is3d, keys, I, J, Z, INFO = _arrays("noisyToyGraph.txt")
    INFO = INFO.copy()
    INFO[:, 0, 2] = INFO[:, 2, 0] = 0.1
    with pytest.raises(rx.RelaxationError, match="diagonal"):
        rx.lago_pose2(len(keys), I, J, Z, INFO)
    ref = _gtsam_planar_chordal(_gtsam_graph(is3d, keys, I, J, Z, INFO), keys)
    assert _rel(rx.chordal_pose2(len(keys), I, J, Z, INFO), ref, angles=True) < 1e-9


@pytest.mark.parametrize("name,method", [("intel.g2o", "chordal2"), ("city10000.g2o", "lago"),
                                         ("parking-garage.g2o", "chordal3")])
def test_benchmark_graphs(name, method):
    is3d, keys, I, J, Z, INFO = _arrays(os.path.join(DATA, name))
    g = _gtsam_graph(is3d, keys, I, J, Z, INFO)
    if method == "chordal3":
        ours, ref = rx.initialize_pose3(len(keys), I, J, Z, INFO), _pose3s(gtsam.InitializePose3.initialize(g), keys)
    elif method == "lago":
        ours = rx.lago_pose2(len(keys), I, J, Z, INFO, keys=keys)
        ref = _pose2s(gtsam.lago.initialize(g, True), keys)
    else:
        ours, ref = rx.chordal_pose2(len(keys), I, J, Z, INFO), _gtsam_planar_chordal(g, keys)
    assert _rel(ours, ref, angles=not is3d) < 1e-9


# --------------------------------------------------------------------------- #
# The numpy Lie-group pieces against GTSAM, around their series thresholds
# --------------------------------------------------------------------------- #

@pytest.mark.parametrize("scale", [0.0, 1e-9, 1e-3, 0.0099, 0.0101, 0.099, 0.101, 1.0, 3.0, np.pi - 1e-7])
def test_pose3_logmap_derivative_and_log(scale):
    rng = np.random.default_rng(2)
    x = rng.normal(size=(20, 6))
    x[:, :3] *= scale / np.linalg.norm(x[:, :3], axis=1)[:, None]
    ref = np.array([gtsam.Pose3.LogmapDerivative(v) for v in x])
    assert np.max(np.abs(rx._pose3_logmap_derivative(x) - ref)) <= 1e-13 * max(1.0, np.max(np.abs(ref)))
    T = np.array([gtsam.Pose3.Expmap(v).matrix() for v in x])
    log = rx._pose3_log(T[:, :3, :3], T[:, :3, 3])
    ref_log = np.array([gtsam.Pose3.Logmap(gtsam.Pose3(t)) for t in T])
    assert np.max(np.abs(log - ref_log)) < 1e-12
    R, V = rx._rot_exp_V(x[:, :3])
    assert np.max(np.abs(R - T[:, :3, :3])) < 1e-15 * 10
    assert np.max(np.abs(np.einsum("kab,kb->ka", V, x[:, 3:]) - T[:, :3, 3])) < 1e-13


def test_rot_log_at_pi_and_past_half_pi():
    rng = np.random.default_rng(3)
    axes = rng.normal(size=(10, 3))
    axes /= np.linalg.norm(axes, axis=1)[:, None]
    for th in (np.pi / 2 - 1e-9, np.pi / 2 + 1e-9, 3.0, np.pi - 1e-9, np.pi):
        R = np.array([gtsam.Rot3.Expmap(th * a).matrix() for a in axes])
        ours = rx._rot_log(R)
        back = np.array([gtsam.Rot3.Expmap(w).matrix() for w in ours])
        assert np.max(np.abs(back - R)) < 1e-14
        assert np.all(np.linalg.norm(ours, axis=1) <= np.pi + 1e-15)


# --------------------------------------------------------------------------- #
# Bad input
# --------------------------------------------------------------------------- #

def _tiny():
    is3d, keys, I, J, Z, INFO = _arrays("pose3example.txt")
    return len(keys), I, J, Z, INFO


def test_disconnected_graph_is_reported():
    n, I, J, Z, INFO = _tiny()
    with pytest.raises(rx.RelaxationError, match="not connected: pose 5"):
        rx.initialize_pose3(n + 1, I, J, Z, INFO)


@pytest.mark.parametrize("change,match", [
    (lambda a: a.update(i=a["i"][:-1]), "shapes differ"),
    (lambda a: a.update(j=a["i"]), "joins a pose to itself"),
    (lambda a: a.update(i=a["i"] + 10), "out of range"),
    (lambda a: a["Z"].__setitem__((0, 0, 0), np.nan), "NaN"),
    (lambda a: a["Z"].__setitem__((0, 0, 0), 2.0), "not orthonormal"),
    (lambda a: a["Z"].__setitem__((0, 3, 0), 1.0), "last row"),
    (lambda a: a["INFO"].__setitem__((0, 0, 1), 5.0), "symmetric"),
    (lambda a: a["INFO"].__setitem__((0, 0, 0), -1.0), "positive definite"),
    (lambda a: a.update(INFO=a["INFO"][:, :3, :3]), r"expected shape"),
])
def test_bad_arrays_raise(change, match):
    n, I, J, Z, INFO = _tiny()
    a = {"i": I.copy(), "j": J.copy(), "Z": Z.copy(), "INFO": INFO.copy()}
    change(a)
    with pytest.raises(ValueError, match=match):
        rx.initialize_pose3(n, a["i"], a["j"], a["Z"], a["INFO"])


def test_relaxation_does_not_import_numba():
    code = ("import sys, numpy as np; from lie_factors.initialization import relaxation as rx;"
            "T = np.eye(4)[None]; rx.initialize_pose3(2, [0], [1], T, np.eye(6)[None]);"
            "rx.lago_pose2(2, [0], [1], [[1, 0, 0]], np.eye(3)[None]);"
            "assert 'numba' not in sys.modules, 'numba imported'")
    subprocess.run([sys.executable, "-c", code], check=True)


# --------------------------------------------------------------------------- #
# lie_factors.initialization: arrays where they give GTSAM's answer, GTSAM's own initializer elsewhere
# --------------------------------------------------------------------------- #

def _small_graph_with(noise_of):
    is3d, keys, I, J, Z, INFO = _arrays("smallGrid3D.g2o")
    g = gtsam.NonlinearFactorGraph()
    for a, b, z, info in zip(I, J, Z, INFO):
        g.add(gtsam.BetweenFactorPose3(int(keys[a]), int(keys[b]), gtsam.Pose3(z), noise_of(info)))
    g.add(gtsam.PriorFactorPose3(int(keys[0]), gtsam.Pose3(),
                                 gtsam.noiseModel.Diagonal.Variances(rx.DEFAULT_PRIOR_VARIANCES_3D)))
    return g, keys


def test_initialize_falls_back_to_gtsam_for_a_lower_triangular_square_root(monkeypatch):
    """GTSAM weighs a chordal row by R[0, 0] of the model's square-root information: √information[0, 0]
    only for an upper-triangular R, so any other R goes to GTSAM's own initializer."""
    rng = np.random.default_rng(4)
    L = np.tril(rng.normal(size=(6, 6))) + 4 * np.eye(6)
    g, keys = _small_graph_with(lambda info: gtsam.noiseModel.Gaussian.SqrtInformation(L, False))

    def not_called(*args, **kwargs):
        raise AssertionError("the arrays' initializer would weigh this graph differently from GTSAM")

    monkeypatch.setattr(rx, "initialize_pose3", not_called)
    got = LI.initialize(g, "chordal").values
    ref = gtsam.InitializePose3.initialize(g)
    assert np.max(np.abs(_pose3s(got, keys) - _pose3s(ref, keys))) == 0.0


def test_initialize_without_cholmod_runs_gtsams(monkeypatch):
    g, keys = _small_graph_with(gtsam.noiseModel.Gaussian.Information)
    arrays = _pose3s(LI.initialize(g, "chordal").values, keys)
    monkeypatch.setattr(rx, "cholmod_available", lambda: False)
    ref = gtsam.InitializePose3.initialize(g)
    fallback = _pose3s(LI.initialize(g, "chordal").values, keys)
    assert np.max(np.abs(fallback - _pose3s(ref, keys))) == 0.0
    assert 0.0 < np.max(np.abs(arrays - fallback)) < 1e-9  # the arrays' answer differs by rounding only


def test_lago_odometric_path_without_a_prior_on_its_root_fails_as_gtsams():
    """The odometric path hangs its first key from the anchor; with the prior elsewhere GTSAM throws (map::at)."""
    args = (2, [0], [1], [[1.0, 0.0, 0.5]], np.eye(3)[None])
    prior = dict(prior_index=[1], prior_measured=[[0.0, 0.0, 0.0]], prior_information=100 * np.eye(3)[None])
    g = gtsam.NonlinearFactorGraph()
    g.add(gtsam.BetweenFactorPose2(0, 1, gtsam.Pose2(1, 0, 0.5), gtsam.noiseModel.Unit.Create(3)))
    g.add(gtsam.PriorFactorPose2(1, gtsam.Pose2(), gtsam.noiseModel.Diagonal.Precisions(np.full(3, 100.0))))
    with pytest.raises(IndexError):
        gtsam.lago.initialize(g, True)
    with pytest.raises(rx.RelaxationError, match="odometric path"):
        rx.lago_pose2(*args, **prior)
    ours = rx.lago_pose2(*args, **prior, use_odometric_path=False)
    assert _rel(ours, _pose2s(gtsam.lago.initialize(g, False), [0, 1]), angles=True) < 1e-12
