"""lie_factors.app: g2o checking, loading, graph building, step-wise LM, the run record."""

from __future__ import annotations

import os
from pathlib import Path

import gtsam
import numpy as np
import pytest

from lie_factors.util import atomic
from lie_factors import factors, g2o, lm  # noqa: F401  (factors: the dropin backend)
from lie_factors import backends
from support.runs import run
import lie_factors as lf
from lie_factors.backends import build_graph
from lie_factors.g2o import read_pose_graph
from lie_factors.app.plotting import positions
from lie_factors.errors import InputError

DATA = Path(__file__).resolve().parents[2] / "data"
SMALL = DATA / "smallGrid3D.g2o"

SE2_INFO = "1 0 0 1 0 1"
SE3_INFO = " ".join(
    " ".join(["1"] + ["0"] * (5 - r)) for r in range(6)
)  # identity, upper triangle row-major: 21 values


def write(tmp_path, text: str, name: str = "g.g2o") -> str:
    path = tmp_path / name
    path.write_text(text)
    return str(path)


def chain2d(n: int = 4) -> str:
    lines = [f"VERTEX_SE2 {i} {i} 0 0" for i in range(n)]
    lines += [f"EDGE_SE2 {i} {i + 1} 1 0 0 {SE2_INFO}" for i in range(n - 1)]
    return "\n".join(lines) + "\n"


# ----------------------------------------------------------------- checking

def test_shipped_dataset_checks_clean():
    s = g2o.check_g2o(str(SMALL))
    assert s.is3d and len(s.vertices) == 125 and len(s.edges) == 297


@pytest.mark.parametrize(
    "text, expected",
    [
        ("EDGE_SE3:QUAT 0 1 1 2 3 0 0 0 1 1 1 1\n",
         "g.g2o:1: EDGE_SE3:QUAT expects 30 fields (id1 id2 x y z qx qy qz qw + 21 information "
         "(6×6 upper triangle)), got 12"),
        ("VERTEX_SE2 0 0 0 0\nBOGUS 1 2 3\n", "g.g2o:2: unknown tag 'BOGUS'"),
        ("VERTEX_SE2 0 0 zero 0\n", "g.g2o:1: field 4 ('zero') is not a number"),
        ("VERTEX_SE2 x 0 0 0\n", "g.g2o:1: field 2 ('x') should be an integer id"),
        ("VERTEX_SE2 0 0 0 nan\n", "g.g2o:1: field 5 ('nan') is not finite"),
        ("VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\nVERTEX_SE3:QUAT 1 1 0 0 0 0 0 1\n"
         "EDGE_SE3:QUAT 0 7 1 0 0 0 0 0 1 " + SE3_INFO + "\n",
         "g.g2o:3: edge 0-7 refers to pose 7, which has no vertex"),
        ("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\n", "empty graph (no edges"),
        ("", "empty graph (no vertices and no edges)"),
        ("\n\n", "empty graph"),
        ("EDGE_SE2 0 1 1 0 0 1 0 0 -1 0 1\n", "g.g2o:1: information matrix is not positive definite"),
        ("EDGE_SE2 0 1 1 0 0 1 0 0 0 0 1\n", "not positive definite"),
        ("EDGE_SE2 0 0 1 0 0 " + SE2_INFO + "\n", "g.g2o:1: edge connects vertex 0 to itself"),
        ("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 0 1 0 0\n", "g.g2o:2: vertex 0 already defined on line 1"),
        ("VERTEX_SE2 0 0 0 0\nVERTEX_SE3:QUAT 1 0 0 0 0 0 0 1\n", "g.g2o:2: VERTEX_SE3:QUAT is a 3-D record"),
        ("VERTEX_SE3:QUAT 0 0 0 0 0 0 0 0\n", "g.g2o:1: quaternion qx qy qz qw has norm 0"),
        ("EDGE_SE2 0 1 1 0 0 " + SE2_INFO + "\nEDGE_SE2 2 3 1 0 0 " + SE2_INFO + "\n",
         "graph is not connected: pose 2 cannot be reached from pose 0"),
    ],
)
def test_bad_files_name_line_and_problem(tmp_path, text, expected):
    with pytest.raises(InputError) as info:
        g2o.check_g2o(write(tmp_path, text))
    assert expected in str(info.value)
    assert "\n" not in str(info.value)


