"""The incremental smoother: ISAM2's interface, exact Gauss–Newton steps, accuracy against
``gtsam.ISAM2``, and refused updates that leave it as it was."""

from __future__ import annotations

from pathlib import Path

import gtsam
import numpy as np
import pytest

from lie_factors import factors as lf
from lie_factors.incremental import Smoother, SmootherParams
from lie_factors.errors import IndeterminantLinearSystem, InputError

ROOT = Path(__file__).resolve().parents[2]
EXACT = dict(relinearizeThreshold=0.0, relinearizeSkip=1, wildfireThreshold=0.0)


def _pose(group, rng, scale=1.0):
    if group == "Pose2":
        return gtsam.Pose2(*(scale * rng.normal(size=3)))
    if group == "Pose3":
        return gtsam.Pose3.Expmap(scale * rng.normal(size=6))
    return gtsam.Similarity3(gtsam.Rot3.Expmap(scale * rng.normal(size=3)), scale * rng.normal(size=3),
                             float(np.exp(0.1 * scale * rng.normal())))


def _noise(group):
    n = {"Pose2": 3, "Pose3": 6, "Similarity3": 7}[group]
    return gtsam.noiseModel.Diagonal.Sigmas(np.linspace(0.05, 0.2, n))


def _updates(group, rng, poses=25, factors=gtsam, loop_every=4, landmarks=False):
    """(new factors, new values) per update: a noisy chain with loop closures, a prior on the
    first pose, and (Pose2) range-bearing landmarks seen from several poses."""
    Between = getattr(factors, f"BetweenFactor{group}")
    Prior = getattr(factors, f"PriorFactor{group}")
    truth = [_pose(group, rng)]
    for _ in range(poses - 1):
        truth.append(truth[-1].compose(_pose(group, rng, 0.4)))
    noise = _noise(group)
    out = []
    est = None
    for i in range(poses):
        g = gtsam.NonlinearFactorGraph()
        v = gtsam.Values()
        if i == 0:
            g.add(Prior(0, truth[0], noise))
            est = truth[0].compose(_pose(group, rng, 0.05))
        else:
            z = truth[i - 1].between(truth[i]).compose(_pose(group, rng, 0.03))
            g.add(Between(i - 1, i, z, noise))
            est = est.compose(z)
            if i % loop_every == 0 and i >= loop_every:
                j = int(rng.integers(0, i - 1))
                g.add(Between(j, i, truth[j].between(truth[i]).compose(_pose(group, rng, 0.03)), noise))
        v.insert(i, est)
        if landmarks and i % 3 == 0:
            L = gtsam.symbol("l", i)
            p = truth[i].transformFrom(np.array([2.0, 1.0]))
            v.insert(L, p + 0.1 * rng.normal(size=2))
            bn = gtsam.noiseModel.Diagonal.Sigmas(np.array([0.05, 0.1]))
            for k in sorted({i, max(i - 1, 0)}):
                g.add(gtsam.BearingRangeFactor2D(k, L, truth[k].bearing(p), truth[k].range(p), bn))
        out.append((g, v))
    return out


def _gn_step(graph, theta):
    """One Gauss–Newton step of the whole graph from θ, by GTSAM's linearization and elimination."""
    return theta.retract(graph.linearize(theta).optimize())


def _as_array(values: gtsam.Values, key) -> np.ndarray:
    for t in ("Pose2", "Pose3", "Similarity3"):
        try:
            return getattr(values, f"at{t}")(key).matrix()
        except RuntimeError:
            pass
    try:
        return np.asarray(values.atPoint2(key))
    except RuntimeError:
        return np.asarray(values.atPoint3(key))


def _max_diff(a: gtsam.Values, b: gtsam.Values) -> float:
    """max over keys of max|A − B| / max(1, max|B|) (the keys of ``a``)."""
    worst = 0.0
    for k in a.keys():
        va, vb = _as_array(a, k), _as_array(b, k)
        worst = max(worst, float(np.max(np.abs(va - vb)) / max(1.0, np.max(np.abs(vb)))))
    return worst


@pytest.mark.parametrize("group,factors,landmarks", [("Pose2", gtsam, True), ("Pose3", gtsam, False),
                                                     ("Pose3", lf, False), ("Similarity3", lf, False)])
