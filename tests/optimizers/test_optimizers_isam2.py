"""lie_factors.optimizers.ISAM2 / IncrementalFixedLagSmoother: GTSAM's results, no copied Values.

The deterministic cause of the speed-up is tested directly: the Values objects the
factor callbacks receive (the drop-in: ISAM2's own linearization point only; plain
gtsam.ISAM2: a new copy per callback). Timings are in benchmarks/incremental.py.
"""

from __future__ import annotations

import gc
import weakref

import gtsam
import numpy as np
import pytest

from lie_factors import factors as F
from lie_factors.errors import ValuesIncorrectType
from lie_factors.optimizers import ISAM2, IncrementalFixedLagSmoother

NOISE2 = gtsam.noiseModel.Diagonal.Sigmas(np.array([0.05, 0.05, 0.02]))
NOISE3 = gtsam.noiseModel.Diagonal.Sigmas(np.array([0.01, 0.01, 0.01, 0.05, 0.05, 0.05]))


def _recording(base):
    """A subclass of our factor ``base`` that appends every Values it is handed to ``seen``."""

    class Recording(base):
        seen: list = []

        def _evaluate(self, this, values, H):
            Recording.seen.append(values)
            return super()._evaluate(this, values, H)

    return Recording


def _online(truth, noise):
    """Per update: (factors, new values) along ``truth``: odometry perturbed by ``noise()``, and
    a loop closure back 20 poses every 5 poses."""

    def meas(i, j):
        return truth[i].between(truth[j]).compose(noise())

    steps = [([("prior", 0, truth[0])], truth[0])]
    guess = truth[0]
    for i in range(1, len(truth)):
        m = meas(i - 1, i)
        guess = guess.compose(m)
        items = [("between", i - 1, i, m)]
        if i % 5 == 0 and i >= 20:
            items.append(("between", i - 20, i, meas(i - 20, i)))
        steps.append((items, guess))
    return steps


def online_pose2(n=60, seed=1):
    """A noisy 2-D loop (:func:`_online`)."""
    rng = np.random.default_rng(seed)
    truth = [gtsam.Pose2(5 * np.cos(2 * np.pi * i / 20), 5 * np.sin(2 * np.pi * i / 20),
                         2 * np.pi * i / 20 + np.pi / 2) for i in range(n)]
    return _online(truth, lambda: gtsam.Pose2(*(rng.normal(size=3) * np.array([0.05, 0.05, 0.02]))))


def online_pose3(n=60, seed=2):
    """A noisy 3-D helix (:func:`_online`)."""
    rng = np.random.default_rng(seed)
    truth = [gtsam.Pose3(gtsam.Rot3.Yaw(2 * np.pi * i / 20 + np.pi / 2),
                         np.array([5 * np.cos(2 * np.pi * i / 20), 5 * np.sin(2 * np.pi * i / 20), 0.02 * i]))
             for i in range(n)]
    return _online(truth, lambda: gtsam.Pose3.Expmap(rng.normal(size=6) * np.array([0.01] * 3 + [0.05] * 3)))


def params(skip=1, threshold=0.001, **kw):
    p = gtsam.ISAM2Params()
    p.relinearizeSkip = skip
    p.setRelinearizeThreshold(threshold)
    for k, v in kw.items():
        setattr(p, k, v)
    return p


def replay(isam, steps, Between, Prior, noise, seen=None, after=None):
    """Run ``steps`` through ``isam``; return the final estimate and, per update, the
    objects ``seen`` collected during it and the result."""
    per_update = []
    relinearized = 0
    for i, (items, guess) in enumerate(steps):
        g = gtsam.NonlinearFactorGraph()
        for item in items:
            if item[0] == "prior":
                g.add(Prior(item[1], item[2], noise))
            else:
                g.add(Between(item[1], item[2], item[3], noise))
        v = gtsam.Values()
        v.insert(i, guess)
        if seen is not None:
            seen.clear()
        result = isam.update(g, v)
        relinearized += result.getVariablesRelinearized()
        per_update.append(list(seen) if seen is not None else None)
        if after is not None:
            after(isam, per_update[-1])
    return isam.calculateEstimate(), per_update, relinearized


