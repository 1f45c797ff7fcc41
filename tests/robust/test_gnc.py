"""GNC: graduated weights against GTSAM's mEstimators, the outer loop against gtsam.GncLMOptimizer."""

from __future__ import annotations

import json

import gtsam
import numpy as np
import pytest

from lie_factors.app import cli, demo
from lie_factors.testing import outliers
from lie_factors import factors as lf
from lie_factors.backends import build_graph
from support.runs import run
from lie_factors.g2o import read_pose_graph
from lie_factors.robust import gnc
from lie_factors.robust import inner
from lie_factors.robust.losses import parse_loss
from lie_factors.initialization import initialize

M = gtsam.noiseModel.mEstimator


# --------------------------------------------------------------------------- #
# Weights
# --------------------------------------------------------------------------- #

def _weights(loss, sched, lam, u2, c2):
    out = np.empty(len(u2))
    gnc.gnc_weights(loss, sched, lam, np.asarray(u2, float), np.full(len(u2), c2),
                    np.zeros(len(u2), np.int64), out)
    return out


LAMBDAS = [1e-6, 1e-3, 0.05, 0.4, 0.999, 1.0, 1.001, 3.0, 60.0, 1e6, 1e16]


@pytest.mark.parametrize("sched, scheme", [(gnc.LINEAR, "GNC_LINEAR"), (gnc.SUPERLINEAR, "GNC_SUPERLINEAR")])
def test_tls_weights_equal_gtsams_graduated_weight(sched, scheme):
    c2 = 5.6724333650721865
    tls = M.TruncatedLeastSquares.Create(np.sqrt(c2), getattr(M.TruncatedLeastSquares.GradScheme, scheme))
    for lam in LAMBDAS:
        mu = lam / (1 + lam)  # GncOptimizer::NormalizedMu for TLS
        # straddle the bounds μc̄, c̄, c̄/μ, c̄/μ²
        u2 = np.concatenate([np.linspace(0, 3 * c2 / min(mu, 1) ** 2, 300),
                             [b * (1 + s) for b in (mu * c2, c2, c2 / mu, c2 / mu ** 2)
                              for s in (-1e-12, 0.0, 1e-12)]])
        ours = _weights(gnc.TLS, sched, lam, u2, c2)
        # GTSAM's member takes a distance and squares it: pass √u2 where that is exact enough,
        # compare to the static formula's value at u2 = distance².
        d = np.sqrt(u2)
        theirs = np.array([tls.graduatedWeight(float(x), mu) for x in d])
        again = _weights(gnc.TLS, sched, lam, d * d, c2)
        np.testing.assert_array_equal(again, theirs)
        assert np.all((ours >= 0) & (ours <= 1))


def test_gm_weights_equal_gtsams_graduated_weight():
    c2 = 8.405946914885464
    gm = M.GemanMcClure.Create(np.sqrt(c2), M.GemanMcClure.GradScheme.STANDARD)
    for lam in [1.0, 1.4, 10.0, 1e4, 1e9]:
        mu = min(1.0, 1.0 / lam)
        d = np.concatenate([np.linspace(0, 20, 200), [np.sqrt(c2)]])
        theirs = np.array([gm.graduatedWeight(float(x), mu) for x in d])
        np.testing.assert_array_equal(_weights(gnc.GM, gnc.LINEAR, lam, d * d, c2), theirs)


def test_known_inliers_and_outliers_keep_their_weights():
    out = np.empty(3)
    gnc.gnc_weights(gnc.TLS, gnc.LINEAR, 1.0, np.array([1e9, 1e9, 0.0]), np.ones(3),
                    np.array([1, 0, 2]), out)
    assert list(out) == [1.0, 0.0, 0.0]


def test_params_validation():
    with pytest.raises(ValueError, match="tls"):
        gnc.GncSettings(loss="huber")
    with pytest.raises(ValueError, match="linear"):
        gnc.GncSettings(loss="gm", scheduler="superlinear")
    with pytest.raises(ValueError, match="both"):
        gnc.factor_types(4, gnc.GncSettings(known_inliers=[1], known_outliers=[1]))
    with pytest.raises(ValueError, match="slot"):
        gnc.factor_types(4, gnc.GncSettings(known_inliers=[4]))


