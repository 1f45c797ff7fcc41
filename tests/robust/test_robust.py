"""Robust losses against GTSAM's mEstimators, and robust batch LM against GTSAM's LM with the same noise models."""

from __future__ import annotations

import math

import gtsam
import mpmath
import numpy as np
import pytest

from lie_factors.app import demo
from lie_factors.testing import outliers
from lie_factors import factors as lf
from lie_factors.robust.losses import LOSSES, RobustLoss, from_gtsam, parse_loss
from lie_factors.robust.statistics import chi2_inlier_threshold
from lie_factors.robust.weighted import WeightedLevenbergMarquardt

M = gtsam.noiseModel.mEstimator


def _distances(k: float) -> np.ndarray:
    """Distances straddling every branch point of every loss (k, √k for DCS) and far tails."""
    d = [0.0, 1e-300, 1e-8, 1e3 * k, 1e8]
    for t in (k, math.sqrt(k)):
        d += list(t * (1 + np.array([-1e-9, -1e-15, 0.0, 1e-15, 1e-9, -0.5, 0.5, 1.0])))
    d += list(np.linspace(0.0, 4.0 * max(k, 1.0), 401))
    return np.array(d)


@pytest.mark.parametrize("name", list(LOSSES))
@pytest.mark.parametrize("k", [0.05, 1.0, 1.345, 4.6851, 30.0])
def test_weight_and_loss_equal_gtsam(name, k):
    ours = RobustLoss(name, k)
    theirs = getattr(M, LOSSES[name][1]).Create(k)
    d = _distances(k)
    w, rho = ours.evaluate(d)
    gw = np.array([theirs.weight(float(x)) for x in d])
    grho = np.array([theirs.loss(float(x)) for x in d])
    # Same formulas in the same operation order: equal to the last bit.
    np.testing.assert_array_equal(w, gw)
    np.testing.assert_array_equal(rho, grho)


@pytest.mark.parametrize("name", list(LOSSES))
def test_loss_derivative_is_weight_times_distance(name):
    # ρ'(d) = w(d)·d away from branch points (what IRLS with weight w minimizes).
    L = RobustLoss(name, 1.7)
    d = np.array([0.3, 0.9, 1.2, 2.5, 4.0])
    d = d[np.abs(d - 1.7) > 1e-3]
    h = 1e-6
    num = (L.loss(d + h) - L.loss(d - h)) / (2 * h)
    np.testing.assert_allclose(num, L.weight(d) * d, rtol=1e-6, atol=1e-9)


@pytest.mark.parametrize("name", list(LOSSES))
def test_from_gtsam_reads_the_parameter(name):
    for k in (0.1, 2.0, 123.456789):
        est = getattr(M, LOSSES[name][1]).Create(k)
        assert from_gtsam(est) == RobustLoss(name, k)


def test_from_gtsam_declines_what_is_not_vectorized():
    assert from_gtsam(M.L2WithDeadZone.Create(1.0)) is None
    assert from_gtsam(M.Huber.Create(1.0, M.Base.ReweightScheme.Scalar)) is None


@pytest.mark.parametrize("text, expected", [
    ("huber", RobustLoss("huber", 1.345)), ("cauchy:0.5", RobustLoss("cauchy", 0.5)),
    ("TUKEY:4", RobustLoss("tukey", 4.0)), ("gm", RobustLoss("gm", 1.0)), ("dcs:2e-1", RobustLoss("dcs", 0.2)),
])
def test_parse_loss(text, expected):
    assert parse_loss(text) == expected


@pytest.mark.parametrize("text, fragment", [
    ("hubr", "unknown robust loss"), ("huber:0", "positive"), ("huber:-1", "positive"),
    ("huber:x", "number"), ("cauchy:nan", "positive"), ("tukey:inf", "positive"),
])
def test_parse_loss_rejects(text, fragment):
    with pytest.raises(ValueError, match=fragment):
        parse_loss(text)


@pytest.mark.parametrize("dim", [1, 2, 3, 6, 7])
def test_chi2_threshold_is_gtsams_and_the_quantile(dim):
    th = chi2_inlier_threshold(dim, 0.99)
    # Reference: ½·χ²_dim(0.99) from the regularized incomplete gamma at 40 digits.
    with mpmath.workdps(40):
        y = mpmath.findroot(lambda t: mpmath.gammainc(mpmath.mpf(dim) / 2, 0, t, regularized=True)
                            - mpmath.mpf("0.99"), mpmath.mpf(dim))
    assert abs(th - float(y)) <= 4e-16 * float(y)
    # and exactly the value GTSAM's GncOptimizer uses for a factor of that dimension
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    for j in range(2):
        values.insert(j, np.zeros(dim))
    graph.add(gtsam.BetweenFactorVector(0, 1, np.zeros(dim), gtsam.noiseModel.Unit.Create(dim)))
    assert np.asarray(gtsam.GncLMOptimizer(graph, values, gtsam.GncLMParams())
                      .getInlierCostThresholds())[0] == th


# --------------------------------------------------------------------------- #
# Robust LM: batch vs GTSAM's LM with the same noise models
# --------------------------------------------------------------------------- #

def _se3_problem(n=60, seed=3, fraction=0.3):
    prob = demo.simulate(n, seed=seed)
    between = demo.between_graph(prob)
    n_lc = int(outliers.loop_closure_mask(between).sum())
    graph, planted = outliers.plant_false_loop_closures(between, list(range(n)), max(2, int(fraction * n_lc)),
                                                        seed, True)
    return prob, graph, planted


