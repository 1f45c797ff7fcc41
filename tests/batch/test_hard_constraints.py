"""Hard constraints in the batch solver (``NonlinearEquality``, ``noiseModel.Constrained``) against
GTSAM's own optimizers and Marginals on the same graphs.

GTSAM eliminates a constrained factor by QR, which imposes its rows of σ = 0 exactly, and weighs
those rows by μ in every error (``squaredMahalanobisDistance``): the batch solver pins a variable a
constraint fixes whole and leaves any other constraint to GTSAM's elimination.  References:
GTSAM's Levenberg–Marquardt, Gauss–Newton and dogleg stepped iteration by iteration (error and λ
or Δ after each), GTSAM's ``Marginals``.
"""

from __future__ import annotations

import gtsam
import numpy as np
import pytest

import lie_factors as lf
from lie_factors.batch.optimizer import BatchLevenbergMarquardt
from lie_factors.errors import InputError

X1, X2 = gtsam.symbol("x", 1), gtsam.symbol("x", 2)
L = [gtsam.symbol("l", j) for j in (1, 2, 3)]


def stereo_vo():
    """GTSAM's test_StereoVOExample: x1 held by a NonlinearEqualityPose3, x2 and three landmarks
    (fixed-size Point3, as GTSAM's Point3 constructor makes them) from six stereo measurements."""
    graph = gtsam.NonlinearFactorGraph()
    graph.add(gtsam.NonlinearEqualityPose3(X1, gtsam.Pose3()))
    K = gtsam.Cal3_S2Stereo(1000, 1000, 0, 320, 240, 0.2)
    model = gtsam.noiseModel.Diagonal.Sigmas(np.array([1.0, 1.0, 1.0]))
    seen = {X1: [(520, 480, 440), (120, 80, 440), (320, 280, 140)],
            X2: [(570, 520, 490), (70, 20, 490), (320, 270, 115)]}
    for x, measured in seen.items():
        for l, m in zip(L, measured):
            graph.add(gtsam.GenericStereoFactor3D(gtsam.StereoPoint2(*m), model, x, l, K))
    values = gtsam.Values()
    values.insert(X1, gtsam.Pose3())
    values.insert(X2, gtsam.Pose3(gtsam.Rot3(), gtsam.Point3(0.1, -0.1, 1.1)))
    for l, p in zip(L, ([1, 1, 5], [-1, 1, 5], [0, -0.5, 5])):
        values.insertPoint3(l, np.array(p, dtype=float))
    return graph, values


def with_factor(graph, factor):
    out = gtsam.NonlinearFactorGraph()
    out.push_back(graph)
    out.add(factor)
    return out


def partly_constrained():
    """A prior on l1 constraining its x exactly (σ = 0) and its y, z softly, away from the start."""
    graph, values = stereo_vo()
    model = gtsam.noiseModel.Diagonal.Sigmas(np.array([0.0, 1.0, 1.0]))
    assert isinstance(model, gtsam.noiseModel.Constrained)
    return with_factor(graph, gtsam.PriorFactorPoint3(L[0], np.array([1.1, 1.05, 5.2]), model)), values


def constrained_between():
    """x1 → x2 held exactly by a between factor with a Constrained.All model (a constraint on two variables)."""
    graph, values = stereo_vo()
    factor = gtsam.BetweenFactorPose3(X1, X2, gtsam.Pose3(gtsam.Rot3(), np.array([0.0, 0.0, 1.0])),
                                      gtsam.noiseModel.Constrained.All(6))
    return with_factor(graph, factor), values


def far_constrained_prior():
    """A Pose3 held by a Constrained.All prior far from the start (its rows weigh μ = 1000 in the
    error), pulled by a soft prior at the identity."""
    x = gtsam.symbol("x", 0)
    graph = gtsam.NonlinearFactorGraph()
    graph.add(gtsam.PriorFactorPose3(x, gtsam.Pose3(gtsam.Rot3.Rodrigues(0.3, 0.2, 0.1), np.array([1.0, 2, 3])),
                                     gtsam.noiseModel.Constrained.All(6)))
    graph.add(gtsam.PriorFactorPose3(x, gtsam.Pose3(), gtsam.noiseModel.Isotropic.Sigma(6, 0.5)))
    values = gtsam.Values()
    values.insert(x, gtsam.Pose3(gtsam.Rot3.Rodrigues(-1.9, 1.1, 0.4), np.array([0.0, 1, 2])))
    return graph, values


def _state(opt, params):
    """(error, Δ for a dogleg, λ for Levenberg–Marquardt, else 0)."""
    return opt.error(), (opt.getDelta() if isinstance(params, gtsam.DoglegParams) else
                         opt.lambda_() if isinstance(params, gtsam.LevenbergMarquardtParams) else 0.0)


