"""``lf.optimize(graph, initial, params)`` on GTSAM graphs as GTSAM's examples build them: a result
without pose variables, values of the types they were given, params of each optimizer, graphs
whose error is not a number, and a start GTSAM's optimizer does not move from.

References: GTSAM's own optimizers and ``Marginals`` on the same graphs.
"""

from __future__ import annotations

import re
from pathlib import Path

import gtsam
import numpy as np
import pytest

import lie_factors as lf
from lie_factors.expressions.ready import from_gtsam as ready_factor
from support.example_graphs import spherical_sfm

X, L = gtsam.symbol_shorthand.X, gtsam.symbol_shorthand.L
ROOT = Path(__file__).resolve().parents[2]


def types(values) -> dict:
    """Each key's C++ type, as ``Values`` prints it."""
    return dict(re.findall(r"^Value (\S+): \((.*)\)$", str(values), flags=re.M))


# ---------------------------------------------------------------------------- no pose variable
def test_a_result_without_pose_variables():
    """Cameras and points: ``keys`` every variable, ``group`` None, ``poses`` refused in one line,
    ``covariances()`` every variable's by key, GTSAM's Marginals' at the estimate."""
    graph, initial = spherical_sfm()
    result = lf.optimize(graph, initial)
    assert repr(result).startswith(f"<Result: {initial.size()} variables, no pose, error ")
    assert str(result) == repr(result)
    assert result.group is None
    np.testing.assert_array_equal(result.keys, sorted(initial.keys()))
    with pytest.raises(lf.InputError, match=r"^the estimate holds no Pose2, Pose3, Rot3, Similarity2 or "
                                            r"Similarity3 variable, so it has no poses: read its variables from "
                                            r"result.values \(result.keys lists them\)$"):
        result.poses
    with pytest.raises(lf.InputError, match="no poses"):
        result.start_poses
    covariances = result.covariances()
    assert list(covariances) == sorted(initial.keys())
    marginals = gtsam.Marginals(graph, result.values)
    for key, covariance in covariances.items():
        expected = np.asarray(marginals.marginalCovariance(key))
        assert covariance.shape == expected.shape == ((6, 6) if gtsam.Symbol(key).chr() == ord("x") else (3, 3))
        np.testing.assert_allclose(covariance, expected, rtol=1e-7, atol=1e-9 * np.max(np.abs(expected)))
    np.testing.assert_allclose(result.covariances([L(1), L(2)]), np.stack([covariances[L(1)], covariances[L(2)]]))
    with pytest.raises(lf.InputError, match="dimensions"):
        result.covariances([X(1), L(1)])


def test_write_covariances_refuses_an_estimate_without_poses(tmp_path):
    graph, initial = spherical_sfm()
    with pytest.raises(lf.InputError, match=r"^write_covariances: the estimate holds no pose variable"):
        lf.write_covariances(lf.optimize(graph, initial, max_iterations=1), str(tmp_path / "c.npz"))


# ---------------------------------------------------------------------------- the values' types
def _three_dimensional_landmarks():
    """known_landmark_localization_20.g2o as GTSAM's readG2o gives it (fixed-size Point3
    landmarks), its bearing-range measurements as the ready factors equal to them, a prior on
    the first pose (which fixes the frame)."""
    native, values = gtsam.readG2o(gtsam.findExampleDataFile("known_landmark_localization_20.g2o"), True)
    native.add(gtsam.PriorFactorPose3(0, values.atPose3(0), gtsam.noiseModel.Isotropic.Sigma(6, 0.01)))
    graph = gtsam.NonlinearFactorGraph()
    for k in range(native.size()):
        graph.add(ready_factor(native.at(k)))
    return native, graph, values


