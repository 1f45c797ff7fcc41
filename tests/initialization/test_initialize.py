"""lie_factors.initialization: GTSAM's initializers on our factors, the fallbacks, the anchor."""

from __future__ import annotations

from pathlib import Path

import gtsam
import numpy as np
import pytest

from support.cli_helpers import last_json, run_main
from lie_factors import factors as F
from lie_factors import initialization as I
from support.runs import run
import lie_factors as lf
from lie_factors.backends import build_graph
from lie_factors.g2o import read_pose_graph
from lie_factors.errors import InputError
from lie_factors.initialization import chordal, lago
from lie_factors.initialization.planar import planar_pose3
from lie_factors.interop import matrices_from_values
from lie_factors.posegraph.graph import PRIOR_VARIANCES, PoseGraph

DATA = Path(__file__).resolve().parents[2] / "data"
SMALL = DATA / "smallGrid3D.g2o"


def pose2_loop(n=12, radius=5.0, noise=0.0, seed=0, full_cov=False, prior=True, offset=0):
    """Poses on a circle, odometry + a few chords; measurements from the truth, perturbed by ``noise``.

    Returns (graph of GTSAM's own factors, truth Values).
    """
    rng = np.random.default_rng(seed)
    truth = gtsam.Values()
    for i in range(n):
        a = 2 * np.pi * i / n
        truth.insert(offset + i, gtsam.Pose2(radius * np.cos(a), radius * np.sin(a), a + np.pi / 2))
    if full_cov:
        model = gtsam.noiseModel.Gaussian.Covariance(np.array([[0.01, 0.004, 0], [0.004, 0.02, 0],
                                                               [0, 0, 0.001]]))
    else:
        model = gtsam.noiseModel.Diagonal.Sigmas(np.array([0.1, 0.1, 0.03]))
    edges = [(i, (i + 1) % n) for i in range(n)] + [(i, (i + n // 2) % n) for i in range(0, n, 3)]
    graph = gtsam.NonlinearFactorGraph()
    for i, j in edges:
        Z = truth.atPose2(offset + i).between(truth.atPose2(offset + j))
        Z = Z.retract(noise * rng.normal(size=3))
        graph.add(gtsam.BetweenFactorPose2(offset + i, offset + j, Z, model))
    if prior:
        graph.add(gtsam.PriorFactorPose2(offset, truth.atPose2(offset),
                                         gtsam.noiseModel.Diagonal.Variances(PRIOR_VARIANCES["Pose2"])))
    return graph, truth


def as_custom(graph: gtsam.NonlinearFactorGraph) -> gtsam.NonlinearFactorGraph:
    """The same graph rebuilt with lie_factors' factors."""
    out = gtsam.NonlinearFactorGraph()
    for k in range(graph.size()):
        f = graph.at(k)
        keys = f.keys()
        if len(keys) == 2:
            cls = F.BetweenFactorPose3 if isinstance(f.measured(), gtsam.Pose3) else F.BetweenFactorPose2
            out.add(cls(keys[0], keys[1], f.measured(), f.noiseModel()))
        else:
            cls = F.PriorFactorPose3 if isinstance(f.prior(), gtsam.Pose3) else F.PriorFactorPose2
            out.add(cls(keys[0], f.prior(), f.noiseModel()))
    return out


def max_pose_diff(a: gtsam.Values, b: gtsam.Values, is3d: bool) -> float:
    keys = sorted(a.keys())
    assert keys == sorted(b.keys())
    at_a = a.atPose3 if is3d else a.atPose2
    at_b = b.atPose3 if is3d else b.atPose2
    return max(np.abs(at_a(k).localCoordinates(at_b(k))).max() for k in keys)


def small3d():
    pg = read_pose_graph(str(SMALL))
    return pg, build_graph(pg, "native")


# ------------------------------------------------------------------ chordal

def test_chordal_3d_is_gtsams_initializer_for_native_and_custom_factors():
    pg, native = small3d()
    ref = gtsam.InitializePose3.initialize(native)
    for graph in (native, as_custom(native)):
        got = I.initialize(graph, "chordal")
        assert got.method == "chordal" and got.skipped == [] and got.seconds > 0
        # Ours (lie_factors.initialization.chordal): GTSAM's results up to rounding (7e-12 here);
        # the contract for a reimplementation is 1e-9.
        assert max_pose_diff(got.values, ref, True) < 1e-9
    # …and it is a much better start than the file's composed odometry.
    assert native.error(ref) < 0.1 * native.error(pg.initial)


def test_chordal_2d_recovers_noise_free_poses_and_stays_planar():
    graph, truth = pose2_loop(noise=0.0, full_cov=True)
    got = I.initialize(graph, "chordal")
    assert max_pose_diff(got.values, truth, False) < 1e-9
    # The planar Pose3 graph handed to GTSAM comes back planar on a noisy graph too.
    noisy, _ = pose2_loop(noise=0.05, full_cov=True, seed=3)
    values3 = gtsam.InitializePose3.initialize(planar_pose3(PoseGraph.from_gtsam(noisy)).factor_graph())
    for k in values3.keys():
        T = values3.atPose3(k)
        assert abs(T.z()) < 1e-9 and abs(T.rotation().roll()) < 1e-9 and abs(T.rotation().pitch()) < 1e-9


def test_chordal_2d_start_reaches_the_optimum():
    graph, truth = pose2_loop(noise=0.05, full_cov=True, seed=1)
    start = I.initialize(graph, "chordal").values
    ref = gtsam.LevenbergMarquardtOptimizer(graph, truth, gtsam.LevenbergMarquardtParams()).optimize()
    res = lf.optimize(graph, start, backend="native")
    assert res.error == pytest.approx(graph.error(ref), rel=1e-8)
    assert graph.error(start) < graph.error(truth) * 10


# --------------------------------------------------------------------- lago

def test_lago_is_gtsams_initializer_for_native_and_custom_factors():
    graph, truth = pose2_loop(noise=0.03, seed=2)
    ref = gtsam.lago.initialize(graph)
    for g in (graph, as_custom(graph)):
        got = I.initialize(g, "lago")
        assert got.method == "lago"
        # Ours (lie_factors.initialization.lago): GTSAM's up to rounding (2e-12 here); the contract for a
        # reimplementation is 1e-9.
        assert max_pose_diff(got.values, ref, False) < 1e-9
    noise_free, truth = pose2_loop(noise=0.0)
    assert max_pose_diff(I.initialize(noise_free, "lago").values, truth, False) < 1e-9


def test_lago_without_an_odometric_chain_uses_the_spanning_tree():
    # Keys 0, 2, 4, … : lago's odometric path (consecutive keys) does not exist.
    graph, truth = pose2_loop(noise=0.0)
    renumbered = gtsam.NonlinearFactorGraph()
    for k in range(graph.size()):
        f = graph.at(k)
        keys = [2 * key for key in f.keys()]
        if len(keys) == 2:
            renumbered.add(gtsam.BetweenFactorPose2(keys[0], keys[1], f.measured(), f.noiseModel()))
        else:
            renumbered.add(gtsam.PriorFactorPose2(keys[0], f.prior(), f.noiseModel()))
    got = I.initialize(renumbered, "lago").values
    for key in truth.keys():
        assert np.abs(got.atPose2(2 * key).localCoordinates(truth.atPose2(key))).max() < 1e-9


def test_lago_refuses_full_covariance_and_3d():
    graph, _ = pose2_loop(full_cov=True)
    with pytest.raises(I.InitializationError, match="lago: LAGO needs diagonal noise models; edge 0-1"):
        I.initialize(graph, "lago")
    _, g3 = small3d()
    with pytest.raises(I.InitializationError, match="LAGO is for Pose2 graphs"):
        I.initialize(g3, "lago")


# --------------------------------------------------------------------- auto

def test_auto_picks_chordal_in_3d():
    pg, graph = small3d()
    got = I.initialize(graph, "auto", pg.initial)
    assert got.method == "chordal" and got.skipped == []


def test_auto_picks_lago_in_2d_with_diagonal_noise():
    graph, _ = pose2_loop(noise=0.03)
    assert I.initialize(graph).method == "lago"


def test_auto_falls_back_to_chordal_for_full_covariance_and_names_why():
    graph, _ = pose2_loop(noise=0.03, full_cov=True)
    got = I.initialize(graph)
    assert got.method == "chordal"
    assert [m for m, _ in got.skipped] == ["lago"] and "diagonal" in got.skipped[0][1]


def disconnected():
    """Two 2-D loops with no edge between them, a prior only on the first."""
    a, ta = pose2_loop(n=6, noise=0.0)
    b, tb = pose2_loop(n=6, noise=0.0, prior=False, offset=100)
    for k in range(b.size()):
        a.add(b.at(k))
    truth = gtsam.Values(ta)
    truth.insert(tb)
    return a, truth


def test_disconnected_graph_every_graph_method_says_so(forbid_factorization):
    """The second loop's gauge is free: refused on the structure, before any factorization."""
    graph, _ = disconnected()
    forbid_factorization()
    for method in ("chordal", "lago", "spanning-tree"):
        with pytest.raises(I.InitializationError, match=f"^{method}: graph is not connected: pose 100"):
            I.initialize(graph, method)


def test_disconnected_graph_auto_falls_back_to_file_then_fails_without_it():
    graph, truth = disconnected()
    got = I.initialize(graph, "auto", truth)
    assert got.method == "file" and got.values is truth
    assert [m for m, _ in got.skipped] == ["lago", "chordal"]
    with pytest.raises(I.InitializationError, match="no initialization method applies"):
        I.initialize(graph, "auto")


def test_auto_without_initial_values_ends_with_spanning_tree(monkeypatch):
    graph, truth = pose2_loop(noise=0.0)

    def cannot(*args):
        raise I.InitializationError("not today")

    monkeypatch.setattr(lago, "initialize_pose2", cannot)
    monkeypatch.setattr(chordal, "initialize", cannot)
    got = I.initialize(graph)
    assert got.method == "spanning-tree"
    assert got.skipped == [("lago", "not today"), ("chordal", "not today")]
    assert max_pose_diff(got.values, truth, False) < 1e-9


# ------------------------------------------------------------ file, tree

def test_file_returns_the_given_values_and_checks_them():
    pg, graph = small3d()
    assert I.initialize(graph, "file", pg.initial).values is pg.initial
    with pytest.raises(I.InitializationError, match="file: no initial values given"):
        I.initialize(graph, "file")
    partial = gtsam.Values()
    partial.insert(0, gtsam.Pose3())
    with pytest.raises(I.InitializationError, match="has no value for pose 1"):
        I.initialize(graph, "file", partial)


def test_spanning_tree_starts_at_the_prior():
    graph, truth = pose2_loop(noise=0.0, offset=7)
    got = I.initialize(graph, "spanning-tree")
    assert max_pose_diff(got.values, truth, False) < 1e-9


# ------------------------------------------------------- anchor, bad input

def test_graph_without_prior_is_anchored_at_identity_on_smallest_key():
    graph, truth = pose2_loop(noise=0.0, prior=False, offset=3)
    for method in ("chordal", "lago", "spanning-tree"):
        values = I.initialize(graph, method).values
        assert np.abs(gtsam.Pose2.Logmap(values.atPose2(3))).max() < 1e-9
        rel = truth.atPose2(3).inverse()
        for k in truth.keys():
            expected = rel.compose(truth.atPose2(k))
            assert np.abs(values.atPose2(k).localCoordinates(expected)).max() < 1e-9


def test_graph_using_gtsams_anchor_key_is_renumbered():
    graph, truth = pose2_loop(noise=0.0, offset=I.ANCHOR_KEY - 5)
    for method in ("chordal", "lago"):
        values = I.initialize(graph, method).values
        assert max_pose_diff(values, truth, False) < 1e-9


def test_robust_noise_uses_its_gaussian_part():
    graph, _ = pose2_loop(noise=0.03, seed=4)
    robust = gtsam.NonlinearFactorGraph()
    for k in range(graph.size()):
        f = graph.at(k)
        if len(f.keys()) == 2:
            model = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(1.0),
                                                   f.noiseModel())
            robust.add(gtsam.BetweenFactorPose2(*f.keys(), f.measured(), model))
        else:
            robust.add(f)
    for method in ("lago", "chordal"):
        a = I.initialize(graph, method).values
        b = I.initialize(robust, method).values
        assert max_pose_diff(a, b, False) < 1e-12


def test_bad_graphs_are_refused():
    graph = gtsam.NonlinearFactorGraph()
    graph.add(gtsam.BetweenFactorPoint3(0, 1, np.zeros(3), gtsam.noiseModel.Unit.Create(3)))
    with pytest.raises(I.InitializationError, match=r"^auto: factor 0 \(BetweenFactorPoint3\) is not"):
        I.initialize(graph)
    # …but given values, auto and file start from them.
    values = gtsam.Values()
    values.insert(0, np.zeros(3))
    values.insert(1, np.ones(3))
    got = I.initialize(graph, "auto", values)
    assert got.method == "file" and got.values is values and "BetweenFactorPoint3" in got.skipped[0][1]
    assert I.initialize(graph, "file", values).values is values
    with pytest.raises(I.InitializationError, match=r"^chordal: factor 0 \(BetweenFactorPoint3\)"):
        I.initialize(graph, "chordal", values)
    with pytest.raises(I.InitializationError, match="no between factors"):
        I.initialize(gtsam.NonlinearFactorGraph())
    mixed, _ = pose2_loop()
    mixed.add(gtsam.BetweenFactorPose3(0, 1, gtsam.Pose3(), gtsam.noiseModel.Unit.Create(6)))
    with pytest.raises(I.InitializationError, match="mixes Pose2 and Pose3"):
        I.initialize(mixed)
    with pytest.raises(I.InitializationError, match="unknown initialization 'odometer'"):
        I.initialize(mixed, "odometer")
    assert issubclass(I.InitializationError, InputError)


# ------------------------------------------------------------ posegraph.run

def test_every_backend_starts_from_the_same_values():
    pg = read_pose_graph(str(SMALL))
    records = {b: run(pg, b, max_iterations=1, init="chordal") for b in ("native", "dropin", "batch")}
    start = records["native"][1].start
    for backend, (record, result, _) in records.items():
        assert record.init == "chordal" and record.init_seconds > 0
        # batch initializes with ours (GTSAM's algorithm, our arithmetic, agreeing to 1e-9);
        # the others run GTSAM's own.
        tol = 1e-9 if backend == "batch" else 1e-12
        assert max_pose_diff(result.start, start, True) < tol
        assert record.initial_error == pytest.approx(records["native"][0].initial_error, rel=1e-9)


def test_run_file_start_is_the_vertices_and_auto_is_no_worse():
    pg = read_pose_graph(str(SMALL))
    file_rec, file_res, _ = run(pg, "native", init="file")
    assert file_rec.init == "file"
    assert np.array_equal(matrices_from_values(file_res.start, "Pose3", pg.keys), pg.vertices)
    auto_rec, _, _ = run(pg, "native")
    assert auto_rec.init == "chordal" and auto_rec.iterations < file_rec.iterations
    assert auto_rec.final_error <= file_rec.final_error * (1 + 1e-6)


# ---------------------------------------------------------------------- CLI

def write_graph(tmp_path, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> str:
    path = str(tmp_path / "g.g2o")
    gtsam.writeG2o(graph, values, path)
    return path


def test_cli_init_choices_are_the_librarys():
    from lie_factors import solve
    from lie_factors.app import cli, posegraph

    assert cli.INIT_METHODS == solve.INIT_METHODS == I.METHODS
    assert set(posegraph.INIT_DESCRIPTIONS) == set(I.METHODS) - {"auto"}
    assert set(posegraph.ENGINE_NOTES) == set(I.ENGINES)


def test_cli_auto_names_the_start_and_why_lago_was_skipped(tmp_path, capsys):
    graph, truth = pose2_loop(noise=0.03, full_cov=True, seed=5)
    path = write_graph(tmp_path, graph, truth)
    status, out, err = run_main(capsys, "posegraph", path, "--backend", "native", "--json")
    assert status == 0
    rec = last_json(out)
    assert rec["init"] == "chordal" and rec["init_seconds"] > 0
    assert "init lago not applicable: LAGO needs diagonal noise models" in out
    assert "initial guess: chordal relaxation (GTSAM's InitializePose3), GTSAM's own" in out


def test_cli_each_method_runs(tmp_path, capsys):
    graph, truth = pose2_loop(noise=0.03, seed=6)
    path = write_graph(tmp_path, graph, truth)
    finals = {}
    for method in I.METHODS:
        status, out, _ = run_main(capsys, "posegraph", path, "--backend", "native", "--init", method,
                                 "--quiet", "--json")
        assert status == 0
        rec = last_json(out)
        assert rec["init"] == ("lago" if method == "auto" else method)
        finals[method] = rec["final_error"]
    assert max(finals.values()) == pytest.approx(min(finals.values()), rel=1e-6)


def test_cli_method_that_cannot_run_is_one_line(tmp_path, capsys):
    status, out, err = run_main(capsys, "posegraph", str(SMALL), "--init", "lago", "--quiet")
    assert status == 2 and err.count("\n") == 1
    assert err.startswith("lie-factors: error: lago: LAGO is for Pose2 graphs") and "Traceback" not in err
    edges_only = tmp_path / "e.g2o"
    edges_only.write_text("EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n")
    status, out, err = run_main(capsys, "posegraph", str(edges_only), "--init", "file", "--quiet")
    assert status == 2 and err == "lie-factors: error: file: no initial values given (the file has no vertices)\n"
    with pytest.raises(SystemExit) as exc:  # argparse's own usage error, status 2
        run_main(capsys, "posegraph", str(edges_only), "--init", "nope", "--quiet")
    assert exc.value.code == 2 and "invalid choice: 'nope'" in capsys.readouterr().err


def test_auto_with_known_inliers_uses_them_alone():
    graph, truth = pose2_loop(noise=0.03, seed=7)  # 12 odometry edges (a cycle), 4 chords, a prior
    n = graph.size()
    chain = list(range(11)) + [n - 1]  # odometry 0-1 ... 10-11 and the prior: a tree
    start = I.initialize(graph, "auto", truth, inliers=chain)
    assert (start.method, start.inliers_only, start.skipped) == ("spanning-tree", True, [])
    pose = graph.at(n - 1).prior()
    for k in range(11):
        pose = pose.compose(graph.at(k).measured())
        assert np.abs(start.values.atPose2(k + 1).localCoordinates(pose)).max() < 1e-12
    # Inliers with a cycle: the usual relaxation, on them only (the chords are left out).
    cycle = list(range(12)) + [n - 1]
    sub = gtsam.NonlinearFactorGraph()
    for k in cycle:
        sub.add(graph.at(k))
    start = I.initialize(graph, "auto", truth, inliers=cycle)
    assert (start.method, start.inliers_only) == ("lago", True)
    assert max_pose_diff(start.values, I.initialize(sub, "lago").values, False) < 1e-12
    assert max_pose_diff(start.values, I.initialize(graph, "lago").values, False) > 1e-6
    # Named methods use every factor.
    assert not I.initialize(graph, "chordal", truth, inliers=chain).inliers_only


def test_odometry_is_dead_reckoning_from_the_prior():
    """``odometry``: the edges between consecutive keys composed from the prior, the loop closures
    left out (the measurements chained, as the definition says)."""
    pg = read_pose_graph(str(DATA / "intel.g2o")).with_first_prior()
    start = I.initialize(pg, "odometry")
    assert start.method == "odometry"
    X = pg.prior_measured[0]
    np.testing.assert_allclose(start.poses[0], X, atol=0)
    chain = {}
    for k, (i, j) in enumerate(pg.edge_keys.tolist()):
        if j == i + 1:
            chain[i] = pg.measured[k]
    for n in range(1, len(pg.keys)):
        X = X @ chain[n - 1]
        np.testing.assert_allclose(start.poses[n], X, atol=1e-9)
    gap = pg.with_edges(np.flatnonzero(~((pg.edge_keys[:, 0] == 10) & (pg.edge_keys[:, 1] == 11))))
    with pytest.raises(I.InitializationError, match="odometry"):
        I.initialize(gap, "odometry")
