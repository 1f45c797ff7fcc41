"""TUM and KITTI files: what we write, evo and we read back; quaternions against GTSAM's; bad files refused."""

from __future__ import annotations

from pathlib import Path

import gtsam
import numpy as np
import pytest
from evo.tools import file_interface

import lie_factors as lf
from lie_factors.evaluation.trajectory import planar_poses, quaternions, rotations
from support.cli_helpers import assert_one_line_error, run_main

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "data"


def _random_poses(rng, n):
    X = np.broadcast_to(np.eye(4), (n, 4, 4)).copy()
    for k in range(n):
        X[k] = gtsam.Pose3(gtsam.Rot3.Expmap(rng.normal(size=3) * 1.5), rng.normal(size=3) * 10).matrix()
    return X


def test_quaternions_are_gtsams_and_rotations_invert_them():
    rng = np.random.default_rng(1)
    axes = rng.normal(size=(400, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    # every branch of Shepperd's method: small angles, generic, and near π about each axis
    angles = np.concatenate([rng.uniform(0, np.pi, 300), np.full(100, np.pi - 1e-9)])
    angles[:50] = 10.0 ** rng.uniform(-12, -2, 50)
    R = np.array([gtsam.Rot3.AxisAngle(a, t).matrix() for a, t in zip(axes, angles)])
    q = quaternions(R)
    for Rk, qk in zip(R, q):
        g = gtsam.Rot3(Rk).toQuaternion()
        ref = np.array([g.x(), g.y(), g.z(), g.w()])
        ref *= np.sign(ref[3]) if ref[3] != 0 else 1.0
        assert np.allclose(qk, ref, atol=1e-12) or np.allclose(qk, -ref, atol=1e-12)
    np.testing.assert_allclose(rotations(q), R, atol=1e-14)


@pytest.mark.parametrize("suffix", [".tum", ".kitti"])
def test_written_files_read_back_in_evo_and_here(tmp_path, suffix):
    rng = np.random.default_rng(2)
    X = _random_poses(rng, 50)
    stamps = np.arange(50) * 3 + 7
    path = str(tmp_path / f"t{suffix}")
    lf.write_trajectory(lf.Trajectory(stamps, X), path)
    back = lf.read_trajectory(path)
    np.testing.assert_allclose(back.poses, X, atol=1e-12)
    if suffix == ".tum":
        np.testing.assert_array_equal(back.stamps, stamps)
        theirs = file_interface.read_tum_trajectory_file(path)
        np.testing.assert_array_equal(theirs.timestamps, stamps)
    else:
        theirs = file_interface.read_kitti_poses_file(path)
    np.testing.assert_allclose(np.array(theirs.poses_se3), X, atol=1e-12)


def test_a_2d_result_is_written_as_planar_3d_poses(tmp_path):
    pg = lf.read_g2o(str(DATA / "intel.g2o"))
    result = lf.optimize(pg)
    lf.write_trajectory(result, str(tmp_path / "intel.tum"))
    theirs = file_interface.read_tum_trajectory_file(str(tmp_path / "intel.tum"))
    np.testing.assert_array_equal(theirs.timestamps, pg.keys)
    P = np.array(theirs.poses_se3)
    np.testing.assert_allclose(P[:, 2, 3], 0.0, atol=0)
    np.testing.assert_allclose(P[:, :2, :2], result.poses[:, :2, :2], atol=1e-12)
    np.testing.assert_allclose(P[:, :2, 3], result.poses[:, :2, 2], atol=1e-12)


def test_a_sim3_pose_is_written_as_its_rotation_and_its_origin():
    S = gtsam.Similarity3(gtsam.Rot3.Ypr(0.3, -0.2, 0.1), np.array([1.0, 2.0, 3.0]), 2.5)
    P = planar_poses(S.matrix()[None])[0]
    np.testing.assert_allclose(P[:3, :3], S.rotation().matrix(), atol=1e-15)
    np.testing.assert_allclose(P[:3, 3], S.transformFrom(np.zeros(3)), atol=1e-14)


def test_the_command_writes_trajectories_by_extension(tmp_path, capsys):
    for suffix, reader in ((".tum", file_interface.read_tum_trajectory_file),
                           (".kitti", file_interface.read_kitti_poses_file)):
        out = tmp_path / f"out{suffix}"
        status, _, _ = run_main(capsys, "posegraph", str(DATA / "smallGrid3D.g2o"), "--quiet", "--output", str(out))
        assert status == 0
        assert len(reader(str(out)).poses_se3) == 125


@pytest.mark.parametrize("text, fragment", [
    ("0 1 2 3 0 0 0 1\n1 1 2 3 0 0 1\n", "bad.tum:2: expected 8 numbers"),
    ("0 1 2 3 0 0 0 1\n1 1 2 3 0 0 0.5 1\n", "bad.tum:2: the quaternion is not a unit one"),
    ("# only a comment\n", "bad.tum: no pose in the file"),
    ("0 1 2 3 0 0 0 x\n", "bad.tum:1: 'x' is not a number"),
    ("0 1 2 nan 0 0 0 1\n", "bad.tum:1: a value is not finite"),
])
def test_bad_tum_files_are_one_line_errors(tmp_path, capsys, text, fragment):
    bad = tmp_path / "bad.tum"
    bad.write_text(text)
    with pytest.raises(lf.InputError, match=fragment.replace("(", r"\(")):
        lf.read_trajectory(str(bad))
    good = tmp_path / "good.tum"
    good.write_text("0 1 2 3 0 0 0 1\n")
    assert_one_line_error(*run_main(capsys, "evaluate", str(bad), str(good)), fragment)


def test_bad_kitti_rotation_and_unpaired_files_are_refused(tmp_path, capsys):
    bad = tmp_path / "bad.kitti"
    bad.write_text("1 0 0 0 0 1 0 0 0 0 1 0\n2 0 0 0 0 1 0 0 0 0 1 0\n")
    with pytest.raises(lf.InputError, match="bad.kitti:2: the rotation is not orthonormal"):
        lf.read_trajectory(str(bad))
    a, b = tmp_path / "a.tum", tmp_path / "b.tum"
    a.write_text("0 1 2 3 0 0 0 1\n1 1 2 3 0 0 0 1\n")
    b.write_text("5 1 2 3 0 0 0 1\n6 1 2 3 0 0 0 1\n")
    assert_one_line_error(*run_main(capsys, "evaluate", str(a), str(b)), "no stamps in common")
    with pytest.raises(lf.InputError, match="cannot tell the trajectory format"):
        lf.write_trajectory(lf.Trajectory([0.0], np.eye(4)[None]), str(tmp_path / "t.csv"))


def test_a_failed_write_leaves_the_existing_file(tmp_path):
    out = tmp_path / "t.tum"
    out.write_text("previous\n")
    with pytest.raises(lf.InputError):
        lf.write_trajectory(lf.Trajectory([0.0, 1.0], np.eye(4)[None]), str(out))  # poses for one stamp only
    assert out.read_text() == "previous\n"
