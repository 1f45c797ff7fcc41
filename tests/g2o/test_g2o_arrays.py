"""g2o files straight into arrays (lie_factors.g2o.read_arrays), the batch Problem built from
them (Problem.from_pose_graph), and the default command's run on them.

References: ``gtsam.readG2o`` for every record type GTSAM reads (its factors' measured
matrices and noise models' information, its Values), our Sim(3) reader for the Sim(3)
records, and the Problem built from the GTSAM graph of lie_factors factors.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import gtsam
import numpy as np
import pytest

from lie_factors.errors import InputError
from lie_factors import factors, g2o
import lie_factors as lf
from support.runs import run
from lie_factors.backends import build_graph
from lie_factors.g2o import read_pose_graph
from lie_factors.batch import BatchLevenbergMarquardt, Problem
from lie_factors.batch.graph import whitening
from lie_factors.posegraph.graph import PoseGraph

ROOT = Path(__file__).resolve().parents[2]


def _spd(rng, n):
    A = rng.normal(size=(n, n))
    return A @ A.T + n * np.eye(n)


def _upper(M):
    return " ".join(repr(float(x)) for x in M[np.triu_indices(len(M))])


def _nums(v):
    return " ".join(repr(float(x)) for x in v)


def _quat(rng):
    q = rng.normal(size=4)
    return q * rng.choice([0.3, 1.0, 7.0])  # not unit: readG2o normalizes


def _file_2d(rng, n=12, diagonal=False, consistent=False):
    """Every 2-D vertex and edge tag, interleaved; angles beyond ±π; a chain plus loop closures.

    ``consistent``: measurements are the vertices' relative poses with small noise (a graph
    like a robot's, where the relaxations are well conditioned), else random."""
    lines = []
    vtags = ("VERTEX_SE2", "VERTEX2", "VERTEX")
    etags = ("EDGE_SE2", "EDGE2", "EDGE", "ODOMETRY")
    order = rng.permutation(n)
    truth = rng.normal(size=(n, 3)) * [5, 5, 2]
    for k, i in enumerate(order):
        lines.append(f"{vtags[k % 3]} {i} {_nums(truth[i, :2])} {float(truth[i, 2] + 2 * np.pi * (k % 2))!r}")
    pairs = [(i, i + 1) for i in range(n - 1)] + [(0, n - 1), (2, 7), (9, 3)]
    for k, (i, j) in enumerate(pairs):
        if consistent:
            z = gtsam.Pose2(*truth[i]).between(gtsam.Pose2(*truth[j]))
            z = np.array([z.x(), z.y(), z.theta()]) + rng.normal(scale=0.05, size=3)
        else:
            z = np.concatenate([rng.normal(size=2), [rng.uniform(-7, 7)]])
        lines.insert(int(rng.integers(0, len(lines) + 1)),
                     f"{etags[k % 4]} {i} {j} {_nums(z)} "
                     f"{_upper(np.diag(rng.uniform(1, 50, 3)) if diagonal else _spd(rng, 3))}")
    return "\n".join(lines) + "\n"


def _file_3d(rng, n=12, vertices=True):
    """VERTEX_SE3:QUAT and VERTEX3, EDGE_SE3:QUAT and EDGE3, interleaved; non-unit quaternions."""
    lines = []
    if vertices:
        for i in rng.permutation(n):
            if i % 2:
                lines.append(f"VERTEX_SE3:QUAT {i} {_nums(rng.normal(size=3))} {_nums(_quat(rng))}")
            else:
                lines.append(f"VERTEX3 {i} {_nums(rng.normal(size=3))} {_nums(rng.uniform(-4, 4, 3))}")
    pairs = [(i, i + 1) for i in range(n - 1)] + [(0, n - 1), (2, 7), (9, 3), (4, 10)]
    for k, (i, j) in enumerate(pairs):
        if k % 2:
            line = f"EDGE_SE3:QUAT {i} {j} {_nums(rng.normal(size=3))} {_nums(_quat(rng))} "
        else:
            line = f"EDGE3 {i} {j} {_nums(rng.normal(size=3))} {_nums(rng.uniform(-4, 4, 3))} "
        lines.insert(int(rng.integers(0, len(lines) + 1)), line + _upper(_spd(rng, 6)))
    return "\n".join(lines) + "\n"