def test_every_update_is_one_gauss_newton_step_with_threshold_zero(group, factors, landmarks):
    rng = np.random.default_rng(7)
    s = Smoother(SmootherParams(**EXACT))
    graph = gtsam.NonlinearFactorGraph()
    for g, v in _updates(group, rng, poses=18, factors=factors, landmarks=landmarks):
        before = s.calculateEstimate() if s.keys else gtsam.Values()
        s.update(g, v)
        graph.push_back(g)
        theta = s.getLinearizationPoint()
        # the linearization point: the previous estimate, and the new variables as given
        expected_theta = gtsam.Values(before)
        expected_theta.insert(v)
        assert _max_diff(theta, expected_theta) <= 1e-12
        assert _max_diff(s.calculateEstimate(), _gn_step(graph, theta)) <= 1e-9
    assert s.relinearizations > 0


def test_accuracy_against_isam2_at_every_tenth_of_a_replay():
    from lie_factors.g2o import read_pose_graph
    from lie_factors.incremental.replay import factor_graph, isam2_params, schedule

    ds = read_pose_graph(str(ROOT / "data" / "smallGrid3D.g2o"))
    graph = factor_graph(ds, "native")
    steps = schedule(ds, graph)
    ours, ref = Smoother(), gtsam.ISAM2(isam2_params())
    so_far = gtsam.NonlinearFactorGraph()
    tenth = max(len(steps) // 10, 1)
    for n, step in enumerate(steps):
        g = gtsam.NonlinearFactorGraph()
        for k in step.factors:
            g.add(graph.at(k))
        so_far.push_back(g)
        for isam in (ours, ref):
            v = gtsam.Values()
            v.insert(step.key, ds.initial.atPose3(step.key) if n == 0 else
                     isam.calculateEstimatePose3(steps[n - 1].key).compose(
                         gtsam.Pose3(ds.measured[step.odometry[0]]) if step.odometry[1] else
                         gtsam.Pose3(ds.measured[step.odometry[0]]).inverse()))
            isam.update(g, v)
        if (n + 1) % tenth == 0 or n + 1 == len(steps):
            e_ours = so_far.error(ours.calculateEstimate())
            e_ref = so_far.error(ref.calculateEstimate())
            assert e_ours <= 1.01 * e_ref + 1e-12
    # the final relinearize-and-iterate call reaches the batch optimum
    ours.optimize()
    params = gtsam.LevenbergMarquardtParams()
    params.setRelativeErrorTol(1e-14)
    params.setAbsoluteErrorTol(1e-14)
    optimum = gtsam.LevenbergMarquardtOptimizer(so_far, ours.calculateEstimate(), params).optimize()
    assert so_far.error(ours.calculateEstimate()) == pytest.approx(so_far.error(optimum), rel=1e-6)


def test_array_updates_equal_graph_updates():
    rng = np.random.default_rng(3)
    a, b = Smoother(), Smoother()
    for g, v in _updates("Pose3", rng, poses=30):
        a.update(g, v)
        from lie_factors.posegraph.graph import PoseGraph

        keys = [int(k) for k in v.keys()]
        pg = PoseGraph.from_gtsam(g, "Pose3", keys=keys + [k for f in range(g.size()) for k in g.at(f).keys()])
        b.update_arrays("Pose3", keys, np.array([v.atPose3(k).matrix() for k in keys]),
                        pg.edge_keys, pg.measured, pg.information, pg.prior_keys, pg.prior_measured,
                        pg.prior_information)
    assert _max_diff(a.calculateEstimate(), b.calculateEstimate()) <= 1e-9
    assert b.getFactorsUnsafe().size() == a.getFactorsUnsafe().size()
    est = a.calculateEstimate()
    assert b.getFactorsUnsafe().error(est) == pytest.approx(a.getFactorsUnsafe().error(est), rel=1e-9)


def test_interface_estimates_linearization_point_factors_and_marginals():
    rng = np.random.default_rng(5)
    s = Smoother()
    graph = gtsam.NonlinearFactorGraph()
    ups = _updates("Pose2", rng, poses=20, landmarks=True)
    for g, v in ups:
        s.update(g, v)
        graph.push_back(g)
    est = s.calculateEstimate()
    last = 19
    assert s.calculateEstimatePose2(last).equals(est.atPose2(last), 1e-12)
    assert s.calculateEstimate(last).equals(est.atPose2(last), 1e-12)
    L = gtsam.symbol("l", 18)
    assert np.allclose(s.calculateEstimatePoint2(L), est.atPoint2(L), atol=1e-12)
    with pytest.raises(InputError, match="not a Pose3"):
        s.calculateEstimatePose3(last)
    assert s.getFactorsUnsafe().size() == graph.size()
    assert s.getFactorsUnsafe().error(est) == pytest.approx(graph.error(est), rel=1e-12)
    theta = s.getLinearizationPoint()
    assert theta.size() == est.size()
    marginals = gtsam.Marginals(graph, theta)
    for key in (last, 0, 7, L):
        assert np.allclose(s.marginalCovariance(key), marginals.marginalCovariance(key), rtol=1e-8, atol=1e-14)
    delta = s.getDelta()
    assert _max_diff(theta.retract(delta), est) <= 1e-12


def _snapshot(s: Smoother):
    return (s.calculateEstimate(), s.getLinearizationPoint(), s.getFactorsUnsafe().size(), len(s.keys),
            s.update_count)


def _assert_same(s: Smoother, snap):
    est, theta, nf, nv, count = snap
    assert _max_diff(s.calculateEstimate(), est) == 0.0
    assert _max_diff(s.getLinearizationPoint(), theta) == 0.0
    assert (s.getFactorsUnsafe().size(), len(s.keys), s.update_count) == (nf, nv, count)


def test_refused_updates_leave_the_smoother_as_it_was():
    rng = np.random.default_rng(11)
    ups = _updates("Pose2", rng, poses=25, landmarks=True)
    s = Smoother(relinearizeSkip=1)
    for g, v in ups[:12]:
        s.update(g, v)
    noise = _noise("Pose2")
    good_g, good_v = ups[12]
    snap = _snapshot(s)

    def refused(g, v, match, exc=InputError):
        with pytest.raises(exc, match=match):
            s.update(g, v)
        _assert_same(s, snap)

    # a factor on a key that has no value
    g = gtsam.NonlinearFactorGraph(good_g)
    g.add(gtsam.BetweenFactorPose2(11, 99, gtsam.Pose2(1, 0, 0), noise))
    refused(g, good_v, "has no value")
    # a new key that is already a variable
    v = gtsam.Values(good_v)
    v.insert(3, gtsam.Pose2())
    refused(good_g, v, "already a variable")
    # a new key no factor constrains
    v = gtsam.Values(good_v)
    v.insert(500, gtsam.Pose2())
    refused(good_g, v, "unconstrained")
    # a NaN measurement
    g = gtsam.NonlinearFactorGraph(good_g)
    g.add(gtsam.BetweenFactorPose2(0, 12, gtsam.Pose2(np.nan, 0, 0), noise))
    refused(g, good_v, rf"factor {good_g.size()} \(BetweenFactorPose2\): its measurement is not finite")
    # a NaN noise model, before a good factor of its kind
    g = gtsam.NonlinearFactorGraph()
    g.add(gtsam.BetweenFactorPose2(0, 12, gtsam.Pose2(1, 0, 0), gtsam.noiseModel.Diagonal.Sigmas(
        np.array([np.nan, 1.0, 1.0]))))
    g.push_back(good_g)
    refused(g, good_v, r"factor 0 \(BetweenFactorPose2\): its noise model is not finite")
    # a value of the wrong type
    v = gtsam.Values()
    v.insert(12, gtsam.Pose3())
    refused(good_g, v, "not a gtsam.Pose2")
    # a landmark seen once by a bearing only: undetermined (the system is rank deficient)
    g = gtsam.NonlinearFactorGraph(good_g)
    v = gtsam.Values(good_v)
    L = gtsam.symbol("m", 1)
    v.insert(L, np.array([5.0, 5.0]))
    g.add(gtsam.BearingFactor2D(12, L, gtsam.Rot2(0.3), gtsam.noiseModel.Isotropic.Sigma(1, 0.1)))
    refused(g, v, "undetermined", IndeterminantLinearSystem)
    # arrays: NaN, wrong shapes, a self loop
    P = s.calculateEstimatePose2(11).matrix()
    with pytest.raises(InputError, match="not finite"):
        s.update_arrays("Pose2", [12], P[None], [[11, 12]], np.full((1, 3, 3), np.nan), np.eye(3)[None])
    with pytest.raises(InputError, match="expected shape"):
        s.update_arrays("Pose2", [12], P[None, :2], [[11, 12]], P[None], np.eye(3)[None])
    with pytest.raises(InputError, match="to itself"):
        s.update_arrays("Pose2", [12], P[None], [[12, 12]], P[None], np.eye(3)[None])
    with pytest.raises(InputError, match="positive definite"):
        s.update_arrays("Pose2", [12], P[None], [[11, 12]], P[None], -np.eye(3)[None])
    _assert_same(s, snap)
    # the next good update works, and the rest of the replay agrees with a smoother never refused
    t = Smoother(relinearizeSkip=1)
    for g, v in ups[:12]:
        t.update(g, v)
    for g, v in ups[12:]:
        s.update(g, v)
        t.update(g, v)
    assert _max_diff(s.calculateEstimate(), t.calculateEstimate()) == 0.0


def test_params_from_isam2_params(capfd):
    p = gtsam.ISAM2Params()
    p.setRelinearizeThreshold(0.05)
    p.relinearizeSkip = 3
    gn = gtsam.ISAM2GaussNewtonParams()
    gn.setWildfireThreshold(0.002)
    p.setOptimizationParams(gn)
    q = Smoother(p).smoother_params
    assert (q.relinearizeThreshold, q.relinearizeSkip, q.wildfireThreshold) == (0.05, 3, 0.002)
    p.enableRelinearization = False
    assert SmootherParams.from_isam2(p).enableRelinearization is False
    assert SmootherParams.from_isam2(gtsam.ISAM2Params()) == SmootherParams()
    dogleg = gtsam.ISAM2Params()
    dl = gtsam.ISAM2DoglegParams()
    dl.setInitialDelta(0.25)
    dl.setAdaptationMode("ONE_STEP_PER_ITERATION")
    dogleg.setOptimizationParams(dl)
    q = SmootherParams.from_isam2(dogleg)
    assert (q.optimizer, q.initialDelta, q.adaptationMode, q.wildfireThreshold) == \
        ("Dogleg", 0.25, "ONE_STEP_PER_ITERATION", 1e-5)
    search = gtsam.ISAM2Params()
    ls = gtsam.ISAM2DoglegLineSearchParams()
    ls.setMaxDelta(2.0)
    search.setOptimizationParams(ls)
    q = SmootherParams.from_isam2(search)
    assert (q.optimizer, q.minDelta, q.maxDelta, q.stepSize) == ("DoglegLineSearch", 0.02, 2.0, 1.5)
    per_type = gtsam.ISAM2Params()
    thresholds = gtsam.ISAM2ThresholdMap()
    thresholds.insert(("x", np.array([0.1, 0.2, 0.3])))
    per_type.setRelinearizeThreshold(thresholds)
    q = SmootherParams.from_isam2(per_type)
    assert list(q.relinearizeThreshold) == ["x"] and np.array_equal(q.relinearizeThreshold["x"], [0.1, 0.2, 0.3])
    partial = gtsam.ISAM2Params()
    partial.enablePartialRelinearizationCheck = True
    with pytest.raises(InputError, match="enablePartialRelinearizationCheck"):
        Smoother(partial)
    # what GTSAM prints to be read reaches neither Python's stdout nor the process's
    assert capfd.readouterr().out == ""
    with pytest.raises(InputError, match="relinearizeSkip"):
        SmootherParams(relinearizeSkip=0)
    with pytest.raises(InputError, match="relinearizeThreshold"):
        SmootherParams(relinearizeThreshold=np.nan)


def test_global_relinearization_policy_relinearizes_everything_at_once():
    """SLAM++'s policy: when any variable moved by the threshold, every variable is relinearized."""
    rng = np.random.default_rng(13)
    ups = _updates("Pose3", rng, poses=30)
    per_variable, everything = Smoother(relinearizeSkip=1), Smoother(relinearizeSkip=1, relinearizePolicy="global")
    graph = gtsam.NonlinearFactorGraph()
    counts = []
    for g, v in ups:
        graph.push_back(g)
        before = everything.relinearizations
        per_variable.update(g, v)
        r = everything.update(g, v)
        counts.append((everything.relinearizations - before, len(everything.keys) - len(v.keys())))
        assert r.getVariablesRelinearized() in (0, len(everything.keys) - len(v.keys()))
    assert any(n > 0 for n, _ in counts)
    assert everything.relinearizations >= per_variable.relinearizations
    e_global, e_var = graph.error(everything.calculateEstimate()), graph.error(per_variable.calculateEstimate())
    assert e_global <= 1.01 * e_var



def _gauge_state(s: Smoother):
    return list(s.gauge.parent), list(s.gauge.anchored), list(s.gauge.size)


def _intel_update(pg, upto: int, start: int = 0):
    """Intel's poses start … upto − 1 and the edges among them: (graph, values) of GTSAM's factors."""
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    for (a, b), M, info in zip(pg.edge_keys.tolist(), pg.measured, pg.information):
        if start <= min(a, b) and max(a, b) < upto:
            graph.add(gtsam.BetweenFactorPose2(a, b, gtsam.Pose2(M[0, 2], M[1, 2], np.arctan2(M[1, 0], M[0, 0])),
                                               gtsam.noiseModel.Gaussian.Information(info)))
    for k in range(start, upto):
        values.insert(k, pg.initial.atPose2(k))
    return graph, values


def test_a_free_gauge_is_refused_on_the_structure_of_the_update(forbid_factorization):
    """Intel with no prior: gtsam.ISAM2 raises, all at once or on its first pose pair; the
    smoother refuses it on its structure, before any elimination, whatever the machine's
    rounding, on either path, and is left as it was (its components too)."""
    from lie_factors.g2o import read_pose_graph

    pg = read_pose_graph(str(ROOT / "data" / "intel.g2o"))
    free = pg.factor_graph()
    first, first_values = _intel_update(pg, 2)
    for graph, values in ((free, pg.initial), (first, first_values)):
        with pytest.raises(RuntimeError, match="Indeterminate linear system"):
            gtsam.ISAM2().update(graph, values)
    running = Smoother()  # intel's first poses, the first update with a prior
    prior, prior_values = _intel_update(pg, 30)
    prior.add(gtsam.PriorFactorPose2(0, pg.initial.atPose2(0), gtsam.noiseModel.Unit.Create(3)))
    running.update(prior, prior_values)
    snap, components = _snapshot(running), _gauge_state(running)
    forbid_factorization()
    for graph, values, size in ((free, pg.initial, 1728), (first, first_values, 2)):
        s = Smoother()
        with pytest.raises(IndeterminantLinearSystem, match=r"^the update leaves a variable undetermined: the "
                           rf"component of 0 \({size} variables\) has no prior: its gauge is free$") as info:
            s.update(graph, values)
        assert info.value.variable == 0 and (len(s.keys), s.bf.nv, len(s.gauge)) == (0, 0, 0)
    M = np.eye(3)[None]
    with pytest.raises(IndeterminantLinearSystem, match=r"component of 0 \(2 variables\) has no prior"):
        Smoother().update_arrays("Pose2", [0, 1], np.stack([np.eye(3)] * 2), [[0, 1]], M, np.eye(3)[None])
    # a new component with no prior beside an anchored one
    later, later_values = _intel_update(pg, 1000, start=900)
    with pytest.raises(IndeterminantLinearSystem, match=r"component of 900 \(100 variables\) has no prior"):
        running.update(later, later_values)
    with pytest.raises(IndeterminantLinearSystem, match=r"component of 900 \(2 variables\) has no prior") as info:
        running.update_arrays("Pose2", [900, 901], np.stack([np.eye(3)] * 2), [[900, 901]], M, np.eye(3)[None])
    assert info.value.variable == 30  # the smoother's variables 0 … 29, then the update's
    _assert_same(running, snap)
    assert _gauge_state(running) == components


def _translation_x(key: int):
    """A CustomFactor of one row on the Pose3 ``key``: the x of its translation."""
    def error(this, values, H):
        pose = values.atPose3(key)
        if H is not None:
            H[0] = np.concatenate([np.zeros(3), pose.rotation().matrix()[0]])[None]
        return np.array([pose.translation()[0]])

    return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(1), [key], error)