# --------------------------------------------------------------------------- #
# Outer loop against GncLMOptimizer on small graphs with planted outliers
# --------------------------------------------------------------------------- #

def _circle_problem(n=80, seed=0, count=6):
    """2-D: two laps of a circle, odometry + every third revisit as loop closure, planted outliers."""
    rng = np.random.default_rng(seed)
    truth = [gtsam.Pose2(5 * np.cos(2 * np.pi * i / 40), 5 * np.sin(2 * np.pi * i / 40),
                         2 * np.pi * i / 40 + np.pi / 2) for i in range(n)]
    sig = np.array([0.05, 0.05, 0.02])
    noise = gtsam.noiseModel.Diagonal.Sigmas(sig)
    between = gtsam.NonlinearFactorGraph()

    def meas(i, j):
        return truth[i].between(truth[j]).compose(gtsam.Pose2(*(rng.normal(size=3) * sig)))

    for i in range(n - 1):
        between.add(gtsam.BetweenFactorPose2(i, i + 1, meas(i, i + 1), noise))
    for i in range(40, n, 3):
        between.add(gtsam.BetweenFactorPose2(i - 40, i, meas(i - 40, i), noise))
    graph, planted = outliers.plant_false_loop_closures(between, list(range(n)), count, seed, False)
    initial = gtsam.Values()
    pose = gtsam.Pose2()
    initial.insert(0, pose)
    for i in range(n - 1):
        pose = pose.compose(graph.at(i).measured())
        initial.insert(i + 1, pose)
    return graph, planted, initial


def _with_prior(between, factory, prior, prior_noise):
    g = gtsam.NonlinearFactorGraph()
    for k in range(between.size()):
        f = between.at(k)
        i, j = f.keys()
        g.add(factory[0](i, j, f.measured(), f.noiseModel()))
    g.add(factory[1](0, prior, prior_noise))
    return g


NATIVE2 = (gtsam.BetweenFactorPose2, gtsam.PriorFactorPose2)
OURS2 = (lf.BetweenFactorPose2, lf.PriorFactorPose2)
NATIVE3 = (gtsam.BetweenFactorPose3, gtsam.PriorFactorPose3)
OURS3 = (lf.BetweenFactorPose3, lf.PriorFactorPose3)


def _params(graph, loss="tls"):
    lc = outliers.loop_closure_mask(graph)
    return gnc.GncSettings(loss=loss, known_inliers=np.flatnonzero(~lc).tolist())


@pytest.mark.parametrize("loss", ["tls", "gm"])
def test_outer_loop_with_gtsam_lm_is_gncLMOptimizer(loss):
    between, planted, initial = _circle_problem()
    prior_noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([1e-3, 1e-3, 1e-4]))
    graph = _with_prior(between, NATIVE2, gtsam.Pose2(), prior_noise)
    params = _params(graph, loss)
    ref = inner.gtsam_gnc(graph, initial, params)
    ours = gnc.gnc_optimize(inner.GtsamInner(graph, initial), params)
    # Same loop on the same inner LM: the same numbers.
    np.testing.assert_array_equal(ours.weights, ref.weights)
    assert ours.iterations == ref.iterations
    assert ours.cost == ref.cost
    if loss == "tls":
        assert set(planted.tolist()) <= set(ours.outliers.tolist())  # recall 1


@pytest.mark.parametrize("loss", ["tls", "gm"])
def test_batch_gnc_matches_gncLMOptimizer_se2(loss):
    between, planted, initial = _circle_problem(seed=1)
    prior_noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([1e-3, 1e-3, 1e-4]))
    native = _with_prior(between, NATIVE2, gtsam.Pose2(), prior_noise)
    ours = _with_prior(between, OURS2, gtsam.Pose2(), prior_noise)
    params = _params(native, loss)
    ref = inner.gtsam_gnc(native, initial, params)
    res = gnc.gnc_optimize(inner.BatchInner(ours, initial), params)
    np.testing.assert_array_equal(res.outliers, ref.outliers)
    np.testing.assert_allclose(res.weights, ref.weights, atol=1e-6)
    assert res.iterations == ref.iterations
    assert res.cost == pytest.approx(ref.cost, rel=1e-4)
    values = res.values.to_values()
    for k in range(80):
        assert np.max(np.abs(ref.values.atPose2(k).localCoordinates(values.atPose2(k)))) < 1e-5