def _compare_with_readg2o(path, is3d):
    summary = g2o.check_g2o(str(path))
    a = g2o.read_arrays(summary)
    graph, initial = gtsam.readG2o(str(path), is3d)
    assert a.group == ("Pose3" if is3d else "Pose2") and a.is3d == is3d
    assert len(a.measured) == graph.size()
    for k in range(graph.size()):
        f = graph.at(k)
        assert tuple(int(x) for x in f.keys()) == tuple(a.edge_keys[k])
        np.testing.assert_array_equal(a.measured[k], f.measured().matrix())
        info = f.noiseModel().information()
        np.testing.assert_allclose(a.information[k], info, rtol=1e-12, atol=1e-12 * np.abs(info).max())
        # The whitening the batch uses is a square root of GTSAM's information.
        R = whitening(a.information[k])
        np.testing.assert_allclose(R.T @ R, info, rtol=1e-12, atol=1e-12 * np.abs(info).max())
        assert np.allclose(np.tril(R, -1), 0.0)
    return a, initial


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("is3d", [False, True], ids=["2d", "3d"])
def test_records_match_readg2o(tmp_path, is3d, seed):
    path = tmp_path / "g.g2o"
    path.write_text((_file_3d if is3d else _file_2d)(np.random.default_rng(seed)))
    a, initial = _compare_with_readg2o(path, is3d)
    assert list(a.keys) == sorted(initial.keys())
    at = initial.atPose3 if is3d else initial.atPose2
    for n, key in enumerate(a.keys):
        np.testing.assert_array_equal(a.vertices[n], at(int(key)).matrix())


def test_quaternion_rotations_compiled_and_numpy_are_readg2os_bits(tmp_path):
    """Both readings of a quaternion (numpy's, for a small file read without numba, and the
    compiled one) give the rotations readG2o builds, bit for bit, on quaternions far from unit."""
    from lie_factors.g2o.compiled import quaternion_poses
    from lie_factors.g2o.rotations import rot3_quaternion

    rng = np.random.default_rng(5)
    n = 400
    lines = [f"VERTEX_SE3:QUAT {i} {_nums(rng.normal(size=3))} {_nums(_quat(rng) * 10.0 ** rng.integers(-6, 7))}"
             for i in range(n)]
    lines += [f"EDGE_SE3:QUAT {i} {i + 1} 1 0 0 0 0 0 1 {_upper(np.eye(6))}" for i in range(n - 1)]
    path = tmp_path / "q.g2o"
    path.write_text("\n".join(lines) + "\n")
    rows = g2o.check_g2o(str(path)).rows["VERTEX_SE3:QUAT"]
    _, initial = gtsam.readG2o(str(path), True)
    theirs = np.array([initial.atPose3(i).matrix() for i in range(n)])
    np.testing.assert_array_equal(quaternion_poses(rows.values), theirs)
    np.testing.assert_array_equal(rot3_quaternion(rows.values[:, 3:7]), theirs[:, :3, :3])


