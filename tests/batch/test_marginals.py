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
    # and at the estimate of GTSAM's own optimizer, against gtsam.Marginals on exact Jacobians: how
    # far GTSAM's own dropped term moves its marginals depends on the residuals where its LM stopped
    # (1.0e-7 relative on intel), so GTSAM's factors are no reference to 1e-7 there
    native = lf.optimize(pg, backend="native")
    exact = pg.with_first_prior().factor_graph(ours)
    assert _relative(native.covariances(), _gtsam(exact, native.values, native.keys)) < 1e-7


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


def test_unknown_keys_and_an_undetermined_graph_are_refused(forbid_factorization):
    pg = lf.read_g2o(str(DATA / "intel.g2o"))
    result = lf.optimize(pg)
    with pytest.raises(InputError, match="not a variable"):
        result.covariance(10 ** 9)
    with pytest.raises(InputError, match="integer key"):
        result.covariance("x1")
    # no prior: the gauge is free, decided on the structure, whatever the machine's rounding
    forbid_factorization()
    free = pg.factor_graph()  # GTSAM's BetweenFactorPose2: relative factors GTSAM linearizes
    for graph in (free, pg.factor_graph(ours)):
        with pytest.raises(IndeterminantLinearSystem, match=r"^Marginals: the information matrix is singular: the "
                           r"component of 0 \(1728 variables\) has no prior: its gauge is free$") as info:
            lf.Marginals(graph, result.values)
        assert info.value.variable == 0
    with pytest.raises(IndeterminantLinearSystem, match=r"the component of 0 \(1728 variables\) has no prior"):
        lf.Marginals.of_pose_graph(pg, result.poses)


def _chain(letter: str, count: int, prior: bool, factors=ours):
    """Pose2 poses ``letter``0 … at x = 0, 1, …, joined in a chain by between factors of unit
    information (exact: the poses are where the measurements put them), a unit prior on the first."""
    key = lambda i: gtsam.symbol(letter, i)  # noqa: E731
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    unit = gtsam.noiseModel.Unit.Create(3)
    if prior:
        graph.add(factors.PriorFactorPose2(key(0), gtsam.Pose2(), unit))
    for i in range(count):
        values.insert(key(i), gtsam.Pose2(float(i), 0.0, 0.0))
        if i:
            graph.add(factors.BetweenFactorPose2(key(i - 1), key(i), gtsam.Pose2(1.0, 0.0, 0.0), unit))
    return graph, values


def _joined(*parts):
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    for g, v in parts:
        graph.push_back(g)
        values.insert(v)
    return graph, values


def test_the_free_component_is_named_by_its_first_variable(forbid_factorization):
    graph, values = _joined(_chain("x", 5, prior=True), _chain("y", 4, prior=False))
    forbid_factorization()
    with pytest.raises(IndeterminantLinearSystem,
                       match=r"the component of y0 \(4 variables\) has no prior: its gauge is free") as info:
        lf.Marginals(graph, values)
    assert info.value.variable == 5  # x0 … x4, then y0


def _translation_x(key: int, target: float):
    """A CustomFactor of one row on the Pose3 ``key``: the x of its translation, minus ``target``."""
    def error(this, values, H):
        pose = values.atPose3(key)
        if H is not None:
            H[0] = np.concatenate([np.zeros(3), pose.rotation().matrix()[0]])[None]
        return np.array([pose.translation()[0] - target])

    return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(1), [key], error)


def test_a_variable_with_fewer_rows_than_its_dimension_is_refused(forbid_factorization):
    """x2 (a Pose3, 6 dimensions) is only in a factor of one row: its columns have rank 1 at most.
    A Point3 in a PriorFactorPoint3 has 3 rows for its 3: not refused."""
    X = lambda i: gtsam.symbol("x", i)  # noqa: E731
    unit6 = gtsam.noiseModel.Unit.Create(6)
    graph = gtsam.NonlinearFactorGraph()
    graph.add(ours.PriorFactorPose3(X(0), gtsam.Pose3(), unit6))
    graph.add(ours.BetweenFactorPose3(X(0), X(1), gtsam.Pose3(gtsam.Rot3(), [1.0, 0.0, 0.0]), unit6))
    landmark = gtsam.symbol("l", 0)
    graph.add(gtsam.PriorFactorPoint3(landmark, np.array([1.0, 2.0, 3.0]), gtsam.noiseModel.Unit.Create(3)))
    values = gtsam.Values()
    values.insert(X(0), gtsam.Pose3())
    values.insert(X(1), gtsam.Pose3(gtsam.Rot3(), [1.0, 0.0, 0.0]))
    values.insert(landmark, np.array([1.0, 2.0, 3.0]))
    np.testing.assert_allclose(lf.Marginals(graph, values).marginalCovariance(landmark), np.eye(3), atol=1e-12)
    graph.add(_translation_x(X(2), 2.0))
    values.insert(X(2), gtsam.Pose3(gtsam.Rot3(), [2.0, 0.0, 0.0]))
    result = lf.optimize(graph, values)  # Levenberg–Marquardt: damping makes the system definite
    forbid_factorization()
    message = r"^Marginals: the information matrix is singular: x2 has 1 row of factors for its 6 dimensions"
    with pytest.raises(IndeterminantLinearSystem, match=message) as info:
        lf.Marginals(graph, values)
    assert info.value.variable == 3  # l0, x0, x1, x2 in key order
    with pytest.raises(IndeterminantLinearSystem, match=message):
        result.covariances([X(0), X(1)])


