"""Marginal covariances from the batch solver's factor (lie_factors.batch.marginals, Result.covariances,
``posegraph --covariances``) against ``gtsam.Marginals`` on the same graph at the same values."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import gtsam
import numpy as np
import pytest

import lie_factors as lf
from lie_factors import factors as ours
from lie_factors.app.plotting import CHI2_2DOF_95, covariance_ellipses
from lie_factors.errors import IndeterminantLinearSystem, InputError
from support.cli_helpers import assert_one_line_error, run_main

DATA = Path(__file__).resolve().parents[2] / "data"


def _relative(ours_: np.ndarray, reference: np.ndarray) -> float:
    """The largest ‖C − C_ref‖_F / ‖C_ref‖_F over the keys."""
    return float(np.max(np.linalg.norm(ours_ - reference, axis=(1, 2)) / np.linalg.norm(reference, axis=(1, 2))))


def _gtsam(graph, values, keys) -> np.ndarray:
    m = gtsam.Marginals(graph, values)
    return np.array([m.marginalCovariance(int(k)) for k in keys])


@pytest.fixture(scope="module", params=["intel", "sphere2500"])
def optimized(request):
    pg = lf.read_g2o(str(DATA / f"{request.param}.g2o"))
    return pg, lf.optimize(pg)


def test_every_pose_equals_gtsams_marginals_on_the_same_factors(optimized):
    pg, result = optimized
    covs = result.covariances()
    assert covs.shape == (pg.pose_count, 3 if pg.group == "Pose2" else 6, 3 if pg.group == "Pose2" else 6)
    graph = pg.with_first_prior().factor_graph(ours)  # exact Jacobians, as the batch solver's
    assert _relative(covs, _gtsam(graph, result.values, result.keys)) < 1e-7


def test_every_pose_equals_gtsams_marginals_on_gtsams_own_factors(optimized):
    # GTSAM's BetweenFactor drops the Jacobian of its Local (unless built with
    # GTSAM_SLOW_BUT_CORRECT_BETWEENFACTOR): its H differs from the exact one by O(‖e‖²)
    pg, result = optimized
    graph = pg.with_first_prior().factor_graph()
    assert _relative(result.covariances(), _gtsam(graph, result.values, result.keys)) < 1e-7
    # and a run with GTSAM's own factors is GTSAM's own linearization, to rounding
    native = lf.optimize(pg, backend="native")
    assert _relative(native.covariances(), _gtsam(graph, native.values, native.keys)) < 1e-9


def _landmark_graph():
    """smallGrid3D with a prior, and four landmarks each seen (bearing and range) from ten poses."""
    pg = lf.read_g2o(str(DATA / "smallGrid3D.g2o")).with_first_prior()
    truth = lf.optimize(pg).values
    graph, values = pg.factor_graph(ours), gtsam.Values(truth)
    rng = np.random.default_rng(7)
    noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([0.01, 0.01, 0.05]))
    landmarks = [gtsam.symbol("l", j) for j in range(4)]
    for j, l in enumerate(landmarks):
        point = truth.atPose3(int(pg.keys[30 * j])).translation() + rng.normal(size=3)
        for k in pg.keys[30 * j:30 * j + 10].tolist():
            pose = truth.atPose3(int(k))
            graph.add(gtsam.BearingRangeFactor3D(int(k), l, pose.bearing(point), pose.range(point) + 0.01, noise))
        values.insert(l, point + rng.normal(scale=0.1, size=3))
    return graph, values, pg.keys, landmarks


def test_a_3d_graph_with_landmarks_equals_gtsams_marginals():
    graph, values, keys, landmarks = _landmark_graph()
    result = lf.optimize(graph, values)
    assert _relative(result.covariances(), _gtsam(graph, result.values, keys)) < 1e-7
    assert _relative(result.covariances(landmarks), _gtsam(graph, result.values, landmarks)) < 1e-7
    assert result.covariance(landmarks[0]).shape == (3, 3)
    m = lf.Marginals(graph, result.values)
    np.testing.assert_allclose(m.marginalInformation(landmarks[1]) @ m.marginalCovariance(landmarks[1]),
                               np.eye(3), atol=1e-9)
    with pytest.raises(InputError, match="dimensions"):
        result.covariances([int(keys[0]), landmarks[0]])


def test_gnc_leaves_the_rejected_closures_out_of_the_covariances():
    pg = lf.read_g2o(str(DATA / "intel.g2o"))
    rng = np.random.default_rng(3)
    bad = rng.choice(pg.pose_count, size=(20, 2), replace=False)
    false = dataclasses.replace(pg, edge_keys=np.concatenate([pg.edge_keys, pg.keys[bad]]),
                                measured=np.concatenate([pg.measured, np.broadcast_to(np.eye(3), (20, 3, 3))]),
                                information=np.concatenate([pg.information, pg.information[:20]]), lines=None)
    result = lf.optimize(false, gnc="tls")
    assert len(result.outliers)
    kept = false.with_edges(np.setdiff1d(np.arange(false.edge_count), result.outliers)).with_first_prior()
    assert _relative(result.covariances(), _gtsam(kept.factor_graph(ours), result.values, result.keys)) < 1e-7


def test_unknown_keys_and_an_undetermined_graph_are_refused():
    pg = lf.read_g2o(str(DATA / "intel.g2o"))
    result = lf.optimize(pg)
    with pytest.raises(InputError, match="not a variable"):
        result.covariance(10 ** 9)
    with pytest.raises(InputError, match="integer key"):
        result.covariance("x1")
    free = pg.factor_graph()  # no prior: the gauge is free
    with pytest.raises(IndeterminantLinearSystem, match="singular"):
        lf.Marginals(free, result.values)


def test_the_command_writes_the_covariances_and_draws_their_ellipses(tmp_path, capsys):
    npz, png = tmp_path / "c.npz", tmp_path / "p.png"
    status, _, _ = run_main(capsys, "posegraph", str(DATA / "intel.g2o"), "--covariances", str(npz), "--plot",
                            str(png), "--quiet")
    assert status == 0 and png.read_bytes()[:4] == b"\x89PNG"
    keys, covs, group = lf.read_covariances(str(npz))
    result = lf.optimize(lf.read_g2o(str(DATA / "intel.g2o")))
    np.testing.assert_array_equal(keys, result.keys)
    assert group == "Pose2" and _relative(covs, result.covariances()) < 1e-12


def test_the_command_refuses_an_unwritable_covariance_file_before_any_work(tmp_path, capsys):
    status, out, err = run_main(capsys, "posegraph", str(DATA / "intel.g2o"), "--covariances",
                                str(tmp_path / "missing" / "c.npz"))
    assert_one_line_error(status, out, err, "c.npz")
    assert "iter" not in out


def test_a_covariance_file_that_is_not_one_is_refused(tmp_path):
    path = tmp_path / "x.npz"
    path.write_text("not numpy")
    with pytest.raises(InputError, match="not a covariance file"):
        lf.read_covariances(str(path))


def test_ellipses_are_the_95_percent_contours_in_the_maps_frame():
    theta = 0.3
    R = np.array([[np.cos(theta), -np.sin(theta)], [np.sin(theta), np.cos(theta)]])
    pose = np.eye(3)
    pose[:2, :2], pose[:2, 2] = R, [5.0, -2.0]
    cov = np.diag([4.0, 1.0, 0.5])
    (outline,) = covariance_ellipses(pose[None], cov[None])
    # every point p on it has (p − t)ᵀ·(R Σ_xy Rᵀ)⁻¹·(p − t) = χ²₂(0.95)
    d = outline - pose[:2, 2]
    S = R @ cov[:2, :2] @ R.T
    np.testing.assert_allclose(np.einsum("ka,ab,kb->k", d, np.linalg.inv(S), d), CHI2_2DOF_95, rtol=1e-12)
    assert np.linalg.norm(d, axis=1).max() == pytest.approx(2.0 * np.sqrt(CHI2_2DOF_95), rel=1e-3)