@pytest.mark.parametrize("is3d", [False, True], ids=["2d", "3d"])
def test_one_information_matrix_for_every_edge_is_shared(tmp_path, is3d):
    """Edges that all state one information matrix share it (a read-only broadcast), with readG2o's
    numbers; the graph runs from it as from separate copies, and a second matrix on one edge
    gives every edge its own again."""
    rng = np.random.default_rng(4)
    tag, dim = ("EDGE_SE3:QUAT", 6) if is3d else ("EDGE_SE2", 3)
    info = _upper(_spd(rng, dim))
    lines = []
    for i in range(6):
        lines.append(f"VERTEX_SE3:QUAT {i} {_nums(rng.normal(size=3))} {_nums(_quat(rng))}" if is3d
                     else f"VERTEX_SE2 {i} {_nums(rng.normal(size=3))}")
    for i, j in [(i, i + 1) for i in range(5)] + [(0, 3), (1, 5)]:
        motion = f"{_nums(rng.normal(size=3))} {_nums(_quat(rng))}" if is3d else _nums(rng.normal(size=3))
        lines.append(f"{tag} {i} {j} {motion} {info}")
    path = tmp_path / "g.g2o"
    path.write_text("\n".join(lines) + "\n")
    a, _ = _compare_with_readg2o(path, is3d)
    assert a.information.strides[0] == 0 and not a.information.flags.writeable
    shared = run(str(path), backend="batch")[0]
    other = read_pose_graph(str(path))
    other.information = np.array(other.information)  # separate copies
    assert run(other, backend="batch")[0].final_error == shared.final_error
    lines[-1] = lines[-1].rsplit(" ", 1)[0] + " 1e4"
    path.write_text("\n".join(lines) + "\n")
    assert g2o.read_arrays(g2o.check_g2o(str(path))).information.strides[0] != 0


def test_edge_only_file(tmp_path):
    path = tmp_path / "g.g2o"
    path.write_text(_file_3d(np.random.default_rng(5), vertices=False))
    a, _ = _compare_with_readg2o(path, True)
    assert a.vertices is None and list(a.keys) == list(range(12))


def test_sim3_records_match_our_reader(tmp_path):
    rng = np.random.default_rng(3)
    lines = []
    for i in range(6):
        lines.append(f"VERTEX_SIM3:EXPMAP {i} {_nums(rng.normal(size=6))} {rng.normal() * 0.3!r} 1 1 0 0")
    for i, j in [(0, 1), (1, 2), (2, 3), (3, 4), (4, 5), (5, 0), (1, 4)]:
        lines.append(f"EDGE_SIM3:EXPMAP {i} {j} {_nums(rng.normal(size=6))} {rng.normal() * 0.3!r} "
                     f"{_upper(_spd(rng, 7))}")
    path = tmp_path / "s.g2o"
    path.write_text("\n".join(lines) + "\n")
    a = g2o.read_arrays(g2o.check_g2o(str(path)))
    graph, initial = g2o.read_sim3_g2o(str(path))
    assert a.group == "Similarity3"
    for k in range(graph.size()):
        f = graph.at(k)
        assert tuple(f.keys()) == tuple(a.edge_keys[k])
        np.testing.assert_allclose(a.measured[k], f.measured().matrix(), rtol=1e-14, atol=1e-14)
        np.testing.assert_allclose(a.information[k], f.noiseModel().information(), rtol=1e-12)
    for n, key in enumerate(a.keys):
        np.testing.assert_allclose(a.vertices[n], initial.atSimilarity3(int(key)).matrix(),
                                   rtol=1e-14, atol=1e-14)


@pytest.mark.parametrize("text", [
    # landmarks: GTSAM's reader (and its BearingRange factors) handles them
    "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nVERTEX_XY 5 1 1\n"
    "EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\nLANDMARK2 0 5 1 1 1 0 1\n",
    # 2-D poses without a vertex line: GTSAM chains them from the odometry
    "VERTEX_SE2 0 0 0 0\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\nEDGE_SE2 1 2 1 0 0 1 0 0 1 0 1\n",
])
def test_files_arrays_do_not_represent_are_read_by_gtsam(tmp_path, text):
    path = tmp_path / "g.g2o"
    path.write_text(text)
    summary = g2o.check_g2o(str(path))
    assert not g2o.arrays_supported(summary)
    with pytest.raises(InputError, match="read_with_gtsam"):
        g2o.read_arrays(summary)
    pg = read_pose_graph(str(path))
    assert pg.edge_count + pg.observation_count == 2