def test_a_key_in_no_factor_is_refused(forbid_factorization):
    graph, values = _chain("x", 3, prior=True)
    values.insert(gtsam.symbol("z", 7), gtsam.Pose2())
    forbid_factorization()
    with pytest.raises(IndeterminantLinearSystem, match="singular: z7 is in no factor: nothing determines it"):
        lf.Marginals(graph, values)


def _point_offset(key1: int, key2: int, offset):
    """A CustomFactor between two Point2: p2 − p1 − offset (a kind the structure does not know)."""
    def error(this, values, H):
        if H is not None:
            H[0], H[1] = -np.eye(2), np.eye(2)
        return values.atPoint2(key2) - values.atPoint2(key1) - offset

    return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(2), [key1, key2], error)


def test_a_component_with_a_factor_of_unknown_kind_is_left_to_the_factorization():
    """The structure decides only components of known factors: one held by a CustomFactor is
    determined (its marginals are GTSAM's) or refused by the pivot rule (an offset between two
    points and nothing else: exactly singular)."""
    graph, values = _chain("x", 4, prior=False)
    anchor = gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(3), [gtsam.symbol("x", 0)],
                                lambda this, v, H: _pose2_prior(v, H))
    graph.add(anchor)
    ref = _gtsam(graph, values, [gtsam.symbol("x", i) for i in range(4)])
    got = lf.Marginals(graph, values).covariances([gtsam.symbol("x", i) for i in range(4)])
    assert _relative(got, ref) < 1e-12
    p, q = gtsam.symbol("p", 0), gtsam.symbol("p", 1)
    points = gtsam.NonlinearFactorGraph()
    points.add(_point_offset(p, q, np.array([1.0, 0.0])))
    at = gtsam.Values()
    at.insert(p, np.array([0.0, 0.0]))
    at.insert(q, np.array([1.0, 0.0]))
    with pytest.raises(RuntimeError, match="Indeterminate linear system"):
        gtsam.Marginals(points, at)
    with pytest.raises(IndeterminantLinearSystem, match=r"singular near variable p[01]: the matrix is not positive"):
        lf.Marginals(points, at)


def _pose2_prior(values, H):
    """The error of a unit prior at the identity on x0, a Pose2 (its Local: x, y, θ at the identity)."""
    pose = values.atPose2(gtsam.symbol("x", 0))
    if H is not None:
        H[0] = np.eye(3)
    return gtsam.Pose2.Logmap(pose)


def _two_poses(w: float, factors=ours):
    """Poses x0 and x1 at the identity, a between factor (identity) of unit information, and a
    prior (identity) of information w·I on x0."""
    X0, X1 = gtsam.symbol("x", 0), gtsam.symbol("x", 1)
    graph = gtsam.NonlinearFactorGraph()
    graph.add(factors.BetweenFactorPose2(X0, X1, gtsam.Pose2(), gtsam.noiseModel.Unit.Create(3)))
    graph.add(factors.PriorFactorPose2(X0, gtsam.Pose2(), gtsam.noiseModel.Gaussian.Information(w * np.eye(3))))
    values = gtsam.Values()
    values.insert(X0, gtsam.Pose2())
    values.insert(X1, gtsam.Pose2())
    return graph, values


@pytest.mark.parametrize("w, refused", [(1e-14, True), (1e-12, False)])
def test_the_pivot_rule_refuses_a_gauge_held_by_a_prior_of_information_1e_14(w, refused, cholmod_way):
    """Two poses at the identity: the between factor's Jacobians are −I and I, the prior's √w·I,
    so each scalar of Λ is [[1 + w, −1], [−1, 1]] (x0, x1).  Eliminating x0 first, x1's pivot is
    1 − 1/(1 + w) of its diagonal entry 1; x1 first, x0's is (1 + w) − 1 of 1 + w: w/(1 + w)
    either way.  Rounding moves that by about 2e-16: w = 1e-14 is 10 times past the threshold
    1e-13, w = 1e-12 10 times inside it, whatever the machine.  The structure does not decide:
    the prior anchors the component."""
    graph, values = _two_poses(w)
    if refused:
        with pytest.raises(IndeterminantLinearSystem, match=r"singular near variable x[01]: the matrix is not "
                                                            r"positive definite to double precision") as info:
            lf.Marginals(graph, values)
        assert info.value.variable in (0, 1)
    else:
        m = lf.Marginals(graph, values)
        # Λ⁻¹ = [[1, 1], [1, 1 + w]]/w per scalar; Λ's condition number 4/w leaves 1e-4 of it
        np.testing.assert_allclose(m.marginalCovariance(gtsam.symbol("x", 0)), np.eye(3) / w, rtol=1e-3)
        np.testing.assert_allclose(m.marginalCovariance(gtsam.symbol("x", 1)), np.eye(3) * (1 + w) / w, rtol=1e-3)


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
