"""The small path of the batch solver (lie_factors.batch.small): the whole solve in one compiled call.

It must be the batch solver's general loop (the same λ schedule on CHOLMOD's factorization, run
from Python) to rounding, and GTSAM's Levenberg–Marquardt in iterations: both are run beside it on
graphs of every group, landmark graphs of factor kinds and graphs that mix them, with the params'
every setting.  The tests count what runs: one compiled call per solve, and nothing of the
Python loop (no kind evaluated from Python, no linear system built).  Bad input is refused as the
general loop refuses it, with the same exception.
"""

from __future__ import annotations

import re

import gtsam
import numpy as np
import pytest

import lie_factors as lf
from lie_factors import batch, factors
from lie_factors.batch import small
from lie_factors.batch.graph import Problem
from lie_factors.batch.kinds import KindGroup
from lie_factors.batch.optimizer import BatchLevenbergMarquardt
from lie_factors.errors import IndeterminantLinearSystem, InputError
from lie_factors.expressions import ready
from lie_factors.robust.weighted import WeightedLevenbergMarquardt

GROUPS = {"Pose3": 6, "Rot3": 3, "Pose2": 3, "Similarity2": 4, "Similarity3": 7}


@lf.factor("Point2", measured="Point2")
def PointPrior2(l, z):
    return l - z


@lf.factor("Point3", measured="Point3")
def PointPrior3(l, z):
    return l - z


def _element(group, rng, scale):
    scales = {"Similarity2": [1, 1, 1, 0.3], "Similarity3": [1, 1, 1, 1, 1, 1, 0.3]}.get(group, 1.0)
    return getattr(gtsam, group).Expmap(scale * rng.normal(size=GROUPS[group]) * np.asarray(scales))


def ring(group, n, seed, closures=((2, 7), (3, 9))):
    """Between factors on a ring with chords, a prior, a noisy start (our factors)."""
    rng = np.random.default_rng(seed)
    d = GROUPS[group]
    truth = [_element(group, rng, 0.8) for _ in range(n)]
    graph, initial = gtsam.NonlinearFactorGraph(), gtsam.Values()
    edges = [(i, i + 1) for i in range(n - 1)] + [(0, n - 1)] + [e for e in closures if e[1] < n]
    Between = getattr(factors, f"BetweenFactor{group}")
    for a, b in edges:
        z = truth[a].between(truth[b]).compose(getattr(gtsam, group).Expmap(rng.normal(scale=0.05, size=d)))
        graph.add(Between(a, b, z, gtsam.noiseModel.Diagonal.Sigmas(rng.uniform(0.05, 0.2, size=d))))
    graph.add(getattr(factors, f"PriorFactor{group}")(0, truth[0], gtsam.noiseModel.Isotropic.Sigma(d, 0.01)))
    for i, t in enumerate(truth):
        initial.insert(i, t.compose(getattr(gtsam, group).Expmap(rng.normal(scale=0.3, size=d))))
    return graph, initial


def planar(seed, poses=6, landmarks=5):
    """Pose2 odometry (ours), bearing-range landmark measurements and a landmark prior (kinds)."""
    rng = np.random.default_rng(seed)
    X, L = gtsam.symbol_shorthand.X, gtsam.symbol_shorthand.L
    graph, initial = gtsam.NonlinearFactorGraph(), gtsam.Values()
    truth = [gtsam.Pose2(2.0 * i, 0.3 * np.sin(i), 0.1 * i) for i in range(poses)]
    points = [np.array([2.0 * j + 1.0, 3.0 + rng.normal()]) for j in range(landmarks)]
    odo = gtsam.noiseModel.Diagonal.Sigmas([0.1, 0.1, 0.05])
    graph.add(factors.PriorFactorPose2(X(0), truth[0], gtsam.noiseModel.Diagonal.Sigmas([0.01, 0.01, 0.005])))
    for i in range(poses - 1):
        graph.add(factors.BetweenFactorPose2(X(i), X(i + 1), truth[i].between(truth[i + 1]), odo))
    br = gtsam.noiseModel.Diagonal.Sigmas([0.05, 0.1])
    for i in range(poses):
        for j in range(landmarks):
            if abs(2.0 * j - 2.0 * i) <= 4.0:
                b = truth[i].bearing(points[j]).theta() + rng.normal(scale=0.02)
                r = truth[i].range(points[j]) + rng.normal(scale=0.05)
                graph.add(ready.BearingRangeFactor2D(X(i), L(j), gtsam.Rot2(b), r, br))
    graph.add(PointPrior2(L(0), points[0], gtsam.noiseModel.Isotropic.Sigma(2, 0.5)))
    for i, t in enumerate(truth):
        initial.insert(X(i), t.retract(rng.normal(scale=0.2, size=3)))
    for j, p in enumerate(points):
        initial.insert(L(j), p + rng.normal(scale=0.3, size=2))
    return graph, initial


