"""g2o's Sim(3) records (VERTEX_SIM3:EXPMAP / EDGE_SIM3:EXPMAP): conversion, checking,
reading, writing, and `lie-factors posegraph` on them.

The conversion is tested against g2o's own definition, independently of GTSAM's
convention: g2o's Sim3 of the 7 numbers [ω, υ, σ] is the matrix exponential of
[[ω× + σI, υ], [0, 0]] (acting as p ↦ s·R·p + t), computed at 50 digits, and the
file's vertex is the camera→world transform, its edge the inverse of g2o's
measurement S_ji.
"""

from __future__ import annotations

import json

import gtsam
import numpy as np
import pytest

from lie_factors.app import cli, demo_sim3
from lie_factors import g2o
from support.runs import run
from lie_factors.g2o import read_pose_graph
from lie_factors.testing import reference as ref

SIM3_INFO = " ".join(" ".join(["4"] + ["0"] * (6 - r)) for r in range(7))  # 4·I, 28 values


def g2o_sim3_reference(v) -> np.ndarray:
    """g2o's element of the 7-vector v, as the 4×4 matrix [[sR, t], [0, 1]], at 50 digits."""
    w, u, sigma = (ref.mp.mpf(float(a)) for a in v[:3]), v[3:6], ref.mp.mpf(float(v[6]))
    w1, w2, w3 = w
    G = ref.mp.matrix([[sigma, -w3, w2, u[0]], [w3, sigma, -w1, u[1]], [-w2, w1, sigma, u[2]], [0, 0, 0, 0]])
    return ref.to_numpy(ref.mp.expm(G))


VECTORS = [
    [0.1, -0.2, 0.3, 1.0, 2.0, -3.0, 0.5],
    [0.0, 0.0, 0.0, 1.0, 2.0, 3.0, 0.0],
    [1e-9, 0.0, 2e-9, 5.0, -1.0, 0.5, 3e-9],  # |σ| < 1e-5: where g2o's own exp drops σ from W
    [0.3, 0.2, -0.1, -4.0, 0.5, 2.0, 3e-6],
    [2.0, -1.5, 1.0, 0.1, 0.2, 0.3, -2.0],  # |ω| ≈ 2.7
    [0.0, 3.1, 0.0, 10.0, 0.0, -10.0, 4.0],  # |ω| near π, large scale
]


@pytest.mark.parametrize("v", VECTORS)
def test_vector_is_gtsam_tangent_of_the_same_similarity(v):
    """similarity3_from_g2o(v) is g2o's Sim3(v) (same map p ↦ s R p + t) and GTSAM's Expmap(v)."""
    X = g2o.similarity3_from_g2o(np.array(v))
    G = g2o_sim3_reference(v)
    s = X.scale()
    assert abs(s - G[3, 3] * np.exp(v[6])) <= 1e-15 * s  # G[3,3] = 1
    sR, t = G[:3, :3], G[:3, 3]
    assert ref.rel_err(s * np.asarray(X.rotation().matrix()), sR) <= 1e-14
    assert ref.rel_err(X.transformFrom(np.zeros(3)), t) <= 1e-14  # camera centre s·t_gtsam = t_g2o
    p = np.array([0.3, -1.2, 2.0])
    assert ref.rel_err(X.transformFrom(p), sR @ p + t) <= 1e-14
    assert ref.rel_err(g2o.similarity3_to_g2o(X), v) <= 1e-14


def test_edge_measurement_is_relative_camera_to_world():
    """EDGE i j v: measured = X_i⁻¹ X_j (GTSAM), i.e. the inverse of g2o's S_ji = S_jw S_iw⁻¹."""
    rng = np.random.default_rng(3)
    vi, vj = rng.normal(size=7), rng.normal(size=7)
    S_iw = np.linalg.inv(g2o_sim3_reference(vi))  # g2o vertex estimates: world→camera
    S_jw = np.linalg.inv(g2o_sim3_reference(vj))
    S_ji = S_jw @ np.linalg.inv(S_iw)
    Xi, Xj = g2o.similarity3_from_g2o(vi), g2o.similarity3_from_g2o(vj)
    Z = Xi.between(Xj)
    # The file stores log(S_ji⁻¹); as a map, S_ji⁻¹ must act like Z.
    p = np.array([1.0, 2.0, -0.5])
    S_inv = np.linalg.inv(S_ji)
    assert ref.rel_err(Z.transformFrom(p), S_inv[:3, :3] @ p + S_inv[:3, 3]) <= 1e-12


def sim3_file(tmp_path, lines, name="s.g2o"):
    path = tmp_path / name
    path.write_text("\n".join(lines) + "\n")
    return str(path)