def test_a_new_variable_with_fewer_rows_than_its_dimension_is_refused(forbid_factorization):
    X = lambda i: gtsam.symbol("x", i)  # noqa: E731
    s = Smoother()
    g, v = gtsam.NonlinearFactorGraph(), gtsam.Values()
    g.add(gtsam.PriorFactorPose3(X(0), gtsam.Pose3(), gtsam.noiseModel.Unit.Create(6)))
    v.insert(X(0), gtsam.Pose3())
    s.update(g, v)
    snap, components = _snapshot(s), _gauge_state(s)
    forbid_factorization()
    g, v = gtsam.NonlinearFactorGraph(), gtsam.Values()
    g.add(_translation_x(X(1)))
    v.insert(X(1), gtsam.Pose3())
    with pytest.raises(IndeterminantLinearSystem, match=r"^the update leaves a variable undetermined: x1 has 1 row "
                                                        r"of factors for its 6 dimensions") as info:
        s.update(g, v)
    assert info.value.variable == 1
    _assert_same(s, snap)
    assert _gauge_state(s) == components


def test_a_component_with_a_factor_of_unknown_kind_is_left_to_the_elimination():
    """Two points tied by a CustomFactor offset and nothing else: the structure does not know the
    factor, the pivot rule refuses the exactly singular system, as gtsam.ISAM2 does."""
    p, q = gtsam.symbol("p", 0), gtsam.symbol("p", 1)

    def offset(this, values, H):
        if H is not None:
            H[0], H[1] = -np.eye(2), np.eye(2)
        return values.atPoint2(q) - values.atPoint2(p) - np.array([1.0, 0.0])

    g, v = gtsam.NonlinearFactorGraph(), gtsam.Values()
    g.add(gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(2), [p, q], offset))
    v.insert(p, np.array([0.0, 0.0]))
    v.insert(q, np.array([1.0, 0.0]))
    with pytest.raises(RuntimeError, match="Indeterminate linear system"):
        gtsam.ISAM2().update(g, v)
    s = Smoother()
    with pytest.raises(IndeterminantLinearSystem, match=r"a pivot of the column of p[01] is not above 1e-13 of its "
                                                        r"diagonal entry"):
        s.update(g, v)
    assert (len(s.keys), s.bf.nv, len(s.gauge)) == (0, 0, 0)
    g.add(gtsam.PriorFactorPoint2(p, np.array([0.0, 0.0]), gtsam.noiseModel.Unit.Create(2)))
    s.update(g, v)
    np.testing.assert_allclose(s.marginalCovariance(q), 2.0 * np.eye(2), rtol=1e-12)