def visual(seed, cameras=5, landmarks=8):
    """Cameras on a circle looking at a cloud (projection factors, kinds), a pose prior (ours) and
    a point prior (a kind): every landmark seen by every camera, so that the factor's cameras form
    one dense supernode."""
    rng = np.random.default_rng(seed)
    X, L = gtsam.symbol_shorthand.X, gtsam.symbol_shorthand.L
    K = gtsam.Cal3_S2(50.0, 50.0, 0.0, 50.0, 50.0)
    graph, initial = gtsam.NonlinearFactorGraph(), gtsam.Values()
    points = [rng.normal(scale=2.0, size=3) for _ in range(landmarks)]
    poses = []
    for i in range(cameras):
        a = 2 * np.pi * i / cameras
        eye = gtsam.Point3(15.0 * np.cos(a), 15.0 * np.sin(a), 1.0)
        poses.append(gtsam.PinholeCameraCal3_S2.Lookat(eye, gtsam.Point3(0, 0, 0), gtsam.Point3(0, 0, 1), K).pose())
    pix = gtsam.noiseModel.Isotropic.Sigma(2, 1.0)
    for i, pose in enumerate(poses):
        camera = gtsam.PinholeCameraCal3_S2(pose, K)
        for j, p in enumerate(points):
            z = camera.project(p) + rng.normal(scale=0.5, size=2)
            graph.add(ready.GenericProjectionFactorCal3_S2(z, pix, X(i), L(j), K))
    graph.add(factors.PriorFactorPose3(X(0), poses[0], gtsam.noiseModel.Diagonal.Sigmas([0.1] * 3 + [0.3] * 3)))
    graph.add(PointPrior3(L(0), points[0], gtsam.noiseModel.Isotropic.Sigma(3, 0.1)))
    for i, pose in enumerate(poses):
        initial.insert(X(i), pose.compose(gtsam.Pose3.Expmap(rng.normal(scale=0.05, size=6))))
    for j, p in enumerate(points):
        initial.insert(L(j), p + rng.normal(scale=0.25, size=3))
    return graph, initial


def lm_params(**settings):
    p = gtsam.LevenbergMarquardtParams()
    for name, value in settings.items():
        getattr(p, name)(value)
    return p


def run(graph, initial, params, linear_solver="auto", cls=BatchLevenbergMarquardt, **kwargs):
    opt = cls(graph, initial, params, linear_solver=linear_solver, **kwargs)
    return opt, opt.optimize()


def assert_same_run(a, b, rtol=1e-9):
    assert (a.iterations, a.inner_iterations, a.converged) == (b.iterations, b.inner_iterations, b.converged)
    np.testing.assert_allclose(a.errors, b.errors, rtol=rtol, atol=1e-12 * a.errors[0])
    np.testing.assert_allclose(a.lambdas, b.lambdas, rtol=1e-12)


GRAPHS = {**{f"ring-{g}": (lambda s, g=g: ring(g, 12, s)) for g in GROUPS},
          "planar": planar, "visual": visual, "visual-wide": lambda s: visual(s, cameras=9, landmarks=14)}


