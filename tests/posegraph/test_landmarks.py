"""Landmark records: the Cartesian → bearing-range information map (ours in 2-D = GTSAM's in 3-D),
LANDMARK2 factors, writing landmarks back, the CLI's plot and output with landmarks."""

from __future__ import annotations

import math

import gtsam
import numpy as np
import pytest

from lie_factors import g2o
from lie_factors.app import cli
from lie_factors.g2o import read_pose_graph


def _random_info(rng, n):
    A = rng.normal(size=(n, n))
    return A @ A.T + 0.3 * np.eye(n)


def test_3d_information_map_is_gtsams(tmp_path):
    """readG2o's EDGE_SE3_TRACKXYZ noise = Jᵀ Λ J with J = [r·B, u] (lie_factors.g2o.conventions)."""
    rng = np.random.default_rng(7)
    for _ in range(5):
        p = rng.normal(size=3) * 3
        L = _random_info(rng, 3)
        up = " ".join(repr(float(L[i, j])) for i in range(3) for j in range(i, 3))
        path = tmp_path / "t.g2o"
        path.write_text("VERTEX_SE3:QUAT 7 0 0 0 0 0 0 1\nVERTEX_TRACKXYZ 9 1 0 0\n"
                        "PARAMS_SE3OFFSET 0 0 0 0 0 0 0 1\nEDGE_SE3_TRACKXYZ 7 9 0 "
                        + " ".join(repr(float(x)) for x in p) + " " + up + "\n")
        graph, _ = gtsam.readG2o(str(path), True)
        R = graph.at(0).noiseModel().R()
        r = np.linalg.norm(p)
        B = gtsam.Unit3(p).basis()
        J = np.column_stack([r * B[:, 0], r * B[:, 1], p / r])
        np.testing.assert_allclose(R.T @ R, J.T @ L @ J, rtol=1e-10, atol=1e-10 * np.abs(L).max())


def test_2d_information_map_is_the_jacobian_of_polar_coordinates():
    rng = np.random.default_rng(3)
    for _ in range(10):
        p = rng.normal(size=2) * 4
        L = _random_info(rng, 2)
        theta, r = math.atan2(p[1], p[0]), math.hypot(*p)
        # J = ∂p/∂(θ, r) by central differences of p(θ, r) = r (cos θ, sin θ)
        h = 1e-6
        f = lambda t, rr: rr * np.array([math.cos(t), math.sin(t)])  # noqa: E731
        J = np.column_stack([(f(theta + h, r) - f(theta - h, r)) / (2 * h),
                             (f(theta, r + h) - f(theta, r - h)) / (2 * h)])
        np.testing.assert_allclose(g2o.bearing_range_information_2d(p, L), J.T @ L @ J, rtol=1e-7)
        back = g2o.point_information_2d(theta, r, g2o.bearing_range_information_2d(p, L))
        np.testing.assert_allclose(back, L, rtol=1e-12, atol=1e-12 * np.abs(L).max())


def test_landmark2_factor_error_is_the_cartesian_mahalanobis_to_first_order(tmp_path):
    # Near the measurement, ½‖bearing-range residual‖²_Λbr ≈ ½ δpᵀ Λ δp (δp in the pose frame).
    path = tmp_path / "l2.g2o"
    path.write_text("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n"
                    "LANDMARK2 0 5 3 4 10 2 5\n")
    pg = read_pose_graph(str(path))
    f = pg.landmarks.factors.at(0)
    L = np.array([[10.0, 2.0], [2.0, 5.0]])
    for dp in (np.array([1e-4, -2e-4]), np.array([-3e-4, 1e-4])):
        v = gtsam.Values()
        v.insert(0, gtsam.Pose2())
        v.insert(g2o.landmark_key(5), np.array([3.0, 4.0]) + dp)
        assert f.error(v) == pytest.approx(0.5 * dp @ L @ dp, rel=1e-3)


def test_landmark_files_from_gtsam_load_with_the_factors_gtsam_builds():
    pg = read_pose_graph("victoria_park.txt")  # ODOMETRY + LANDMARK: GTSAM builds every factor
    graph, _ = gtsam.readG2o(gtsam.findExampleDataFile("victoria_park.txt"), False)
    assert pg.edge_count + pg.observation_count == graph.size()
    assert isinstance(pg.landmarks.factors.at(0), gtsam.BearingRangeFactor2D)
    pg = read_pose_graph("cityTrees_reduced_1k.g2o")  # LANDMARK2: GTSAM skips them, we do not
    assert pg.observation_count == 406 and pg.landmark_count == 66


def test_cli_plot_and_output_with_landmarks(tmp_path, capsys):
    out, png = tmp_path / "o.g2o", tmp_path / "o.png"
    status = cli.main(["posegraph", "known_landmark_localization_20.g2o", "--backend", "native",
                       "--quiet", "--json", "--output", str(out), "--plot", str(png)])
    assert status == 0
    assert png.read_bytes()[:4] == b"\x89PNG"
    text = out.read_text()
    assert text.count("EDGE_SE3_TRACKXYZ") == 80 and text.count("VERTEX_TRACKXYZ") == 4
    again = read_pose_graph(str(out))
    assert again.observation_count == 80 and again.landmark_count == 4

    out2 = tmp_path / "v.g2o"
    status = cli.main(["posegraph", "victoriaPark_reduced_1k.g2o", "--backend", "native", "--quiet",
                       "--max-iterations", "3", "--output", str(out2), "--plot", str(png)])
    assert status == 0
    text = out2.read_text()
    assert text.count("LANDMARK2") == 606 and text.count("VERTEX_XY") == 48
    assert read_pose_graph(str(out2)).observation_count == 606