def _two_dimensional_landmarks(tmp_path):
    """A 2-D file with VERTEX_XY landmarks (readG2o makes fixed-size Point2) and BR measurements,
    the measurements as the ready BearingRangeFactor2D, a prior on the first pose."""
    path = tmp_path / "planar.g2o"
    path.write_text("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1.1 0.1 0.05\nVERTEX_SE2 2 2.0 -0.1 0.0\n"
                    "VERTEX_XY 0 1.2 1.9\nVERTEX_XY 1 2.1 2.2\n"
                    "EDGE_SE2 0 1 1 0 0 100 0 0 100 0 400\nEDGE_SE2 1 2 1 0 0 100 0 0 100 0 400\n"
                    "BR 0 0 1.107 2.236 0.05 0.1\nBR 1 0 1.571 2.0 0.05 0.1\nBR 1 1 1.107 2.236 0.05 0.1\n"
                    "BR 2 1 1.571 2.0 0.05 0.1\n")
    native, values = gtsam.readG2o(str(path), False)
    native.add(gtsam.PriorFactorPose2(0, gtsam.Pose2(), gtsam.noiseModel.Isotropic.Sigma(3, 0.01)))
    graph = gtsam.NonlinearFactorGraph()
    for k in range(native.size()):
        graph.add(ready_factor(native.at(k)))
    return native, graph, values


@pytest.mark.parametrize("dim", [2, 3])
def test_values_keep_the_types_they_were_given(dim, tmp_path):
    """readG2o's landmarks are fixed-size Point2/Point3 (not the dynamic vectors an array inserted
    from Python makes): after the solve each value is of its type still, at GTSAM's optimum."""
    native, graph, values = _two_dimensional_landmarks(tmp_path) if dim == 2 else _three_dimensional_landmarks()
    given = types(values)
    landmark = "Eigen::Matrix<double, 2, 1, 0, 2, 1>" if dim == 2 else "Eigen::Matrix<double, 3, 1, 0, 3, 1>"
    assert given[gtsam.DefaultKeyFormatter(L(0))] == landmark
    assert any(type(graph.at(k)).__module__ == "lie_factors.expressions.ready" for k in range(graph.size()))
    result = lf.optimize(graph, values)
    assert types(result.values) == given
    # GTSAM's optimizer on the same graph (GTSAM's own BearingRangeFactor3D has the same error but a
    # Jacobian that is not quite its derivative, so its optimum is not quite this one), and on GTSAM's factors
    reference = gtsam.LevenbergMarquardtOptimizer(graph, values).optimize()
    assert result.error == pytest.approx(float(graph.error(reference)), rel=1e-9)
    delta = reference.localCoordinates(result.values)
    assert max(np.max(np.abs(delta.at(k))) for k in values.keys()) < 1e-9
    assert result.error == pytest.approx(float(native.error(gtsam.LevenbergMarquardtOptimizer(native, values)
                                                            .optimize())), rel=1e-6)


def test_dynamic_and_fixed_size_points_in_one_graph():
    """A landmark inserted from Python (a dynamic vector) beside readG2o's fixed-size ones."""
    native, graph, values = _three_dimensional_landmarks()
    mixed = gtsam.Values()
    for key in values.keys():
        if key == L(2):
            mixed.insert(key, np.array(values.atPoint3(key)))  # a dynamic-size vector
        elif gtsam.Symbol(key).chr() == ord("l"):
            mixed.insertPoint3(key, values.atPoint3(key))
        else:
            mixed.insert(key, values.atPose3(key))
    given = types(mixed)
    assert given["l2"] != given["l1"]
    result = lf.optimize(graph, mixed)
    assert types(result.values) == given
    reference = gtsam.LevenbergMarquardtOptimizer(native, values).optimize()
    for key in (L(1), L(2)):
        np.testing.assert_allclose(result.values.atPoint3(key), reference.atPoint3(key), atol=1e-8)


# ---------------------------------------------------------------------------- params
def test_params_of_another_optimizer_are_refused_in_one_line():
    graph, initial = spherical_sfm()
    with pytest.raises(lf.InputError, match=r"^params: expected gtsam.LevenbergMarquardtParams, "
                                            r"gtsam.GaussNewtonParams or gtsam.DoglegParams, got ISAM2Params$"):
        lf.optimize(graph, initial, gtsam.ISAM2Params())


def test_gnc_refuses_dogleg_params():
    with pytest.raises(lf.InputError, match=r"^params: gnc runs Levenberg-Marquardt or Gauss-Newton inside: "
                                            r"expected gtsam.LevenbergMarquardtParams or gtsam.GaussNewtonParams, "
                                            r"got DoglegParams$"):
        lf.optimize(lf.read_g2o(str(ROOT / "data" / "intel.g2o")), params=gtsam.DoglegParams(), gnc="tls")


