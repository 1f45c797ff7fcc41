"""ATE and RPE against evo's own (``evo_ape -a``/``-as``, ``evo_rpe -d N -u f``) and against an
implementation here that shares no code with the library's (SciPy's Kabsch, GTSAM's Pose3.between)."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import gtsam
import numpy as np
import pytest
from evo.core import metrics, sync
from evo.core.units import Unit
from evo.main_ape import ape
from evo.main_rpe import rpe
from evo.tools import file_interface
from scipy.spatial.transform import Rotation

import lie_factors as lf
from lie_factors.evaluation.trajectory import planar_poses
from support.cli_helpers import last_json, run_main

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "data"
GRAPHS = ["city10000", "manhattan", "sphere2500"]
STATS = ("rmse", "mean", "median", "std", "min", "max")


@pytest.fixture(scope="module")
def estimates(tmp_path_factory):
    """Each graph's default-command optimum, written as TUM (what evo reads)."""
    out = tmp_path_factory.mktemp("estimates")
    files = {}
    for name in GRAPHS:
        path = out / f"{name}.tum"
        lf.write_trajectory(lf.optimize(lf.read_g2o(str(DATA / f"{name}.g2o"))), str(path))
        files[name] = (str(path), str(DATA / "groundtruth" / f"{name}.tum"))
    demo = tmp_path_factory.mktemp("demo")
    assert run_main_quiet(["demo", "--output", str(demo), "--quiet"]) == 0
    est = demo / "optimized.tum"
    lf.write_trajectory(lf.trajectory_of(str(demo / "optimized.g2o")), str(est))
    files["demo"] = (str(est), str(demo / "groundtruth.tum"))
    return files


def run_main_quiet(argv):
    from lie_factors.app import cli

    return cli.main(argv)


def _evo(est_path, ref_path, align, delta):
    ref = file_interface.read_tum_trajectory_file(ref_path)
    est = file_interface.read_tum_trajectory_file(est_path)
    ref, est = sync.associate_trajectories(ref, est)
    flags = dict(align=align != "none", correct_scale=align == "sim3")
    a = ape(copy.deepcopy(ref), copy.deepcopy(est), metrics.PoseRelation.translation_part, **flags)
    r = rpe(copy.deepcopy(ref), copy.deepcopy(est), metrics.PoseRelation.translation_part, delta=delta,
            delta_unit=Unit.frames, **flags)
    return a.stats, r.stats


@pytest.mark.parametrize("align", ["se3", "sim3", "none"])
@pytest.mark.parametrize("name", GRAPHS + ["demo"])
def test_ate_and_rpe_equal_evos(estimates, name, align):
    est, ref = estimates[name]
    for delta in (1, 10):
        ours = lf.evaluate(est, ref, align=align, delta=delta)
        a, r = _evo(est, ref, align, delta)
        for k in STATS:
            assert getattr(ours.ate, k) == pytest.approx(a[k], rel=1e-6, abs=1e-12), (k, "ate")
            assert getattr(ours.rpe, k) == pytest.approx(r[k], rel=1e-6, abs=1e-12), (k, "rpe")


def _independent(est: lf.Trajectory, ref: lf.Trajectory, align: str, delta: int):
    """ATE and RPE written from the definitions with other tools: integer stamps paired by a dict,
    the rotation by SciPy's Kabsch solver, relative poses by GTSAM."""
    at = {int(s): k for k, s in enumerate(ref.stamps)}
    pairs = [(k, at[int(s)]) for k, s in enumerate(est.stamps) if int(s) in at]
    q = np.array([est.poses[i][:3, 3] for i, _ in pairs])
    p = np.array([ref.poses[j][:3, 3] for _, j in pairs])
    if align == "none":
        R, s, t = np.eye(3), 1.0, np.zeros(3)
    else:
        qc, pc = q - q.mean(axis=0), p - p.mean(axis=0)
        rot, _ = Rotation.align_vectors(pc, qc)
        R = rot.as_matrix()
        s = float(np.sum(pc * (qc @ R.T)) / np.sum(qc * qc)) if align == "sim3" else 1.0
        t = p.mean(axis=0) - s * R @ q.mean(axis=0)
    ate = np.linalg.norm(p - (s * q @ R.T + t), axis=1)
    T = gtsam.Pose3(gtsam.Rot3(R), t)
    P = [T.compose(gtsam.Pose3(gtsam.Rot3(est.poses[i][:3, :3]), s * est.poses[i][:3, 3])) for i, _ in pairs]
    Q = [gtsam.Pose3(ref.poses[j]) for _, j in pairs]
    ids = list(range(0, len(pairs), delta))
    rpe_ = [np.linalg.norm(Q[a].between(Q[b]).between(P[a].between(P[b])).translation())
            for a, b in zip(ids, ids[1:])]
    return ate, np.array(rpe_)