def max_diff(a: gtsam.Values, b: gtsam.Values, at: str) -> float:
    assert sorted(a.keys()) == sorted(b.keys())
    return max(np.max(np.abs(getattr(a, at)(k).matrix() - getattr(b, at)(k).matrix())) for k in a.keys())


@pytest.mark.parametrize("group", ["Pose2", "Pose3"])
def test_estimates_identical_and_callbacks_get_the_linearization_point(group):
    steps = online_pose2() if group == "Pose2" else online_pose3()
    noise = NOISE2 if group == "Pose2" else NOISE3
    Between = _recording(getattr(F, f"BetweenFactor{group}"))
    Prior = getattr(F, f"PriorFactor{group}")

    plain, plain_seen, plain_relin = replay(gtsam.ISAM2(params()), steps, Between, Prior, noise,
                                            seen=Between.seen)
    checked = []

    def check(isam, seen_now):
        # The wrappers the callbacks got are still referenced by `seen_now`, so
        # getLinearizationPoint() returns that same object if they were it.
        lp = isam.getLinearizationPoint()
        checked.append(all(v is lp for v in seen_now))

    dropin, drop_seen, drop_relin = replay(ISAM2(params()), steps, Between, Prior, noise,
                                           seen=Between.seen, after=check)
    assert plain_relin > 0 and drop_relin == plain_relin  # relinearization did happen, alike
    assert max_diff(plain, dropin, f"at{group}") <= 1e-9
    # The cause: plain ISAM2 hands every callback a new copy, the drop-in only its own θ.
    calls = sum(len(s) for s in plain_seen)
    assert calls == sum(len(s) for s in drop_seen) > len(steps)
    assert len({id(v) for s in plain_seen for v in s}) == calls
    assert all(checked)
    assert len({id(v) for s in drop_seen for v in s}) == 1


@pytest.mark.parametrize("form", ["positional", "update_params"])
def test_evaluate_nonlinear_error_without_copies(form):
    """GTSAM evaluates errorBefore/errorAfter on a temporary (a copy per callback); the drop-in
    on Values Python owns: per update at most θ and the two estimates, and GTSAM's numbers."""
    steps = online_pose2(40)
    Between = _recording(F.BetweenFactorPose2)
    runs = []
    for cls in (gtsam.ISAM2, ISAM2):
        isam = cls(params(evaluateNonlinearError=True))
        errors, distinct = [], []
        for i, (items, guess) in enumerate(steps):
            g = gtsam.NonlinearFactorGraph()
            for item in items:
                g.add(F.PriorFactorPose2(item[1], item[2], NOISE2) if item[0] == "prior"
                      else Between(item[1], item[2], item[3], NOISE2))
            v = gtsam.Values()
            v.insert(i, guess)
            Between.seen = []
            remove = [isam.getFactorsUnsafe().size() - 1] if i == 30 else []  # drop a loop closure
            if form == "positional":
                r = isam.update(g, v, remove)
            else:
                up = gtsam.ISAM2UpdateParams()
                up.removeFactorIndices = remove
                r = isam.update(g, v, up)
            errors.append((r.getErrorBefore(), r.getErrorAfter(), r.getVariablesRelinearized(),
                           list(r.getNewFactorsIndices())))
            distinct.append(len({id(x) for x in Between.seen}))
        runs.append((errors, distinct, isam.calculateEstimate(), r))
    (e_plain, d_plain, est_plain, _), (e_drop, d_drop, est_drop, r) = runs
    assert isinstance(r, gtsam.ISAM2Result)
    assert max_diff(est_plain, est_drop, "atPose2") <= 1e-9
    for a, b in zip(e_plain, e_drop):
        assert a[2:] == b[2:]
        assert b[0] == pytest.approx(a[0], rel=1e-12, abs=1e-12)
        assert b[1] == pytest.approx(a[1], rel=1e-12, abs=1e-12)
    assert max(d_drop) <= 3 < max(d_plain)
    assert sum(d_plain) > 10 * sum(d_drop)