def _factor_problem(pg):
    return Problem(build_graph(pg, "batch"), pg.initial)


@pytest.mark.parametrize("name", ["intel.g2o", "sphere2500.txt"])
def test_problem_from_pose_graph_matches_the_factor_graph(name):
    path = ROOT / "data" / name
    pg = read_pose_graph(str(path) if path.exists() else name)
    arrays = Problem.from_pose_graph(pg.with_first_prior(), pg.start_poses)
    ref = _factor_problem(pg)
    assert arrays.graph_size == ref.graph_size == pg.edge_count + 1
    assert arrays.error() == pytest.approx(ref.error(), rel=1e-12)
    assert arrays.linearize() == pytest.approx(ref.linearize(), rel=1e-12)
    for ga, gr in zip(arrays.groups, ref.groups):
        assert ga.kind == gr.kind
        np.testing.assert_allclose(ga.A1, gr.A1, rtol=1e-10, atol=1e-9 * np.abs(gr.A1).max())
        np.testing.assert_allclose(ga.b, gr.b, rtol=1e-10, atol=1e-9 * np.abs(gr.b).max())
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(5)
    ra = BatchLevenbergMarquardt(arrays, None, params).optimize()
    rr = BatchLevenbergMarquardt(ref.graph, pg.initial, params).optimize()
    assert ra.iterations == rr.iterations
    assert ra.final_error == pytest.approx(rr.final_error, rel=1e-9)
    va, vr = ra.values, rr.values
    for k in list(pg.keys)[:50]:
        get = getattr(va, f"at{pg.group}")
        np.testing.assert_allclose(get(int(k)).matrix(), getattr(vr, f"at{pg.group}")(int(k)).matrix(),
                                   atol=1e-8)


def test_from_pose_graph_refuses_bad_input():
    M = np.eye(3)[None]

    def problem(keys, edge_keys, measured, X):
        return Problem.from_pose_graph(PoseGraph("Pose2", np.array(keys), np.array(edge_keys), measured,
                                                 np.eye(3)[None], None, None), X)

    with pytest.raises(InputError, match="itself"):
        problem([0], [[0, 0]], M, M)
    with pytest.raises(InputError, match="no initial element"):
        problem([0], [[0, 1]], M, M)
    bad = np.eye(3)[None] * 1.01
    with pytest.raises(InputError, match="measured 0: rotation block is not orthonormal"):
        problem([0, 1], [[0, 1]], bad, np.stack([np.eye(3)] * 2))


def test_default_run_builds_no_factor_object(monkeypatch, tmp_path):
    """The default command (batch, plain LM) on a pose graph constructs no lie_factors factor."""
    path = tmp_path / "g.g2o"
    path.write_text(_file_3d(np.random.default_rng(7)))

    def refuse(*args, **kwargs):
        raise AssertionError("a factor object was constructed")

    native, native_result, _ = run(str(path), "native")
    monkeypatch.setattr(factors.BetweenFactor, "__init__", refuse)
    monkeypatch.setattr(factors.PriorFactor, "__init__", refuse)
    pg = lf.read_g2o(str(path))
    result = lf.optimize(pg)
    # No GTSAM graph was read and no Values made of the file: the arrays are the only copy.
    assert pg.landmarks is None and "initial" not in vars(pg) and result._values is None
    assert result.init == native.init == "chordal"
    for k in pg.keys.tolist():  # the array initializer starts where GTSAM's does
        np.testing.assert_allclose(result.start.atPose3(k).matrix(),
                                   native_result.start.atPose3(k).matrix(), rtol=0, atol=1e-9)
    result = lf.optimize(pg)
    lf.write_g2o(result, str(tmp_path / "out.g2o"))
    assert result.factors == native.factors and result.iterations == native.iterations
    assert result.error == pytest.approx(native.final_error, rel=1e-9)
    assert set(result.timings) == {"init", "setup", "iterations"}
    # The Values built from the arrays' estimate (for the output file) have the same error.
    assert build_graph(pg, "native").error(result.values) == pytest.approx(result.error, rel=1e-12)
    assert read_pose_graph(str(tmp_path / "out.g2o")).pose_count == pg.pose_count