# ---------------------------------------------------------------------------- errors that are not numbers
def _log_graph(start: float):
    """One scalar x with the residual log(x) − 1 (GTSAM's CustomFactor, exact Jacobian 1/x): a
    Gauss–Newton step from x = 100 lands at x(2 − log x) < 0, where the residual is NaN."""
    def error(this, values, H):
        x = float(values.atVector(this.keys()[0])[0])
        if H is not None:
            H[0] = np.array([[1.0 / x]])
        with np.errstate(invalid="ignore"):
            return np.array([np.log(x) - 1.0])

    graph = gtsam.NonlinearFactorGraph()
    graph.add(gtsam.PriorFactorVector(1, np.array([0.0]), gtsam.noiseModel.Isotropic.Sigma(1, 1e3)))
    graph.add(gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(1), [1], error))
    initial = gtsam.Values()
    initial.insert(1, np.array([start]))
    return graph, initial


@pytest.mark.parametrize("backend", ["batch", "dropin", "native"])
def test_a_start_whose_error_is_not_a_number_is_refused_naming_the_factor(backend):
    graph, initial = _log_graph(-1.0)
    with pytest.raises(lf.InputError, match=r"^the graph's error at the initial values is not a finite number: "
                                            r"factor 1 \(CustomFactor on 1\) has error nan$"):
        lf.optimize(graph, initial, backend=backend)


@pytest.mark.parametrize("backend, when", [("batch", "Gauss-Newton step 1"), ("dropin", "iteration 1"),
                                           ("native", "iteration 1")])
def test_a_gauss_newton_step_to_nan_is_refused_naming_the_factor(backend, when):
    graph, initial = _log_graph(100.0)
    gn = gtsam.GaussNewtonOptimizer(graph, initial, gtsam.GaussNewtonParams())
    gn.iterate()
    assert np.isnan(gn.error())  # GTSAM's Gauss-Newton takes the step, and goes on from NaN
    with pytest.raises(lf.InputError, match=rf"^the graph's error after {when} is not a finite number: "
                                            r"factor 1 \(CustomFactor on 1\) has error nan$"):
        lf.optimize(graph, initial, gtsam.GaussNewtonParams(), backend=backend)


@pytest.mark.parametrize("params", [gtsam.LevenbergMarquardtParams, gtsam.DoglegParams])
def test_levenberg_marquardt_and_dogleg_reject_a_step_to_nan_as_gtsams_do(params):
    graph, initial = _log_graph(100.0)
    cls = gtsam.LevenbergMarquardtOptimizer if params is gtsam.LevenbergMarquardtParams else gtsam.DoglegOptimizer
    reference = cls(graph, initial, params())
    values = reference.optimize()
    result = lf.optimize(graph, initial, params())
    assert np.isfinite(result.error) and result.iterations == reference.iterations()
    assert result.error == pytest.approx(float(graph.error(values)), rel=1e-9)


# ---------------------------------------------------------------------------- a start GTSAM does not leave
def test_a_start_at_most_error_tol_is_returned_as_gtsam_returns_it():
    """GTSAM's test_GaussianFactorGraph: LinearContainerFactors without a linearization point (error
    0 at any values) on keys the (empty) values lack; GTSAM's LM stops before its first iteration
    and its Marginals answer from the linear factors: so do ours."""
    graph = gtsam.GaussianFactorGraph()
    keys = [gtsam.symbol("x", i) for i in range(3)]
    unit = gtsam.noiseModel.Unit.Create(1)
    graph.add(keys[0], np.eye(1), np.zeros(1), unit)
    graph.add(keys[0], -np.eye(1), keys[1], np.eye(1), np.ones(1), unit)
    graph.add(keys[1], -np.eye(1), keys[2], np.eye(1), 2 * np.ones(1), unit)
    nonlinear = gtsam.LinearContainerFactor.ConvertLinearGraph(graph)
    result = lf.optimize(nonlinear, gtsam.Values())
    assert (result.error, result.iterations, result.converged, result.values.size()) == (0.0, 0, True, 0)
    marginals = gtsam.Marginals(nonlinear, gtsam.Values())
    for key in keys:
        np.testing.assert_allclose(result.covariance(key), marginals.marginalCovariance(key), rtol=1e-12)
    with pytest.raises(lf.InputError, match="missing from the initial Values"):
        lf.optimize(nonlinear, gtsam.Values(), max_iterations=3, params=_error_tol(-1.0))


def _error_tol(tol: float):
    p = gtsam.LevenbergMarquardtParams()
    p.setErrorTol(tol)
    return p