def test_read_file_written_by_hand(tmp_path):
    v0, v1, e = [0.0] * 7, [0.0, 0.0, 0.1, 1.0, 0.0, 0.0, 0.2], [0.0, 0.0, 0.1, 1.0, 0.0, 0.0, 0.25]
    path = sim3_file(tmp_path, [
        "VERTEX_SIM3:EXPMAP 0 " + " ".join(map(str, v0)) + " 1 1 0 0",
        "VERTEX_SIM3:EXPMAP 1 " + " ".join(map(str, v1)) + " 500 500 320 240",
        "EDGE_SIM3:EXPMAP 0 1 " + " ".join(map(str, e)) + " " + SIM3_INFO,
    ])
    summary = g2o.check_g2o(path)
    assert summary.group == "Similarity3" and summary.is3d
    graph, values = g2o.read_with_gtsam(path, summary)
    assert graph.size() == 1 and values.size() == 2
    f = graph.at(0)
    assert isinstance(f, gtsam.BetweenFactorSimilarity3) and list(f.keys()) == [0, 1]
    assert ref.rel_err(gtsam.Similarity3.Logmap(f.measured()), e) <= 1e-15
    assert ref.rel_err(np.asarray(f.noiseModel().information()), 4 * np.eye(7)) <= 1e-14
    assert ref.rel_err(values.atSimilarity3(1).matrix(), gtsam.Similarity3.Expmap(v1).matrix()) <= 1e-15


@pytest.mark.parametrize(
    "lines, expected",
    [
        (["VERTEX_SIM3:EXPMAP 0 0 0 0 0 0 0 0"],
         "s.g2o:1: VERTEX_SIM3:EXPMAP expects 12 fields (id ω1 ω2 ω3 υ1 υ2 υ3 σ fx fy cx cy), got 8"),
        (["EDGE_SIM3:EXPMAP 0 1 0 0 0 1 0 0 0 " + SIM3_INFO + " 1"],
         "EDGE_SIM3:EXPMAP expects 37 fields (id1 id2 ω1 ω2 ω3 υ1 υ2 υ3 σ + 28 information "
         "(7×7 upper triangle)), got 38"),
        (["EDGE_SIM3:EXPMAP 0 1 0 0 0 1 0 0 800 " + SIM3_INFO], "s.g2o:1: log-scale λ = 800 is out of range"),
        (["EDGE_SIM3:EXPMAP 0 1 0 0 0 1 0 0 0 " + SIM3_INFO.replace("4", "-4", 1)],
         "information matrix is not positive definite"),
        (["VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1", "VERTEX_SIM3:EXPMAP 1 0 0 0 0 0 0 0 1 1 0 0"],
         "s.g2o:2: VERTEX_SIM3:EXPMAP is a Similarity3 record but line 1 made this a Pose3 file"),
        (["VERTEX_SIM3:EXPMAP 1 0 0 0 0 0 0 0 1 1 0 0", "EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1"],
         "s.g2o:2: EDGE_SE2 is a 2-D record"),
    ],
)
def test_bad_sim3_records(tmp_path, lines, expected):
    with pytest.raises(g2o.InputError) as info:
        g2o.check_g2o(sim3_file(tmp_path, lines))
    assert expected in str(info.value)


def test_write_rejects_non_sim3_factor(tmp_path):
    graph = gtsam.NonlinearFactorGraph()
    graph.add(gtsam.BetweenFactorSimilarity3(0, 1, gtsam.Similarity3(), gtsam.noiseModel.Isotropic.Sigma(7, 1.0)))
    graph.add(gtsam.BetweenFactorPose3(1, 2, gtsam.Pose3(), gtsam.noiseModel.Isotropic.Sigma(6, 1.0)))
    values = gtsam.Values()
    for k in range(3):
        values.insert(k, gtsam.Similarity3())
    out = tmp_path / "o.g2o"
    out.write_text("keep me\n")
    with pytest.raises(TypeError, match="BetweenFactorSimilarity3"):
        g2o.write_g2o(str(out), graph, values)
    assert out.read_text() == "keep me\n"  # never clobbered by a failed write


def test_edge_only_file_is_initialized_along_a_spanning_tree(tmp_path):
    e = [0.0, 0.0, 0.2, 1.0, 0.0, 0.0, 0.1]
    path = sim3_file(tmp_path, [f"EDGE_SIM3:EXPMAP {i} {i + 1} " + " ".join(map(str, e)) + " " + SIM3_INFO
                                for i in range(3)])
    pg = read_pose_graph(path)
    assert pg.group == "Similarity3" and (pg.vertices is None) and pg.pose_count == 4
    Z = gtsam.Similarity3.Expmap(e)
    expected = Z.compose(Z).compose(Z)
    assert ref.rel_err(pg.initial.atSimilarity3(3).matrix(), expected.matrix()) <= 1e-14


# ---------------------------------------------- round trip through the demo's file and the CLI