def _robust_graphs(between, loss, prior_noise):
    native, ours = gtsam.NonlinearFactorGraph(), gtsam.NonlinearFactorGraph()
    est = loss.to_gtsam()
    lc = outliers.loop_closure_mask(between)
    for k in range(between.size()):
        f = between.at(k)
        noise = gtsam.noiseModel.Robust.Create(est, f.noiseModel()) if lc[k] else f.noiseModel()
        i, j = f.keys()
        native.add(gtsam.BetweenFactorPose3(i, j, f.measured(), noise))
        ours.add(lf.BetweenFactorPose3(i, j, f.measured(), noise))
    native.add(gtsam.PriorFactorPose3(0, gtsam.Pose3(), prior_noise))
    ours.add(lf.PriorFactorPose3(0, gtsam.Pose3(), prior_noise))
    return native, ours


@pytest.mark.parametrize("loss", ["huber", "cauchy:1.0", "tukey", "gm", "dcs", "welsch"])
def test_robust_batch_lm_reaches_gtsams_optimum(loss):
    prob, between, _ = _se3_problem()
    native, ours = _robust_graphs(between, parse_loss(loss),
                                  gtsam.noiseModel.Diagonal.Sigmas(demo.PRIOR_SIGMAS))
    params = gtsam.LevenbergMarquardtParams()
    ref_opt = gtsam.LevenbergMarquardtOptimizer(native, prob.initial, params)
    ref = ref_opt.optimize()
    opt = WeightedLevenbergMarquardt(ours, prob.initial, gtsam.LevenbergMarquardtParams())
    assert len(opt.problem.robust) == int(outliers.loop_closure_mask(between).sum())
    assert not opt.problem.native  # every factor vectorized, robust ones included
    # Same error function as GTSAM at the initial values (Σ ρ, not ½Σ‖·‖²).
    assert opt.error() == pytest.approx(native.error(prob.initial), rel=1e-12)
    res = opt.optimize()
    assert res.final_error == pytest.approx(native.error(ref), rel=1e-4)
    assert native.error(res.values) == pytest.approx(res.final_error, rel=1e-12)
    assert res.iterations == pytest.approx(ref_opt.iterations(), abs=2)
    for k in range(len(prob.truth)):
        assert np.max(np.abs(ref.atPose3(k).localCoordinates(res.values.atPose3(k)))) < 1e-4


def test_robust_lm_first_linearization_is_gtsams_reweighted_system():
    # Block reweighting: rows of a robust factor scaled by √w(‖R e‖), b likewise.
    prob, between, _ = _se3_problem(n=40)
    native, ours = _robust_graphs(between, parse_loss("cauchy:0.7"),
                                  gtsam.noiseModel.Diagonal.Sigmas(demo.PRIOR_SIGMAS))
    opt = WeightedLevenbergMarquardt(ours, prob.initial, gtsam.LevenbergMarquardtParams())
    opt._linearize()
    H = opt.system.to_dense()
    lin = native.linearize(prob.initial)
    Aref, bref = lin.jacobian()
    Href = Aref.T @ Aref
    # both in key order: keys 0..n-1, 6 columns each
    np.testing.assert_allclose(H, Href, rtol=1e-9, atol=1e-9 * np.abs(Href).max())
    np.testing.assert_allclose(opt.system.rhs, Aref.T @ bref, rtol=1e-9,
                               atol=1e-9 * np.abs(Aref.T @ bref).max())


def test_plain_batch_lm_leaves_robust_factors_to_gtsam():
    # Only the weighted optimizer applies ρ; the plain one must not treat them as Gaussian.
    from lie_factors.batch import BatchLevenbergMarquardt

    prob, between, _ = _se3_problem(n=40)
    native, ours = _robust_graphs(between, parse_loss("huber"),
                                  gtsam.noiseModel.Diagonal.Sigmas(demo.PRIOR_SIGMAS))
    opt = BatchLevenbergMarquardt(ours, prob.initial)
    assert not opt.problem.robust
    assert len(opt.problem.native) == int(outliers.loop_closure_mask(between).sum())
    assert opt.error() == pytest.approx(native.error(prob.initial), rel=1e-12)


@pytest.mark.parametrize("weighted", [False, True])
def test_initial_error_is_evaluated_once(weighted, monkeypatch):
    # One cost hook: the base __init__ evaluates the objective once, after the
    # subclass's setup, never the plain error first and the robust one after it.
    from lie_factors.batch import BatchLevenbergMarquardt
    from lie_factors.batch.graph import Problem

    prob, between, _ = _se3_problem(n=30)
    native, ours = _robust_graphs(between, parse_loss("cauchy"),
                                  gtsam.noiseModel.Diagonal.Sigmas(demo.PRIOR_SIGMAS))
    calls = []
    error = Problem.error

    def counting(self, *args, **kwargs):
        calls.append(args)
        return error(self, *args, **kwargs)

    monkeypatch.setattr(Problem, "error", counting)
    cls = WeightedLevenbergMarquardt if weighted else BatchLevenbergMarquardt
    opt = cls(ours, prob.initial, gtsam.LevenbergMarquardtParams())
    assert len(calls) == 1
    assert opt.error() == pytest.approx(native.error(prob.initial), rel=1e-12)
    # Each tried step is evaluated once too: one call per λ tried that reached the nonlinear error.
    calls.clear()
    opt.iterate()
    assert 1 <= len(calls) <= opt.inner_iterations