@pytest.mark.parametrize("align", ["se3", "sim3", "none"])
@pytest.mark.parametrize("name", ["manhattan", "sphere2500", "demo"])
def test_ate_and_rpe_equal_the_definitions(estimates, name, align):
    est, ref = (lf.read_trajectory(f) for f in estimates[name])
    ours = lf.evaluate(est, ref, align=align, delta=5)
    ate, rpe_ = _independent(est, ref, align, 5)
    np.testing.assert_allclose(np.sort(ours.errors), np.sort(ate), rtol=1e-7, atol=1e-12)
    assert ours.ate.rmse == pytest.approx(np.sqrt(np.mean(ate ** 2)), rel=1e-9)
    assert ours.rpe.rmse == pytest.approx(np.sqrt(np.mean(rpe_ ** 2)), rel=1e-7)
    assert ours.rpe.count == len(rpe_) and ours.rpe.max == pytest.approx(rpe_.max(), rel=1e-7)


def test_association_pairs_nearest_stamps_within_a_hundredth(tmp_path):
    X = np.broadcast_to(np.eye(4), (4, 4, 4)).copy()
    X[:, 0, 3] = [0.0, 1.0, 2.0, 3.0]
    ref = lf.Trajectory([0.0, 1.0, 2.0, 3.0], X)
    est = lf.Trajectory([0.004, 1.02, 2.0], X[:3])
    ev = lf.evaluate(est, ref, align="none")
    np.testing.assert_array_equal(ev.stamps, [0.0, 2.0])  # 1.02 is 0.02 from 1.0: not paired


def test_evaluate_from_the_command_line_nests_ate_and_rpe(estimates, capsys, tmp_path):
    est, ref = estimates["city10000"]
    status, out, _ = run_main(capsys, "evaluate", est, ref, "--align", "sim3", "--delta", "10", "--json",
                              "--plot", str(tmp_path / "e.png"))
    assert status == 0
    d = last_json(out)
    ours = lf.evaluate(est, ref, align="sim3", delta=10)
    assert d["ate"]["rmse"] == ours.ate.rmse and d["rpe"]["max"] == ours.rpe.max and d["align"] == "sim3"
    assert (tmp_path / "e.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert json.loads(json.dumps(d)) == d


def test_posegraph_reports_the_ate_of_the_start_and_of_the_optimum(capsys):
    status, out, _ = run_main(capsys, "posegraph", str(DATA / "manhattan.g2o"), "--groundtruth",
                              str(DATA / "groundtruth" / "manhattan.tum"), "--json", "--quiet")
    assert status == 0
    d = last_json(out)
    pg = lf.read_g2o(str(DATA / "manhattan.g2o"))
    result = lf.optimize(pg)
    truth = str(DATA / "groundtruth" / "manhattan.tum")
    assert d["ate"]["rmse"] == pytest.approx(lf.evaluate(result, truth).ate.rmse, rel=1e-9)
    start = lf.Trajectory(result.keys, planar_poses(result.start_poses))
    assert d["ate_initial"]["rmse"] == pytest.approx(lf.evaluate(start, truth).ate.rmse, rel=1e-9)
    assert d["ate"]["rmse"] < d["ate_initial"]["rmse"]