def test_missing_file_and_directory(tmp_path):
    with pytest.raises(InputError, match="no such file"):
        g2o.resolve_dataset(str(tmp_path / "absent.g2o"))
    with pytest.raises(InputError, match="not a dataset shipped with GTSAM"):
        g2o.resolve_dataset("surely-not-a-gtsam-dataset.g2o")
    with pytest.raises(InputError, match="is a directory"):
        g2o.resolve_dataset(str(tmp_path))


def test_gtsam_example_name_resolves():
    assert g2o.resolve_dataset("sphere2500.txt").endswith("sphere2500.txt")


# ------------------------------------------------------------------ loading

def test_load_2d_and_comment_lines_survive(tmp_path):
    # gtsam.readG2o drops every edge after a '#' line; read_pose_graph() must not.
    pg = read_pose_graph(write(tmp_path, "# a comment\n" + chain2d(5)))
    assert not pg.is3d and pg.pose_count == 5 and pg.edge_count == 4 and int(pg.keys[0]) == 0


def test_edge_only_file_initialized_by_spanning_tree(tmp_path):
    # Non-chain order on purpose: 0-2, 2-1, 1-3 (BFS has to follow the tree).
    text = (f"EDGE_SE2 0 2 2 0 0 {SE2_INFO}\n"
            f"EDGE_SE2 2 1 -1 0 0 {SE2_INFO}\n"
            f"EDGE_SE2 3 1 0 1 1.5707963267948966 {SE2_INFO}\n")
    pg = read_pose_graph(write(tmp_path, text))
    assert (pg.vertices is None) and pg.pose_count == 4
    xs = positions(pg.initial, False)
    np.testing.assert_allclose(xs[:3, 0], [0, 1, 2], atol=1e-12)
    # x1 = x3 · Z31 with Z31 = (0, 1, π/2), x1 = (1, 0, 0)  ⇒  x3 = (0, 0, -π/2)
    x3 = pg.initial.atPose2(3)
    np.testing.assert_allclose([x3.x(), x3.y(), x3.theta()], [0, 0, -np.pi / 2], atol=1e-12)


def test_se3_information_reordering_is_gtsams():
    # g2o: [t, R] = diag(100, 100, 100, 25, 25, 25); GTSAM Pose3 tangent [ω, v].
    pg = read_pose_graph(str(SMALL))
    np.testing.assert_allclose(np.diag(pg.information[0]), [25, 25, 25, 100, 100, 100])
    R = build_graph(pg, "native").at(0).noiseModel().R()
    np.testing.assert_allclose(np.diag(R.T @ R), [25, 25, 25, 100, 100, 100])


# ----------------------------------------------------------- optimization

class _Iterations(lf.Events):
    def __init__(self):
        self.seen = []

    def iteration(self, info):
        self.seen.append(info)


def test_stepwise_lm_matches_gtsam_optimize():
    pg = read_pose_graph(str(SMALL))
    graph = build_graph(pg, "native")
    events = _Iterations()
    result = lf.optimize(graph, pg.initial, backend="native", events=events)
    seen = events.seen
    ref = gtsam.LevenbergMarquardtOptimizer(graph, pg.initial, gtsam.LevenbergMarquardtParams())
    values = ref.optimize()
    assert result.iterations == ref.iterations() == len(seen)
    assert result.error == pytest.approx(graph.error(values), rel=1e-12)
    assert result.converged and result.initial_error > result.error
    assert [s.iteration for s in seen] == list(range(1, len(seen) + 1))
    assert "lambda" in lm.format_iteration(seen[0])


def test_max_iterations_respected():
    pg = read_pose_graph(str(SMALL))
    result = lf.optimize(build_graph(pg, "native"), pg.initial, backend="native", max_iterations=2)
    assert result.iterations == 2 and not result.converged
    result = lf.optimize(build_graph(pg, "native"), pg.initial, backend="native", max_iterations=0)
    assert result.iterations == 0 and result.error == result.initial_error


def test_run_record_fields():
    record, result, pg = run(str(SMALL), "native", init="file")
    d = record.to_dict()
    for key in ("backend", "dataset", "poses", "factors", "iterations", "initial_error",
                "final_error", "seconds", "converged", "init", "init_seconds"):
        assert key in d
    assert d["poses"] == 125 and d["factors"] == 298  # 297 edges + the prior
    assert d["final_error"] == pytest.approx(517.9253346774, rel=1e-9)