def test_batch_gnc_matches_gncLMOptimizer_se3_and_finds_the_planted_outliers():
    prob = demo.simulate(60, seed=5)
    between = demo.between_graph(prob)
    n_lc = int(outliers.loop_closure_mask(between).sum())
    between, planted = outliers.plant_false_loop_closures(between, list(range(60)), n_lc // 4, 5, True)
    prior_noise = gtsam.noiseModel.Diagonal.Sigmas(demo.PRIOR_SIGMAS)
    native = _with_prior(between, NATIVE3, gtsam.Pose3(), prior_noise)
    ours = _with_prior(between, OURS3, gtsam.Pose3(), prior_noise)
    params = _params(native)
    ref = inner.gtsam_gnc(native, prob.initial, params)
    res = gnc.gnc_optimize(inner.BatchInner(ours, prob.initial), params)
    assert set(res.outliers.tolist()) == set(ref.outliers.tolist())
    assert set(planted.tolist()) <= set(res.outliers.tolist())  # recall 1
    assert res.cost == pytest.approx(ref.cost, rel=1e-4)


class _RecordingInner:
    """An inner solver that records where each solve starts (GtsamInner underneath)."""

    def __init__(self, graph, initial):
        self._inner = inner.GtsamInner(graph, initial)
        self.size, self.dims, self.initial = self._inner.size, self._inner.dims, initial
        self.starts, self.results = [], []

    def factor_errors(self, values):
        return self._inner.factor_errors(values)

    def optimize(self, weights, start=None, max_iterations=None):
        self.starts.append(start)
        self.limits = getattr(self, "limits", []) + [max_iterations]
        values, n = self._inner.optimize(weights, start, max_iterations)
        self.results.append(values)
        return values, n


def test_warm_start_continues_each_solve_from_the_last():
    between, planted, initial = _circle_problem(seed=1)
    prior_noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([1e-3, 1e-3, 1e-4]))
    graph = _with_prior(between, NATIVE2, gtsam.Pose2(), prior_noise)
    params = _params(graph)
    cold, warm = _RecordingInner(graph, initial), _RecordingInner(graph, initial)
    ref = gnc.gnc_optimize(cold, params)
    res = gnc.gnc_optimize(warm, gnc.GncSettings(**{**params.__dict__, "warm_start": True}))
    assert all(s is None for s in cold.starts)  # GTSAM's: every solve from the initial values
    assert warm.starts[0] is None and len(warm.starts) > 2
    assert all(s is r for s, r in zip(warm.starts[1:], warm.results))
    # the continuation ends at the same verdict with fewer LM iterations
    np.testing.assert_array_equal(res.outliers, ref.outliers)
    assert set(planted.tolist()) <= set(res.outliers.tolist())
    assert res.inner_iterations < ref.inner_iterations
    with pytest.raises(ValueError, match="warm_start"):
        gnc.GncSettings(warm_start=True).to_gtsam()


def test_a_declined_run_ends_at_its_first_solve_and_an_accepted_one_is_the_plain_run():
    between, planted, initial = _circle_problem(seed=2)
    graph = _with_prior(between, NATIVE2, gtsam.Pose2(), gtsam.noiseModel.Diagonal.Sigmas(np.array([1e-3, 1e-3, 1e-4])))
    params = _params(graph)
    plain = gnc.gnc_optimize(_RecordingInner(graph, initial), params)
    asked, recording = [], _RecordingInner(graph, initial)
    declined = gnc.gnc_optimize(recording, params, proceed=lambda v: asked.append(v) or False)
    assert declined.stop == gnc.DECLINED and declined.iterations == 0 and declined.history == []
    assert len(recording.results) == 1 and asked == recording.results  # one solve, shown to proceed
    assert declined.values is recording.results[0]
    np.testing.assert_array_equal(declined.weights, np.ones(graph.size()))  # the first solve's weights
    accepted = gnc.gnc_optimize(_RecordingInner(graph, initial), params, proceed=lambda v: True)
    np.testing.assert_array_equal(accepted.weights, plain.weights)
    assert (accepted.iterations, accepted.cost, accepted.stop) == (plain.iterations, plain.cost, plain.stop)
    assert set(planted.tolist()) <= set(accepted.outliers.tolist())