@pytest.mark.parametrize("name", sorted(GRAPHS))
@pytest.mark.parametrize("seed", [1, 2])
def test_the_small_path_is_the_general_loop_and_gtsams(name, seed):
    graph, initial = GRAPHS[name](seed)
    params = lm_params()
    opt, res = run(graph, initial, params)
    assert opt.small_refusal is None and res.linear_solver == "small"
    general, ref = run(graph, initial, params, linear_solver="cholmod")
    assert_same_run(res, ref)
    gt = gtsam.LevenbergMarquardtOptimizer(graph, initial, params)
    values = gt.optimize()
    assert res.iterations == gt.iterations()
    assert res.final_error == pytest.approx(graph.error(values), rel=1e-9)
    np.testing.assert_allclose(values.localCoordinates(opt.values()).vector(), 0.0, atol=1e-6)


@pytest.mark.parametrize("settings", [
    dict(setDiagonalDamping=True), dict(setUseFixedLambdaFactor=False), dict(setlambdaInitial=10.0),
    dict(setlambdaUpperBound=1e-3), dict(setRelativeErrorTol=1e-2), dict(setAbsoluteErrorTol=1e3),
    dict(setMaxIterations=1), dict(setMaxIterations=0), dict(setErrorTol=1e9), dict(setlambdaLowerBound=1e-3),
], ids=lambda s: ",".join(f"{k}={v}" for k, v in s.items()))
@pytest.mark.parametrize("name", ["ring-Pose3", "planar", "visual"])
def test_every_setting_of_the_params_is_the_general_loops(name, settings):
    graph, initial = GRAPHS[name](3)
    params = lm_params(**settings)
    opt, res = run(graph, initial, params)
    assert res.linear_solver == "small"
    _, ref = run(graph, initial, params, linear_solver="cholmod")
    assert_same_run(res, ref)


@pytest.mark.parametrize("name", ["ring-Pose2", "ring-Similarity3", "planar", "visual"])
def test_gauss_newton_is_the_general_loops(name):
    graph, initial = GRAPHS[name](4)
    params = gtsam.GaussNewtonParams()
    opt, res = run(graph, initial, params)
    assert res.linear_solver == "small"
    _, ref = run(graph, initial, params, linear_solver="cholmod")
    assert (res.iterations, res.converged) == (ref.iterations, ref.converged)
    np.testing.assert_allclose(res.errors, ref.errors, rtol=1e-9)


class _Counted:
    def __init__(self, fn):
        self.fn, self.calls = fn, 0

    def __call__(self, *args):
        self.calls += 1
        return self.fn(*args)


def _refuse(*args, **kwargs):
    raise AssertionError("the small path ran Python's loop")


def test_one_compiled_call_per_solve_and_no_python_loop(monkeypatch):
    from lie_factors.sparse import cholmod

    graph, initial = visual(5)
    counted = _Counted(small._solve)
    monkeypatch.setattr(small, "_solve", counted)
    monkeypatch.setattr(cholmod, "order_blocks", _refuse)  # the order is the call's own
    opt = BatchLevenbergMarquardt(graph, initial)
    for name in ("linearize", "evaluate"):
        monkeypatch.setattr(KindGroup, name, _refuse)
    for name in ("linearize", "linearize_kinds", "linearize_native", "retract"):
        monkeypatch.setattr(Problem, name, _refuse)
    monkeypatch.setattr(BatchLevenbergMarquardt, "_linear", _refuse)
    res = opt.optimize()
    assert res.iterations > 2 and counted.calls == 1