def gtsam_steps(cls, graph, values, params):
    """GTSAM's optimizer stepped as its optimize() steps (defaultOptimize's stopping rule): the
    (error, λ or Δ) before and after each iteration."""
    opt = cls(graph, values, params)
    rows = [_state(opt, params)]
    while opt.iterations() < params.getMaxIterations():
        before = opt.error()
        opt.iterate()
        rows.append(_state(opt, params))
        if gtsam.checkConvergence(params.getRelativeErrorTol(), params.getAbsoluteErrorTol(), params.getErrorTol(),
                                  before, opt.error(), gtsam.NonlinearOptimizerParams.Verbosity.SILENT):
            break
    return rows


def our_steps(graph, values, params, steps: int, linear_solver: str):
    opt = BatchLevenbergMarquardt(graph, values, params, linear_solver=linear_solver)
    rows = [_state(opt, params)]
    for _ in range(steps):
        opt.iterate()
        rows.append(_state(opt, params))
    return rows, opt


def assert_same_steps(ref, ours, initial_error):
    errors_ref, errors_ours = np.array([r[0] for r in ref]), np.array([r[0] for r in ours])
    # 1e-8 relative, errors below 1e-12 of the initial error being rounding (zero-residual graphs)
    np.testing.assert_allclose(errors_ours, errors_ref, rtol=1e-8, atol=1e-12 * initial_error)
    # λ's unfixed update (1 − (2ρ − 1)³) amplifies the rounding of a small decrease: GTSAM's own
    # stereo and Between factors are evaluated by their twin kinds, GTSAM's to rounding
    np.testing.assert_allclose([r[1] for r in ours], [r[1] for r in ref], rtol=1e-6)


def lm(diagonal=False, fixed=True):
    p = gtsam.LevenbergMarquardtParams()
    p.setDiagonalDamping(diagonal)
    p.setUseFixedLambdaFactor(fixed)
    return p


CASES = {"stereo": stereo_vo, "partly": partly_constrained, "between": constrained_between,
         "far prior": far_constrained_prior}
PARAMS = {"LM": (gtsam.LevenbergMarquardtOptimizer, lm), "LM diagonal": (gtsam.LevenbergMarquardtOptimizer,
                                                                         lambda: lm(diagonal=True)),
          "LM unfixed factor": (gtsam.LevenbergMarquardtOptimizer, lambda: lm(fixed=False)),
          "GN": (gtsam.GaussNewtonOptimizer, gtsam.GaussNewtonParams),
          "Dogleg": (gtsam.DoglegOptimizer, gtsam.DoglegParams)}


@pytest.mark.parametrize("method", sorted(PARAMS))
@pytest.mark.parametrize("case", sorted(CASES))
@pytest.mark.parametrize("linear_solver", ["auto", "gtsam"])
def test_iterations_are_gtsams(case, method, linear_solver):
    """Error and λ (or Δ) after every iteration as GTSAM's, until GTSAM's optimize() stops; with
    CHOLMOD (pins) and with GTSAM's elimination (every constraint by QR)."""
    graph, values = CASES[case]()
    cls, params = PARAMS[method]
    ref = gtsam_steps(cls, graph, values, params())
    ours, opt = our_steps(graph, values, params(), len(ref) - 1, linear_solver)
    assert_same_steps(ref, ours, ref[0][0])
    # CHOLMOD where every constraint pins a variable; GTSAM's elimination for the others, and for
    # dogleg, whose points GTSAM takes from the elimination that imposes the constraints
    pins = case in ("stereo", "far prior") and method != "Dogleg"
    assert opt.linear_solver == ("cholmod" if pins and linear_solver == "auto" else "gtsam")


def test_a_pinned_variable_does_not_move_and_the_optimum_is_gtsams():
    graph, values = stereo_vo()
    result = lf.optimize(graph, values)
    reference = gtsam.LevenbergMarquardtOptimizer(graph, values).optimize()
    assert result.values.atPose3(X1).equals(gtsam.Pose3(), 0.0)  # its step is exactly 0
    delta = reference.localCoordinates(result.values)
    assert max(np.max(np.abs(delta.at(k))) for k in reference.keys()) < 1e-9
    assert result.error == pytest.approx(float(graph.error(reference)), rel=1e-6, abs=1e-15)


def test_a_constraint_away_from_the_start_is_met_in_one_step():
    """The pin's step solves A·δ = b: the far prior holds after the first iteration (to rounding)."""
    graph, values = far_constrained_prior()
    opt = BatchLevenbergMarquardt(graph, values)
    opt.iterate()
    x = opt.values().atPose3(gtsam.symbol("x", 0))
    held = graph.at(0).prior()
    assert np.max(np.abs(gtsam.Pose3.Logmap(held.between(x)))) < 1e-6