@pytest.mark.parametrize("kind", ["gtsam", "batch"])
def test_the_first_solve_stops_at_first_iterations_and_the_others_at_lms_limit(kind):
    between, _, initial = _circle_problem(seed=4)
    noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([1e-3, 1e-3, 1e-4]))
    graph = _with_prior(between, NATIVE2 if kind == "gtsam" else OURS2, gtsam.Pose2(), noise)
    lm = gtsam.LevenbergMarquardtParams()
    kind_of = inner.GtsamInner if kind == "gtsam" else inner.BatchInner

    def made():
        return kind_of(graph, initial, lm)

    w = np.ones(graph.size())
    assert made().optimize(w)[1] > 2
    assert made().optimize(w, None, 2)[1] == 2
    assert lm.getMaxIterations() == 100  # the caller's parameters as they were
    recording = _RecordingInner(graph, initial) if kind == "gtsam" else None
    if recording is not None:
        res = gnc.gnc_optimize(recording, _params(graph), first_iterations=1)
        assert recording.limits[0] == 1 and all(m is None for m in recording.limits[1:])
        assert res.iterations > 0


def test_batch_warm_start_begins_at_the_given_state():
    between, _, initial = _circle_problem(seed=3)
    ours = _with_prior(between, OURS2, gtsam.Pose2(), gtsam.noiseModel.Diagonal.Sigmas(np.array([1e-3, 1e-3, 1e-4])))
    w = np.ones(ours.size())
    solved, n = inner.BatchInner(ours, initial).optimize(w)
    assert n > 1
    none = gtsam.LevenbergMarquardtParams()
    none.setMaxIterations(0)  # a solve that returns where it starts
    idle = inner.BatchInner(ours, initial, none)
    at_start, at_solved = idle.optimize(w)[0].to_values(), idle.optimize(w, solved)[0].to_values()
    expected = solved.to_values()
    for k in range(80):
        assert initial.atPose2(k).equals(at_start.atPose2(k), 1e-15)
        assert expected.atPose2(k).equals(at_solved.atPose2(k), 1e-15)


def test_robust_noise_models_are_replaced_by_their_gaussian_part():
    # GncOptimizer strips Robust noise: the same result with or without it.
    between, planted, initial = _circle_problem(seed=2)
    prior_noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([1e-3, 1e-3, 1e-4]))
    plain = _with_prior(between, OURS2, gtsam.Pose2(), prior_noise)
    robust = gtsam.NonlinearFactorGraph()
    for k in range(plain.size()):
        f = plain.at(k)
        robust.add(inner.with_noise(f, gtsam.noiseModel.Robust.Create(M.Huber.Create(1.0), f.noiseModel())))
    params = _params(plain)
    a = gnc.gnc_optimize(inner.BatchInner(plain, initial), params)
    b = gnc.gnc_optimize(inner.BatchInner(robust, initial), params)
    np.testing.assert_array_equal(a.weights, b.weights)
    assert a.cost == b.cost


# --------------------------------------------------------------------------- #
# CLI
# --------------------------------------------------------------------------- #

def _write_g2o(path, between, initial):
    gtsam.writeG2o(between, initial, str(path))


@pytest.fixture(scope="module")
def outlier_file(tmp_path_factory):
    between, planted, initial = _circle_problem(seed=4)
    path = tmp_path_factory.mktemp("g2o") / "circle_outliers.g2o"
    _write_g2o(path, between, initial)
    return path, planted