def test_what_the_small_path_refuses_runs_the_general_loop():
    graph, initial = planar(6)
    for params, why in [(lm_params(setVerbosityLM="SUMMARY"), "print"), (lm_params(setVerbosity="ERROR"), "print"),
                        (gtsam.DoglegParams(), "DoglegParams")]:
        opt = BatchLevenbergMarquardt(graph, initial, params)
        assert why in opt.small_refusal
    native = gtsam.NonlinearFactorGraph(graph)
    native.add(gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(2), [gtsam.symbol_shorthand.L(1)],
                                  lambda this, values, H: values.atVector(this.keys()[0])))
    assert "GTSAM linearizes" in BatchLevenbergMarquardt(native, initial).small_refusal
    assert "linear_solver" in BatchLevenbergMarquardt(graph, initial, linear_solver="cholmod").small_refusal
    big, start = ring("Pose3", small.MAX_UNKNOWNS // 6 + 1, 1)
    assert "unknowns" in BatchLevenbergMarquardt(big, start).small_refusal
    K = gtsam.Cal3_S2(50.0, 50.0, 0.0, 50.0, 50.0)
    g3, v3 = visual(7)
    g3.add(ready.GenericProjectionFactorCal3_S2(np.zeros(2), gtsam.noiseModel.Unit.Create(2), gtsam.symbol_shorthand.X(0),
                                                gtsam.symbol_shorthand.L(0), K, True, False))
    assert "behind the camera" in BatchLevenbergMarquardt(g3, v3).small_refusal


def _perturbed(name, seed, scale):
    """GRAPHS[name] with its initial values moved far (LM's first steps fail)."""
    graph, initial = GRAPHS[name](seed)
    rng = np.random.default_rng(seed)
    moved = gtsam.Values()
    for k in initial.keys():
        if initial.exists(k) and gtsam.Symbol(k).chr() == ord("x"):
            moved.insert(k, initial.atPose2(k).retract(rng.normal(scale=scale, size=3)))
        else:
            x = initial.atVector(k)
            moved.insert(k, x + rng.normal(scale=2 * scale, size=x.shape))
    return graph, moved


def _printed(capsys, monkeypatch, graph, initial, params, linear_solver):
    from lie_factors import lm

    monkeypatch.setattr(lm.COUT, "precision", 6)  # (std::cout's precision carries from print to print)
    capsys.readouterr()
    opt, res = run(graph, initial, params, linear_solver)
    return opt, res, capsys.readouterr().out


@pytest.mark.parametrize("case", ["converged", "maximum", "none allowed", "converged at start", "gave up",
                                  "gauss-newton"])
def test_termination_prints_on_the_small_path_are_the_general_loops(case, capsys, monkeypatch):
    """Verbosity TERMINATION takes the small path; what it prints after the compiled loop is what
    the general loop prints as it goes (GTSAM's lines: the last convergence test, LM's warning
    when it gives up at the maximum λ, the iteration count)."""
    graph, initial = planar(9)
    settings = {"maximum": dict(setMaxIterations=1), "none allowed": dict(setMaxIterations=0),
                "converged at start": dict(setErrorTol=1e9),
                "gave up": dict(setlambdaUpperBound=1e-3, setlambdaInitial=1e-4)}
    if case == "gave up":  # (LM's steps fail from far: a failure takes λ to its bound)
        graph, initial = _perturbed("planar", 5, 2.5)
    params = gtsam.GaussNewtonParams() if case == "gauss-newton" else lm_params(**settings.get(case, {}))
    params.setVerbosity("TERMINATION")
    opt, res, text = _printed(capsys, monkeypatch, graph, initial, params, "auto")
    assert opt.small_refusal is None and res.linear_solver == "small"
    _, ref, expected = _printed(capsys, monkeypatch, graph, initial, params, "cholmod")
    assert (res.iterations, res.converged) == (ref.iterations, ref.converged)
    assert opt._small.gave_up == (case == "gave up")
    expected_lines = {"converged": ["converged", "errorThreshold", "absoluteDecrease", "relativeDecrease",
                                    "iterations"],
                      "maximum": ["iterations", "Terminating"], "none allowed": ["iterations"],
                      "converged at start": [],
                      "gave up": ["Warning", "converged", "errorThreshold", "absoluteDecrease",
                                  "relativeDecrease", "iterations"]}
    lines, ref_lines = text.splitlines(), expected.splitlines()
    assert [line.split()[0].rstrip(":") for line in ref_lines] == expected_lines.get(case, expected_lines["converged"])
    assert len(lines) == len(ref_lines)
    number = re.compile(r"[-+]?(?:\d+\.\d*|\.\d+|\d+)(?:[eE][-+]?\d+)?")
    for line, ref_line in zip(lines, ref_lines):
        assert number.sub("#", line) == number.sub("#", ref_line)
        a, b = (np.array([float(x) for x in number.findall(t)]) for t in (line, ref_line))
        np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-12 * res.errors[0])