class _Start(lf.Events):
    """Keeps the initialization a run started from."""

    def started(self, start):
        self.start = start


@pytest.mark.parametrize("diagonal", [True, False])
def test_2d_array_initialization_matches_gtsams(tmp_path, diagonal):
    """auto in 2-D: LAGO (diagonal information) or, with the same reason as GTSAM's path, chordal."""
    path = tmp_path / "g.g2o"
    path.write_text(_file_2d(np.random.default_rng(11), n=30, diagonal=diagonal, consistent=True))
    pg = lf.read_g2o(str(path))
    native_start, batch_start = _Start(), _Start()
    native_result = lf.optimize(pg, backend="native", max_iterations=0, events=native_start)
    lf.optimize(pg, max_iterations=0, events=batch_start)
    assert "initial" not in vars(pg)
    assert batch_start.start.method == native_result.init == ("lago" if diagonal else "chordal")
    assert batch_start.start.skipped == native_start.start.skipped
    assert len(batch_start.start.skipped) == (0 if diagonal else 1)
    # 1e-9 relative : to the size of the graph, ~10 here
    scale = max(1.0, max(np.abs(native_result.start.atPose2(k).translation()).max()
                         for k in pg.keys.tolist()))
    for k in pg.keys.tolist():
        d = batch_start.start.values.atPose2(k).localCoordinates(native_result.start.atPose2(k))
        assert np.abs(d).max() < 1e-9 * scale
    # From starts that agree to 1e-9, LM reaches the same optimum.
    done = lf.optimize(pg)
    assert done.error == pytest.approx(run(str(path), "native")[0].final_error, rel=1e-9)


def _modules_after(code: str) -> str:
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300)
    assert p.returncode == 0, p.stderr
    return p.stderr.strip().splitlines()[-1]


def test_native_backend_and_input_check_do_not_import_numba(tmp_path):
    path = tmp_path / "g.g2o"
    path.write_text(_file_3d(np.random.default_rng(8)))
    code = ("import sys\nfrom lie_factors import g2o\nfrom lie_factors.app import cli\n"
            f"g2o.read_arrays(g2o.check_g2o({str(path)!r}))\n"
            "assert 'numba' not in sys.modules\n"
            f"assert cli.main(['posegraph', {str(path)!r}, '--backend', 'native', '--quiet']) == 0\n"
            "print(sorted(m for m in ('numba', 'lie_factors.batch.graph', 'lie_factors.factors')"
            " if m in sys.modules), file=sys.stderr)\n")
    assert _modules_after(code) == "[]"


def test_batch_modules_import_downward_only():
    """batch.graph reads robust noise models with batch.losses, not the optimizer that imports it."""
    code = ("import sys\nimport lie_factors.batch.graph\n"
            "print(sorted(m for m in ('lie_factors.batch.optimizer', 'lie_factors.robust.weighted')"
            " if m in sys.modules), file=sys.stderr)\n")
    assert _modules_after(code) == "[]"


def test_g2o_modules_import_one_way():
    """Inside lie_factors.g2o each module imports only the ones before it in this order (no cycle)."""
    import ast

    order = ["dataset", "records", "strtod", "scan", "parse", "rotations", "compiled", "conventions", "check",
             "read", "load", "write"]
    package = ROOT / "lie_factors" / "g2o"
    assert sorted(p.stem for p in package.glob("*.py")) == sorted(order + ["__init__"])
    for k, name in enumerate(order):
        tree = ast.parse((package / f"{name}.py").read_text(encoding="utf-8"))
        inside = {node.module for node in ast.walk(tree)
                  if isinstance(node, ast.ImportFrom) and node.level == 1}
        assert inside <= set(order[:k]), (name, inside - set(order[:k]))