@pytest.mark.parametrize("backend", ["native", "batch", "dropin"])
def test_cli_gnc_reports_the_planted_outliers(outlier_file, backend, capsys):
    path, planted = outlier_file
    assert cli.main(["posegraph", str(path), "--gnc", "tls", "--backend", backend, "--json", "--quiet"]) == 0
    record = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert record["gnc"] == "tls"
    assert record["outliers"] == sorted(planted.tolist())


@pytest.mark.parametrize("backend", ["native", "batch"])
@pytest.mark.parametrize("every_edge", [False, True])
def test_cli_robust_loss_is_applied_where_asked(outlier_file, backend, every_edge, tmp_path, capsys):
    # The reported error is GTSAM's error of the graph with Robust noise on the loop closures
    # (on every edge with --robust-all), evaluated at the written result.
    path, _ = outlier_file
    out = tmp_path / "out.g2o"
    extra = ["--robust-all"] if every_edge else []
    assert cli.main(["posegraph", str(path), "--robust", "cauchy:1", *extra, "--backend", backend,
                     "--output", str(out), "--json", "--quiet"]) == 0
    record = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert record["robust"] == "cauchy:1" + ("+all" if every_edge else "") and "outliers" not in record
    between, values = gtsam.readG2o(str(path), False)
    _, result = gtsam.readG2o(str(out), False)
    lc = outliers.loop_closure_mask(between)
    graph = gtsam.NonlinearFactorGraph()
    for k in range(between.size()):
        f = between.at(k)
        noise = f.noiseModel()
        if every_edge or lc[k]:
            noise = gtsam.noiseModel.Robust.Create(M.Cauchy.Create(1.0), noise)
        graph.add(f.cloneWithNewNoiseModel(noise))
    # the CLI's prior on the first pose, at its initial value (error ~0 at the optimum)
    graph.add(gtsam.PriorFactorPose2(0, result.atPose2(0), gtsam.noiseModel.Unit.Create(3)))
    assert record["final_error"] == pytest.approx(graph.error(result), rel=1e-6, abs=1e-6)