def test_other_methods_and_update_forms_match_gtsam():
    steps = online_pose2(40)
    plain, dropin = gtsam.ISAM2(params()), ISAM2(params())
    for isam in (plain, dropin):
        for i, (items, guess) in enumerate(steps):
            g = gtsam.NonlinearFactorGraph()
            for item in items:
                g.add(F.PriorFactorPose2(item[1], item[2], NOISE2) if item[0] == "prior"
                      else F.BetweenFactorPose2(item[1], item[2], item[3], NOISE2))
            v = gtsam.Values()
            v.insert(i, guess)
            if i % 3 == 0:
                isam.update(newFactors=g, newTheta=v)
            elif i % 3 == 1:
                isam.update(g, v, gtsam.ISAM2UpdateParams())
            else:
                isam.update(g, v, [], None, None, None, i % 2 == 0)
        # remove the last loop closure (keyword form), as GTSAM's own does
        last = isam.getFactorsUnsafe().size() - 1
        isam.update(removeFactorIndices=[last])
    assert isinstance(dropin, gtsam.ISAM2)
    assert max_diff(plain.calculateEstimate(), dropin.calculateEstimate(), "atPose2") <= 1e-9
    assert np.allclose(plain.calculateEstimatePose2(7).matrix(), dropin.calculateEstimatePose2(7).matrix(),
                       atol=1e-9, rtol=0)
    assert np.allclose(plain.calculateBestEstimate().atPose2(3).matrix(),
                       dropin.calculateBestEstimate().atPose2(3).matrix(), atol=1e-9, rtol=0)
    assert np.allclose(plain.marginalCovariance(10), dropin.marginalCovariance(10), atol=1e-12, rtol=1e-9)
    assert plain.getFactorsUnsafe().size() == dropin.getFactorsUnsafe().size()
    assert abs(plain.error(plain.getDelta()) - dropin.error(dropin.getDelta())) <= 1e-9
    copy = ISAM2(dropin)  # GTSAM's copy constructor
    assert max_diff(copy.calculateEstimate(), dropin.calculateEstimate(), "atPose2") == 0


def test_dogleg_params_give_gtsams_estimates():
    p = gtsam.ISAM2Params()
    p.setOptimizationParams(gtsam.ISAM2DoglegParams())
    steps = online_pose3(30)
    a, _, _ = replay(gtsam.ISAM2(p), steps, F.BetweenFactorPose3, F.PriorFactorPose3, NOISE3)
    p = gtsam.ISAM2Params()
    p.setOptimizationParams(gtsam.ISAM2DoglegParams())
    b, _, _ = replay(ISAM2(p), steps, F.BetweenFactorPose3, F.PriorFactorPose3, NOISE3)
    assert max_diff(a, b, "atPose3") <= 1e-9