@pytest.fixture(scope="module")
def demo_file(tmp_path_factory):
    out = tmp_path_factory.mktemp("demo")
    status = cli.main(["demo", "--scenario", "sim3", "--poses", "30", "--seed", "2", "--quiet",
                       "--output", str(out)])
    assert status == 0
    return out / "optimized.g2o"


def test_demo_file_round_trip(demo_file, tmp_path):
    """The demo's optimized.g2o reads back as the demo's graph at the optimized values, and
    writing what was read reproduces the file's numbers."""
    problem = demo_sim3.simulate(30, 2)
    between = demo_sim3.between_graph(problem)
    summary = g2o.check_g2o(str(demo_file))
    graph, values = g2o.read_with_gtsam(str(demo_file), summary)
    assert summary.group == "Similarity3" and graph.size() == between.size() and values.size() == 30
    for k in range(graph.size()):
        a, b = graph.at(k), between.at(k)
        assert list(a.keys()) == list(b.keys())
        assert ref.rel_err(a.measured().matrix(), b.measured().matrix()) <= 1e-13
        assert ref.rel_err(np.asarray(a.noiseModel().information()),
                           np.asarray(b.noiseModel().information())) <= 1e-13
    again = tmp_path / "again.g2o"
    g2o.write_g2o(str(again), graph, values)
    first = [line.split() for line in demo_file.read_text().splitlines()]
    second = [line.split() for line in again.read_text().splitlines()]
    assert len(first) == len(second)
    for r1, r2 in zip(first, second):
        n_ids = 1 if r1[0].startswith("VERTEX") else 2
        assert r1[: 1 + n_ids] == r2[: 1 + n_ids]
        x1 = np.array(r1[1 + n_ids:], dtype=float)
        x2 = np.array(r2[1 + n_ids:], dtype=float)
        assert np.max(np.abs(x1 - x2)) <= 1e-12 * max(1.0, np.max(np.abs(x1)))


@pytest.mark.parametrize("backend", ["native", "dropin", "batch"])
def test_posegraph_cli_on_demo_file(demo_file, tmp_path, capsys, backend):
    out = tmp_path / f"{backend}.g2o"
    status = cli.main(["posegraph", str(demo_file), "--backend", backend, "--json", "--quiet",
                       "--output", str(out), "--plot", str(tmp_path / "p.png")])
    stdout = capsys.readouterr().out
    assert status == 0
    rec = json.loads(stdout.strip().splitlines()[-1])
    assert rec["poses"] == 30 and rec["factors"] == 30 - 1 + len(demo_sim3.loop_closure_pairs(30)) + 1
    # Starting at the demo's optimum (with a different prior), the optimizer has little left to do.
    assert rec["final_error"] <= rec["initial_error"]
    text = out.read_text()
    assert text.count("VERTEX_SIM3:EXPMAP") == 30 and text.count("EDGE_SIM3:EXPMAP") == rec["factors"] - 1
    g2o.check_g2o(str(out))


def test_dropin_and_native_reach_the_same_optimum_from_dead_reckoning(tmp_path):
    """A Sim(3) file whose vertices are the drifting dead-reckoned start: posegraph with our
    factors gets at least as low as GTSAM's own (whose Jacobians are inexact)."""
    problem = demo_sim3.simulate(40, 1)
    path = tmp_path / "start.g2o"
    g2o.write_g2o(str(path), demo_sim3.between_graph(problem), problem.initial)
    records = {b: run(str(path), b, 100)[0] for b in ("native", "dropin", "batch")}
    assert records["dropin"].final_error <= records["native"].final_error * (1 + 1e-9)
    assert records["batch"].final_error == pytest.approx(records["dropin"].final_error, rel=1e-9)
    assert records["dropin"].final_error < 1e-2 * records["dropin"].initial_error


def test_initialization_methods_on_a_sim3_file(tmp_path):
    """--init on Similarity3 graphs: auto takes the file's vertices, spanning-tree composes the
    edges, GTSAM's chordal/LAGO initializers (Pose2/Pose3 only) are refused with a reason."""
    problem = demo_sim3.simulate(20, 3)
    path = tmp_path / "start.g2o"
    g2o.write_g2o(str(path), demo_sim3.between_graph(problem), problem.initial)
    record, result, _ = run(str(path), "dropin", 50, init="auto")
    assert record.init == "file"
    assert ref.rel_err(result.start.atSimilarity3(19).matrix(), problem.initial.atSimilarity3(19).matrix()) <= 1e-13
    record, result, _ = run(str(path), "dropin", 50, init="spanning-tree")
    assert record.init == "spanning-tree" and result.start.atSimilarity3(19).scale() > 0
    for method in ("chordal", "lago"):
        with pytest.raises(g2o.InputError, match="Similarity3"):
            run(str(path), "native", 50, init=method)