@pytest.mark.parametrize("linear_solver", ["cholmod", "gtsam"])
def test_a_pose_graph_of_our_factors_held_by_a_nonlinear_equality(linear_solver):
    """smallGrid3D with our BetweenFactorPose3 (the batch solver's arrays) and GTSAM's
    NonlinearEqualityPose3 on its first pose, from a perturbed start: GTSAM's iterations on GTSAM's
    factors, and the first pose exactly where it was."""
    from pathlib import Path

    from lie_factors import factors

    native, initial = gtsam.readG2o(str(Path(__file__).resolve().parents[2] / "data" / "smallGrid3D.g2o"), True)
    ours, theirs = gtsam.NonlinearFactorGraph(), gtsam.NonlinearFactorGraph()
    for k in range(native.size()):
        f = native.at(k)
        ours.add(factors.BetweenFactorPose3(*f.keys(), f.measured(), f.noiseModel()))
        theirs.add(f)
    first = min(initial.keys())
    rng = np.random.default_rng(5)
    start = gtsam.Values()
    for key in initial.keys():
        start.insert(key, initial.atPose3(key) if key == first else initial.atPose3(key).retract(rng.normal(0, 0.1, 6)))
    for graph in (ours, theirs):
        graph.add(gtsam.NonlinearEqualityPose3(first, start.atPose3(first)))
    ref = gtsam_steps(gtsam.LevenbergMarquardtOptimizer, theirs, start, lm())
    mine, opt = our_steps(ours, start, lm(), len(ref) - 1, linear_solver)
    assert_same_steps(ref, mine, ref[0][0])
    assert opt.values().atPose3(first).equals(start.atPose3(first), 0.0)


@pytest.mark.parametrize("case", ["stereo", "between", "partly"])
def test_marginals_are_gtsams(case):
    """A pinned variable's covariance is 0 (GTSAM's), the others conditioned on it; a constraint on
    part of a variable or on two is GTSAM's Marginals' own answer."""
    graph, values = CASES[case]()
    estimate = gtsam.LevenbergMarquardtOptimizer(graph, values).optimize()
    ours, theirs = lf.Marginals(graph, estimate), gtsam.Marginals(graph, estimate)
    for key in (X1, X2, *L):
        expected = np.asarray(theirs.marginalCovariance(key))
        np.testing.assert_allclose(ours.marginalCovariance(key), expected, rtol=1e-8,
                                   atol=1e-10 * np.max(np.abs(expected)))
    if case == "stereo":
        assert not np.any(ours.marginalCovariance(X1))


def test_result_covariances_of_a_constrained_graph():
    graph, values = stereo_vo()
    result = lf.optimize(graph, values)
    covs = result.covariances()
    assert covs.shape == (2, 6, 6) and not np.any(covs[0])
    np.testing.assert_allclose(covs[1], gtsam.Marginals(graph, result.values).marginalCovariance(X2), rtol=1e-8)


@pytest.mark.parametrize("linear_solver", ["cholmod", "pardiso"])
def test_a_partial_constraint_is_refused_by_a_solver_that_cannot_impose_it(linear_solver):
    graph, values = partly_constrained()
    with pytest.raises(InputError, match=r"^linear_solver='\w+': factor 7 \(PriorFactorPoint3\) is a hard "
                                         r"constraint .* use linear_solver='gtsam' \(or 'auto'\)$"):
        lf.optimize(graph, values, linear_solver=linear_solver)


def test_an_infeasible_nonlinear_equality_is_refused_naming_it():
    """GTSAM's NonlinearEquality has error 0·∞ = NaN away from its value, and refuses to linearize
    there; the batch solver refuses the start, naming the factor."""
    graph, values = stereo_vo()
    values.update(X1, gtsam.Pose3(gtsam.Rot3(), np.array([0.0, 0.0, 0.1])))
    with pytest.raises((RuntimeError, ValueError), match="not feasible"):
        gtsam.LevenbergMarquardtOptimizer(graph, values).optimize()
    with pytest.raises(InputError, match=r"^the graph's error at the initial values is not a finite number: "
                                         r"factor 0 \(NonlinearEqualityPose3 on x1\) has error nan$"):
        lf.optimize(graph, values)


def test_the_pins_leave_the_system_as_it_was():
    """``LinearSystem.holding`` restores H's entries after the factorization it serves (LM's linear
    change is computed on H afterwards)."""
    graph, values = stereo_vo()
    opt = BatchLevenbergMarquardt(graph, values)
    opt._linearize()
    system = opt.system
    before, rhs_before = system.data.copy(), system.rhs.copy()
    rhs = system.in_matrix_order(system.rhs)
    with system.holding(system.data, rhs):
        assert not np.array_equal(system.data, before)
    np.testing.assert_array_equal(system.data, before)
    np.testing.assert_array_equal(system.rhs, rhs_before)