def _mixed_graph_replay(isam, steps, seen):
    """GTSAM's own factors (prior, odometry), a user's plain gtsam.CustomFactor (every 4th
    odometry edge) and ours (loop closures) in one graph."""

    def user_between(measured):
        def error(this, values, H):
            seen.append(values)
            k1, k2 = this.keys()
            x1, x2 = values.atPose2(k1), values.atPose2(k2)
            J1, J2 = np.zeros((3, 3), order="F"), np.zeros((3, 3), order="F")
            e = gtsam.Pose2.Logmap(measured.between(x1.between(x2, J1, J2)))
            if H is not None:  # GTSAM's Jacobians of between; Logmap's neglected (small residual)
                H[0], H[1] = J1, J2
            return e

        return error

    for i, (items, guess) in enumerate(steps):
        g = gtsam.NonlinearFactorGraph()
        for item in items:
            if item[0] == "prior":
                g.add(gtsam.PriorFactorPose2(item[1], item[2], NOISE2))
            elif item[2] - item[1] != 1:
                g.add(F.BetweenFactorPose2(item[1], item[2], item[3], NOISE2))
            elif item[2] % 4 == 0:
                g.add(gtsam.CustomFactor(NOISE2, [item[1], item[2]], user_between(item[3])))
            else:
                g.add(gtsam.BetweenFactorPose2(item[1], item[2], item[3], NOISE2))
        v = gtsam.Values()
        v.insert(i, guess)
        isam.update(g, v)
    return isam.calculateEstimate()


def test_mixed_graph_users_custom_factor_gets_the_same_object():
    steps = online_pose2(50)
    plain_seen, drop_seen = [], []
    a = _mixed_graph_replay(gtsam.ISAM2(params()), steps, plain_seen)
    isam = ISAM2(params())
    b = _mixed_graph_replay(isam, steps, drop_seen)
    assert max_diff(a, b, "atPose2") <= 1e-9
    assert len(plain_seen) == len(drop_seen) > 10
    assert len({id(v) for v in plain_seen}) == len(plain_seen)
    lp = isam.getLinearizationPoint()
    assert all(v is lp for v in drop_seen)


def test_exception_in_callback_propagates_like_gtsams():
    class Boom(Exception):
        pass

    def raising(this, values, H):
        raise Boom("callback failed")

    outcomes = []
    for cls in (gtsam.ISAM2, ISAM2):
        isam = cls()
        g = gtsam.NonlinearFactorGraph()
        g.add(F.PriorFactorPose2(0, gtsam.Pose2(), NOISE2))
        g.add(gtsam.CustomFactor(NOISE2, [0], raising))
        v = gtsam.Values()
        v.insert(0, gtsam.Pose2())
        with pytest.raises(Exception) as info:
            isam.update(g, v)
        outcomes.append((type(info.value), str(info.value)))
        # our factor on a key of the wrong type: the factor's ValuesIncorrectType, through ISAM2
        isam = cls()
        g = gtsam.NonlinearFactorGraph()
        g.add(F.PriorFactorPose3(0, gtsam.Pose3(), NOISE3))
        v = gtsam.Values()
        v.insert(0, gtsam.Pose2())
        with pytest.raises(Exception) as info:
            isam.update(g, v)
        outcomes.append((type(info.value), str(info.value)))
    assert outcomes[0] == outcomes[2] and outcomes[0][0] is Boom
    assert outcomes[1] == outcomes[3] and outcomes[1][0] is ValuesIncorrectType


#: Built once: lie_factors' factors are never freed (the C++ CustomFactor holds their bound
#: callback, which holds the Python object: a cycle the garbage collector cannot see), so
#: the lifetime tests reuse these instead of counting the factors' memory as the optimizer's.
SMALL_FACTORS = (F.PriorFactorPose2(0, gtsam.Pose2(), NOISE2),
                 F.BetweenFactorPose2(0, 1, gtsam.Pose2(1, 0, 0.1), NOISE2))


def _small_update(isam, *timestamps):
    g = gtsam.NonlinearFactorGraph()
    for f in SMALL_FACTORS:
        g.add(f)
    v = gtsam.Values()
    v.insert(0, gtsam.Pose2(0.1, 0, 0))
    v.insert(1, gtsam.Pose2(1.1, 0.2, 0))
    isam.update(g, v, *timestamps)
    return v