def test_unknown_backend():
    with pytest.raises(InputError, match="unknown backend 'nope'"):
        backends.factor_namespace("nope")
    with pytest.raises(InputError, match="unknown backend 'nope'"):
        lf.optimize(read_pose_graph(str(SMALL)), backend="nope")


def test_dropin_matches_native_on_shipped_dataset():
    pg = read_pose_graph(str(SMALL))
    native, _, _ = run(pg, "native")
    dropin, _, _ = run(pg, "dropin")
    assert dropin.initial_error == pytest.approx(native.initial_error, rel=1e-9)
    assert dropin.final_error == pytest.approx(native.final_error, rel=1e-6)


def test_dropin_matches_native_2d(tmp_path):
    pg = read_pose_graph(os.path.join(os.path.dirname(__file__), "..", "..", "data", "MIT.g2o"))
    native, _, _ = run(pg, "native")
    dropin, _, _ = run(pg, "dropin")
    assert dropin.final_error == pytest.approx(native.final_error, rel=1e-6)


# ------------------------------------------------------------------ output

def test_write_g2o_roundtrip_and_atomic(tmp_path):
    record, result, pg = run(str(SMALL), "native")
    out = tmp_path / "opt.g2o"
    g2o.write_g2o(str(out), pg.factor_graph(), result.values)
    again = read_pose_graph(str(out))
    assert again.pose_count == 125 and again.edge_count == 297
    graph = build_graph(again, "native")
    # Re-reading the optimum gives (nearly) the optimum error: writeG2o prints ~6 digits.
    assert graph.error(again.initial) == pytest.approx(record.final_error, rel=1e-3)
    assert [p.name for p in tmp_path.iterdir()] == ["opt.g2o"]  # no temporary left


def test_failed_write_leaves_existing_file(tmp_path):
    out = tmp_path / "keep.g2o"
    out.write_text("precious\n")

    def boom(tmp):
        Path(tmp).write_text("half")
        raise RuntimeError("disk full")

    with pytest.raises(RuntimeError):
        atomic.replace_atomically(str(out), boom)
    assert out.read_text() == "precious\n"
    assert [p.name for p in tmp_path.iterdir()] == ["keep.g2o"]


def test_check_writable(tmp_path):
    atomic.check_writable(str(tmp_path / "ok.g2o"))
    with pytest.raises(InputError, match="does not exist"):
        atomic.check_writable(str(tmp_path / "missing" / "x.g2o"))
    with pytest.raises(InputError, match="is a directory"):
        atomic.check_writable(str(tmp_path))


def test_build_graph_shares_equal_noise_models(tmp_path):
    # Edges 0-1, 1-2, 2-3 share one information matrix, 0-2 and 1-3 another:
    # readG2o makes five noise model objects, build_graph two (per backend),
    # each equal to what GTSAM read for its edges.
    a = "1 0 0 1 0 1"
    b = "4 0.5 0 3 0 2"
    text = ("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nVERTEX_SE2 2 2 0 0\nVERTEX_SE2 3 3 0 0\n"
            f"EDGE_SE2 0 1 1 0 0 {a}\nEDGE_SE2 1 2 1 0 0 {a}\nEDGE_SE2 2 3 1 0 0 {a}\n"
            f"EDGE_SE2 0 2 2 0 0 {b}\nEDGE_SE2 1 3 2 0 0 {b}\n")
    path = write(tmp_path, text)
    pg = read_pose_graph(path)
    read, _ = gtsam.readG2o(path, False)
    for backend in ("native", "dropin", "batch"):
        graph = build_graph(pg, backend)
        noises = [graph.at(k).noiseModel() for k in range(pg.edge_count)]
        assert len({id(n) for n in noises}) == 2
        for k, n in enumerate(noises):
            np.testing.assert_array_equal(n.R(), read.at(k).noiseModel().R())
    # The loop closures' Robust wrappers are shared the same way, the odometry stays Gaussian.
    from lie_factors.robust.losses import RobustLoss

    graph = build_graph(pg, "dropin", robust=RobustLoss("huber", 1.345))
    noises = [graph.at(k).noiseModel() for k in range(pg.edge_count)]
    assert all(isinstance(n, gtsam.noiseModel.Robust) for n in noises[3:])
    assert not any(isinstance(n, gtsam.noiseModel.Robust) for n in noises[:3])
    assert noises[3] is noises[4]
    np.testing.assert_array_equal(noises[3].noise().R(), read.at(3).noiseModel().R())