@pytest.mark.parametrize("argv, fragment", [
    (["--robust", "hubber"], "unknown loss"),
    (["--robust", "huber:0"], "positive"),
    (["--robust", "tukey:-2"], "positive"),
    (["--robust", "welsch"], "unknown loss"),
    (["--robust-all"], "needs --robust"),
    (["--robust", "huber", "--gnc", "tls"], "alternatives"),
])
def test_cli_bad_robust_options(outlier_file, argv, fragment, capsys):
    path, _ = outlier_file
    assert cli.main(["posegraph", str(path), *argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("lie-factors: error:") and fragment in err[0]


def test_cli_gnc_needs_loop_closures(tmp_path, capsys):
    between, _, initial = _circle_problem()
    chain = gtsam.NonlinearFactorGraph()
    for k in range(79):
        chain.add(between.at(k))
    path = tmp_path / "chain.g2o"
    _write_g2o(path, chain, initial)
    assert cli.main(["posegraph", str(path), "--gnc", "tls"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "loop closures" in err[0]


def test_cli_bad_gnc_loss(outlier_file, capsys):
    path, _ = outlier_file
    assert cli.main(["posegraph", str(path), "--gnc", "huber"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--gnc" in err[0]


# --------------------------------------------------------------------------- #
# Where GNC starts: --init auto under --gnc / --robust
# --------------------------------------------------------------------------- #

@pytest.fixture(scope="module")
def se3_outlier_file(tmp_path_factory):
    # 150-pose SE(3) trajectory, 34 true loop closures, 13 planted false ones: the chordal
    # relaxation over every edge is bent so far by them that GNC from it rejects every true one.
    prob = demo.simulate(150, seed=1)
    between = demo.between_graph(prob)
    n_lc = int(outliers.loop_closure_mask(between).sum())
    between, planted = outliers.plant_false_loop_closures(between, list(range(150)), int(0.4 * n_lc), 1, True)
    path = tmp_path_factory.mktemp("g2o") / "se3_outliers.g2o"
    gtsam.writeG2o(between, prob.initial, str(path))
    return path, planted


def _cli_json(capsys, *argv):
    assert cli.main(["posegraph", *map(str, argv), "--json"]) == 0
    out = capsys.readouterr().out.strip().splitlines()
    return json.loads(out[-1]), out


def test_gnc_default_init_starts_from_odometry_and_recovers(se3_outlier_file, capsys):
    path, planted = se3_outlier_file
    auto, out = _cli_json(capsys, path, "--gnc", "tls")
    assert auto["init"] == "spanning-tree" and auto["init_inliers_only"] is True
    assert any("initial guess: measurements composed along a spanning tree of the odometry edges "
               "and the prior only" in line for line in out)
    c = outliers.classify(auto["outliers"], planted)
    assert (c.precision, c.recall) == (1.0, 1.0)
    # The same classification as from the file's vertices (dead reckoning) ...
    from_file, _ = _cli_json(capsys, path, "--gnc", "tls", "--init", "file")
    assert from_file["init"] == "file" and from_file["init_inliers_only"] is False
    assert from_file["outliers"] == auto["outliers"]
    assert auto["final_error"] == pytest.approx(from_file["final_error"], rel=1e-6)
    # ... while from the relaxation over every edge (what auto was before) plain GNC rejects true
    # loop closures; the consistency stage and the final check recover from that start too.
    chordal, _ = _cli_json(capsys, path, "--gnc", "tls", "--init", "chordal", "--no-consistency")
    assert chordal["init_inliers_only"] is False
    assert outliers.classify(chordal["outliers"], planted).precision < 0.5
    checked, _ = _cli_json(capsys, path, "--gnc", "tls", "--init", "chordal")
    c = outliers.classify(checked["outliers"], planted)
    assert (c.precision, c.recall) == (1.0, 1.0)


def test_robust_default_init_starts_from_odometry(se3_outlier_file, capsys):
    path, _ = se3_outlier_file
    rec, _ = _cli_json(capsys, path, "--robust", "cauchy", "--backend", "native", "--quiet")
    assert rec["init"] == "spanning-tree" and rec["init_inliers_only"] is True
    start = run(str(path), "native", max_iterations=0, robust=parse_loss("cauchy"))[1].start
    between, values = gtsam.readG2o(str(path), True)
    pose = values.atPose3(0)
    for k in range(149):  # odometry edge k joins poses k and k + 1
        assert between.at(k).keys() == [k, k + 1]
        pose = pose.compose(between.at(k).measured())
        np.testing.assert_allclose(start.atPose3(k + 1).matrix(), pose.matrix(), atol=1e-9)


def test_plain_default_init_is_unchanged(se3_outlier_file, capsys):
    # Without --gnc/--robust, auto is the relaxation over every edge, as before (the native
    # backend's: GTSAM's own chordal initializer).
    path, _ = se3_outlier_file
    rec, _ = _cli_json(capsys, path, "--backend", "native", "--max-iterations", "0", "--quiet")
    assert rec["init"] == "chordal" and "init_inliers_only" not in rec
    start = run(str(path), "native", max_iterations=0)[1].start
    pg = read_pose_graph(str(path))
    expected = initialize(build_graph(pg, "native"), "chordal", engine="gtsam").values
    for k in range(150):
        np.testing.assert_allclose(start.atPose3(k).matrix(), expected.atPose3(k).matrix(), atol=1e-12)


def test_inlier_start_falls_back_when_odometry_does_not_connect(tmp_path, capsys):
    # Poses 0-39 and 40-79 joined only by loop closures: the known inliers cannot place the
    # second half, so auto says why and takes the file's vertices.
    between, _, initial = _circle_problem()
    graph = gtsam.NonlinearFactorGraph()
    for k in range(between.size()):
        if list(between.at(k).keys()) != [39, 40]:
            graph.add(between.at(k))
    path = tmp_path / "split.g2o"
    _write_g2o(path, graph, initial)
    rec, out = _cli_json(capsys, path, "--gnc", "tls", "--backend", "native")
    assert rec["init"] == "file" and rec["init_inliers_only"] is False
    assert any("init auto on the known inliers not applicable: graph is not connected" in line
               for line in out)