@pytest.mark.parametrize("w, refused", [(1e-14, True), (1e-12, False)])
@pytest.mark.parametrize("arrays", [False, True])
def test_the_pivot_rule_refuses_a_gauge_held_by_a_prior_of_information_1e_14(w, refused, arrays):
    """Poses 0 and 1 at the identity, a between factor (identity) of unit information, a prior
    (identity) of information w·I on 0: each scalar of Λ is [[1 + w, −1], [−1, 1]], and the
    pivot of the pose eliminated second is w/(1 + w) of its diagonal entry (1 − 1/(1 + w) of 1,
    or (1 + w) − 1 of 1 + w), rounded by about 2e-16.  w = 1e-14 is refused by the pivot rule
    (10 times past 1e-13), w = 1e-12 is not (10 times inside), on either path."""
    I3 = np.eye(3)
    s = Smoother()
    if arrays:
        update = lambda: s.update_arrays("Pose2", [0, 1], np.stack([I3, I3]), [[0, 1]], I3[None], I3[None],  # noqa: E731
                                         [0], I3[None], w * I3[None])
    else:
        g, v = gtsam.NonlinearFactorGraph(), gtsam.Values()
        g.add(gtsam.BetweenFactorPose2(0, 1, gtsam.Pose2(), gtsam.noiseModel.Unit.Create(3)))
        g.add(gtsam.PriorFactorPose2(0, gtsam.Pose2(), gtsam.noiseModel.Gaussian.Information(w * I3)))
        v.insert(0, gtsam.Pose2())
        v.insert(1, gtsam.Pose2())
        update = lambda: s.update(g, v)  # noqa: E731
    if refused:
        with pytest.raises(IndeterminantLinearSystem, match=r"^the update leaves a variable undetermined: a pivot of "
                                                            r"the column of [01] is not above 1e-13") as info:
            update()
        assert info.value.variable in (0, 1)
        assert (len(s.keys), s.bf.nv, len(s.gauge)) == (0, 0, 0)
    else:
        update()
        # Λ⁻¹ = [[1, 1], [1, 1 + w]]/w per scalar; Λ's condition number 4/w leaves 1e-4 of it
        np.testing.assert_allclose(s.marginalCovariance(0), I3 / w, rtol=1e-3)
        np.testing.assert_allclose(s.marginalCovariance(1), I3 * (1 + w) / w, rtol=1e-3)