def _nan_start():
    graph, initial = planar(8)
    initial.update(gtsam.symbol_shorthand.L(2), np.array([np.nan, 1.0]))
    return graph, initial


def _free_landmark():
    graph, initial = planar(9)
    initial.insert(gtsam.symbol_shorthand.L(99), np.zeros(2))
    graph.add(ready.RangeFactor2D(gtsam.symbol_shorthand.X(0), gtsam.symbol_shorthand.L(99), 3.0,
                                  gtsam.noiseModel.Unit.Create(1)))
    return graph, initial


@pytest.mark.parametrize("case, params, error", [
    (_nan_start, lm_params(), InputError),
    (_free_landmark, gtsam.GaussNewtonParams(), IndeterminantLinearSystem),
])
def test_bad_input_is_refused_as_the_general_loop_refuses_it(case, params, error):
    graph, initial = case()
    messages = []
    for linear_solver in ("auto", "cholmod"):
        with pytest.raises(error) as info:
            BatchLevenbergMarquardt(graph, initial, params, linear_solver=linear_solver).optimize()
        messages.append(str(info.value))
    assert messages[0] == messages[1]


def test_a_fault_of_a_kind_is_the_general_loops():
    """A kind whose residual divides by a variable that is 0: the kernel's status raises the same
    error, with the same message, from both paths."""

    @lf.factor("Point2", "Vector1", measured="Vector1")
    def ratio(p, s, z):
        return p.dot(p) / s - z

    graph, initial = gtsam.NonlinearFactorGraph(), gtsam.Values()
    graph.add(ratio(1, 2, np.array([1.0]), gtsam.noiseModel.Unit.Create(1)))
    graph.add(PointPrior2(1, np.array([1.0, 0.0]), gtsam.noiseModel.Unit.Create(2)))
    initial.insert(1, np.array([1.0, 0.0]))
    initial.insert(2, np.array([0.0]))
    messages = []
    for linear_solver in ("auto", "cholmod"):
        with pytest.raises(lf.LieFactorsError) as info:
            BatchLevenbergMarquardt(graph, initial, linear_solver=linear_solver).optimize()
        messages.append((type(info.value), str(info.value)))
    assert messages[0] == messages[1]


def test_robust_losses_and_scales_are_the_weighted_loops():
    graph, initial = ring("Pose2", 10, 11, closures=((2, 7), (3, 9), (1, 6)))
    robust = gtsam.NonlinearFactorGraph()
    huber = gtsam.noiseModel.mEstimator.Huber.Create(0.5)
    for i in range(graph.size()):
        f = graph.at(i)
        if isinstance(f, factors.BetweenFactorPose2) and abs(f.keys()[0] - f.keys()[1]) > 1:
            f = factors.BetweenFactorPose2(f.keys()[0], f.keys()[1], f.measured(),
                                           gtsam.noiseModel.Robust.Create(huber, f.noiseModel()))
        robust.add(f)
    scale = np.linspace(0.2, 1.0, robust.size())
    opt, res = run(robust, initial, lm_params(), cls=WeightedLevenbergMarquardt, scale=scale)
    assert res.linear_solver == "small"
    _, ref = run(robust, initial, lm_params(), cls=WeightedLevenbergMarquardt, scale=scale, linear_solver="cholmod")
    assert_same_run(res, ref)


def test_lf_optimize_takes_the_small_path_and_reports_it():
    graph, initial = visual(12)
    result = lf.optimize(graph, initial)
    assert result.converged
    ref = gtsam.LevenbergMarquardtOptimizer(graph, initial, gtsam.LevenbergMarquardtParams())
    values = ref.optimize()
    assert result.iterations == ref.iterations()
    assert result.error == pytest.approx(graph.error(values), rel=1e-9)
    assert batch.optimize(graph, initial).linear_solver == "small"