def test_dropped_dropin_is_freed_and_user_references_keep_working():
    Recording = _recording(F.BetweenFactorPose2)
    Recording.seen = []
    isam = ISAM2(params())
    g = gtsam.NonlinearFactorGraph()
    g.add(F.PriorFactorPose2(0, gtsam.Pose2(), NOISE2))
    g.add(Recording(0, 1, gtsam.Pose2(1, 0, 0.1), NOISE2))
    v = gtsam.Values()
    v.insert(0, gtsam.Pose2(0.1, 0, 0))
    v.insert(1, gtsam.Pose2(1.1, 0.2, 0))
    lp_before = isam.getLinearizationPoint()  # a user's own reference, taken before the update
    isam.update(g, v)
    estimate = isam.calculateEstimate()
    ref = weakref.ref(isam)
    del isam
    gc.collect()
    # The callback's object and the user's reference keep ISAM2 alive (pybind11 keep_alive)...
    assert ref() is not None
    held = Recording.seen[0]
    assert held is lp_before and held.size() == 2
    assert np.allclose(held.atPose2(1).matrix(), gtsam.Pose2(1.1, 0.2, 0).matrix())
    assert v.size() == 2 and estimate.size() == 2  # the user's own Values are untouched
    # ...and once they are gone it is freed: no cycle through the held wrapper.
    del held, lp_before
    Recording.seen.clear()
    gc.collect()
    assert ref() is None

    isam = ISAM2()
    _small_update(isam)
    isam.calculateEstimate()
    ref = weakref.ref(isam)
    del isam
    gc.collect()
    assert ref() is None


def _rss_kib() -> int:
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    raise AssertionError("no VmRSS in /proc/self/status")


def test_rss_flat_over_1000_create_drop_cycles():
    def cycle():
        isam = ISAM2(params())
        _small_update(isam)
        isam.calculateEstimatePose2(1)
        smoother = IncrementalFixedLagSmoother(1.0)
        _small_update(smoother, {0: 0.0, 1: 1.0})
        smoother.calculateEstimatePose2(1)
        del isam, smoother

    for _ in range(200):  # allocator and caches settle
        cycle()
    gc.collect()
    before = _rss_kib()
    for _ in range(1000):
        cycle()
    gc.collect()
    grown = _rss_kib() - before
    # A leaked ISAM2 with its graph is ~15 KiB: 1000 of them would be ~15 MiB.
    assert grown < 512, f"RSS grew by {grown} KiB over 1000 cycles"


def test_incremental_fixed_lag_smoother_matches_and_gets_one_object():
    Recording = _recording(F.BetweenFactorPose2)
    steps = online_pose2(40)
    results = []
    for cls in (gtsam.IncrementalFixedLagSmoother, IncrementalFixedLagSmoother):
        Recording.seen = []
        smoother = cls(3.0, params())
        ts = {}
        for i, (items, guess) in enumerate(steps):
            g = gtsam.NonlinearFactorGraph()
            for item in items:
                if item[0] == "prior":
                    g.add(F.PriorFactorPose2(item[1], item[2], NOISE2))
                elif item[2] - item[1] == 1:  # odometry only: loop closures reach outside the lag
                    g.add(Recording(item[1], item[2], item[3], NOISE2))
            v = gtsam.Values()
            v.insert(i, guess)
            smoother.update(g, v, {i: float(i)})
        est = smoother.calculateEstimate()
        results.append((est, list(Recording.seen), smoother))
    (a, seen_a, _), (b, seen_b, smoother) = results
    assert sorted(a.keys()) == sorted(b.keys()) and a.size() < len(steps)  # marginalized
    assert max_diff(a, b, "atPose2") <= 1e-9
    assert len(seen_a) == len(seen_b) > len(steps)
    assert len({id(v) for v in seen_a}) == len(seen_a)
    lp = smoother.getLinearizationPoint()
    assert all(v is lp for v in seen_b)
    ref = weakref.ref(smoother)
    del results, smoother, lp, seen_b, b
    Recording.seen = []
    gc.collect()
    assert ref() is None
