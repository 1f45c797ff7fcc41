"""Powell's dogleg in the batch solver (``gtsam.DoglegParams``) against GTSAM's ``DoglegOptimizer``,
and the dogleg policy (:mod:`lie_factors.dogleg`) against a from-scratch computation.

GTSAM's optimizer is stepped with ``iterate()`` on the same graph: the error, the trust-region
radius Δ and the iteration count after every iteration must be its, from starting radii that put
the first points in each of the three regions (steepest descent, blend, Gauss–Newton), with
every branch of the radius rule taken (recorded on the policy's functions).
"""

from __future__ import annotations

import math
from pathlib import Path

import gtsam
import numpy as np
import pytest

import lie_factors as lf
from lie_factors import dogleg, factors
from lie_factors.batch.optimizer import BatchLevenbergMarquardt
from lie_factors.errors import IndeterminantLinearSystem
from support.example_graphs import rosenbrock, spherical_sfm

ROOT = Path(__file__).resolve().parents[2]


def pose_graph(is3d: bool, ours: bool, far: float = 0.0):
    """smallGrid3D or w100 with a prior on the first pose, our factors or GTSAM's; ``far``: the
    start's poses perturbed by that much (0: the file's)."""
    if is3d:
        native, initial = gtsam.readG2o(str(ROOT / "data" / "smallGrid3D.g2o"), True)
    else:
        native, initial = gtsam.load2D(gtsam.findExampleDataFile("w100.graph"))
    group = "Pose3" if is3d else "Pose2"
    F = factors if ours else gtsam
    graph = gtsam.NonlinearFactorGraph()
    for i in range(native.size()):
        f = native.at(i)
        graph.add(getattr(F, f"BetweenFactor{group}")(*f.keys(), f.measured(), f.noiseModel()))
    first = min(initial.keys())
    at = getattr(initial, f"at{group}")
    graph.add(getattr(F, f"PriorFactor{group}")(first, at(first), gtsam.noiseModel.Isotropic.Sigma(6 if is3d else 3,
                                                                                                   1e-3)))
    if far:
        rng = np.random.default_rng(7)
        start = gtsam.Values()
        for key in initial.keys():
            start.insert(key, at(key).retract(rng.normal(0.0, far, 6 if is3d else 3)))
        initial = start
    return graph, initial


def params(delta0: float = 1.0):
    p = gtsam.DoglegParams()
    p.setDeltaInitial(delta0)
    return p


def steps(opt, n: int | None = None, p=None):
    """(iterations, error, Δ) before and after each iteration: ``n`` of them, or (``p``: the params)
    as many as ``optimize()`` runs (GTSAM's stopping rule)."""
    rows = [(opt.iterations(), opt.error(), opt.getDelta())]
    while n is None or len(rows) <= n:
        before = opt.error()
        opt.iterate()
        rows.append((opt.iterations(), opt.error(), opt.getDelta()))
        if n is None and (opt.iterations() >= p.getMaxIterations() or gtsam.checkConvergence(p, before, opt.error())):
            break
    return rows


def assert_same(ref, ours, atol: float = 0.0):
    assert [r[0] for r in ours] == [r[0] for r in ref]
    np.testing.assert_allclose([r[1] for r in ours], [r[1] for r in ref], rtol=1e-8, atol=atol)
    np.testing.assert_allclose([r[2] for r in ours], [r[2] for r in ref], rtol=1e-8, atol=0)


@pytest.fixture
def taken(monkeypatch):
    """The regions of the dogleg points computed and the radius rule's decisions, as they run."""
    seen = {"regions": set(), "rule": set()}
    point, rule = dogleg.dogleg_point, dogleg.next_radius

    def recording_point(radius, uu, nn, un, verbose=False):
        s_u, s_n = point(radius, uu, nn, un, verbose)
        seen["regions"].add("steepest descent" if s_n == 0.0 else "Gauss-Newton" if s_u == 0.0 else "blend")
        return s_u, s_n

    def recording_rule(rho, radius, norm):
        action, new = rule(rho, radius, norm)
        branch = ("grow" if rho >= 0.75 else "keep" if rho >= 0.25 else "shrink" if rho >= 0.0
                  else "retry" if action == dogleg.RETRY else "give up")
        seen["rule"].add(branch)
        return action, new

    monkeypatch.setattr(dogleg, "dogleg_point", recording_point)
    monkeypatch.setattr(dogleg, "next_radius", recording_rule)
    return seen


@pytest.mark.parametrize("is3d", [True, False], ids=["Pose3", "Pose2"])
@pytest.mark.parametrize("ours", [True, False], ids=["our-factors", "gtsam-factors"])
@pytest.mark.parametrize("delta0, far", [(1.0, 0.0), (1e-3, 0.0), (100.0, 0.0), (1.0, 0.5)])
@pytest.mark.parametrize("linear_solver", ["cholmod", "gtsam"])
def test_iterations_are_gtsams(is3d, ours, delta0, far, linear_solver, taken):
    """Every iteration of GTSAM's ``optimize()``.  With GTSAM's elimination the points are its Bayes
    tree's, as in GTSAM's dogleg; CHOLMOD's normal equations round otherwise (1e-15 of the error
    at the first step), and w100's Gauss–Newton steps from its start (38.5 → 0.61 in three)
    amplify that about a hundredfold a step: there the errors agree to 1e-9 of the initial one."""
    graph, initial = pose_graph(is3d, ours, far)
    ref = steps(gtsam.DoglegOptimizer(graph, initial, params(delta0)), p=params(delta0))
    mine = steps(BatchLevenbergMarquardt(graph, initial, params(delta0), linear_solver=linear_solver),
                 len(ref) - 1)
    # GTSAM's own Pose2 factors are evaluated by their twin kinds, whose Jacobians are exact where
    # GTSAM's lose digits (residual angles below about 1e-3): to 1e-9 of the initial error there too
    near = linear_solver == "cholmod" or (not ours and not is3d)
    assert_same(ref, mine, atol=1e-9 * ref[0][1] if near else 0.0)
    if delta0 == 100.0:
        assert taken["regions"] == {"Gauss-Newton"}


@pytest.mark.parametrize("start, delta0", [((-1.2, 1.0), 0.1), ((-1.2, 1.0), 1.0), ((-1.2, 1.0), 10.0),
                                           ((0.0, 5.0), 0.1), ((2.0, -1.0), 10.0)])
@pytest.mark.parametrize("linear_solver", ["cholmod", "gtsam"])
def test_rosenbrock_is_gtsams(start, delta0, linear_solver, taken):
    """Every iteration of GTSAM's ``optimize()`` from Rosenbrock's classic start (−1.2, 1) and two
    others: Δ grows, is kept, shrinks and a step is retried (each branch of the rule is taken from
    (−1.2, 1) at Δ₀ = 0.1 and 1), and the minimum, where the error is 0, is reached (errors below
    1e-12 of the initial one are rounding)."""
    graph, initial = rosenbrock(start)
    ref = steps(gtsam.DoglegOptimizer(graph, initial, params(delta0)), p=params(delta0))
    mine = steps(BatchLevenbergMarquardt(graph, initial, params(delta0), linear_solver=linear_solver), len(ref) - 1)
    assert_same(ref, mine, atol=1e-12 * ref[0][1])
    if start == (-1.2, 1.0) and delta0 < 10.0:
        assert {"grow", "keep", "shrink", "retry"} <= taken["rule"], taken


def test_spherical_camera_sfm_is_gtsams():
    """SFMExample_SphericalCamera's graph (GTSAM's own factors, no pose variable), through the front
    door: GTSAM's dogleg's iterations and optimum."""
    graph, initial = spherical_sfm()
    opt = gtsam.DoglegOptimizer(graph, initial, params())
    ref = [opt.error()]
    while True:
        before = opt.error()
        opt.iterate()
        ref.append(opt.error())
        if gtsam.checkConvergence(params(), before, opt.error()):
            break
    result = lf.optimize(graph, initial, params())
    assert result.iterations == opt.iterations()
    np.testing.assert_allclose(result.errors, ref, rtol=1e-8, atol=1e-12 * ref[0])
    assert result.group is None and len(result.keys) == initial.size()
    delta = opt.values().localCoordinates(result.values)
    assert max(np.max(np.abs(delta.at(k))) for k in initial.keys()) < 1e-9


@pytest.mark.parametrize("backend", ["batch", "dropin", "native"])
def test_every_backend_runs_dogleg(backend):
    graph, initial = pose_graph(True, backend != "native", far=0.2)
    p = params(0.5)
    reference = gtsam.DoglegOptimizer(graph, initial, p)
    values = reference.optimize()
    result = lf.optimize(graph, initial, p, backend=backend)
    assert result.iterations == reference.iterations()
    assert result.error == pytest.approx(float(graph.error(values)), rel=1e-8)


def test_a_free_gauge_is_refused_as_gtsams_dogleg_refuses_it(forbid_factorization):
    """Without the prior: GTSAM's dogleg raises on its elimination; ours on the graph's structure,
    before any factorization."""
    native, initial = pose_graph(True, False)
    ours, _ = pose_graph(True, True)
    free_native, free_ours = gtsam.NonlinearFactorGraph(), gtsam.NonlinearFactorGraph()
    for i in range(native.size() - 1):
        free_native.add(native.at(i))
        free_ours.add(ours.at(i))
    with pytest.raises(RuntimeError, match="Indeterminate"):
        gtsam.DoglegOptimizer(free_native, initial).optimize()
    forbid_factorization()
    with pytest.raises(IndeterminantLinearSystem, match=r"^Dogleg: the linear system is singular"):
        lf.optimize(free_ours, initial, params())


# ---------------------------------------------------------------------------- the policy
def _point(radius, u, n):
    """The dogleg point from scratch: the boundary point of the path 0 → u → n."""
    if radius < np.linalg.norm(u):
        return radius / np.linalg.norm(u) * u
    if radius < np.linalg.norm(n):
        # bisection on the segment u → n for ‖(1 − τ)u + τn‖ = radius (the norm grows along it here)
        lo, hi = 0.0, 1.0
        for _ in range(200):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if np.linalg.norm((1 - mid) * u + mid * n) < radius else (lo, mid)
        return (1 - lo) * u + lo * n
    return n


@pytest.mark.parametrize("radius", [0.5 * (1 - 1e-12), 0.5, 0.5 * (1 + 1e-12), 1.0, 2.0 * (1 - 1e-12), 2.0, 3.0])
def test_dogleg_point_is_the_paths_boundary_point(radius):
    """‖u‖ = 0.5, ‖n‖ = 2: radii on both sides of each region's edge."""
    u = np.array([0.3, 0.4, 0.0])
    n = np.array([1.2, 1.2, 0.0]) + np.array([0.0, 0.0, math.sqrt(4.0 - 2.88)])
    s_u, s_n = dogleg.dogleg_point(radius, u @ u, n @ n, u @ n)
    np.testing.assert_allclose(s_u * u + s_n * n, _point(radius, u, n), rtol=1e-12, atol=1e-15)
    if 0.5 <= radius < 2.0:
        assert math.hypot(*(s_u * u + s_n * n)) == pytest.approx(radius, rel=1e-14)


@pytest.mark.parametrize("f, m, rho", [(1.0, 4.0, 0.25), (0.9e-15, 4.0, 0.5), (-0.9e-15, 4.0, 0.5),
                                       (1.1e-15, 4.4e-15, 0.25), (-3.0, 2.0, -1.5), (3.0, 0.9e-15, 0.5),
                                       (3.0, 1.1e-15, 3.0 / 1.1e-15)])
def test_gain_ratio_is_half_where_a_change_is_below_1e_15(f, m, rho):
    assert dogleg.gain_ratio(f, m) == pytest.approx(rho, rel=1e-15)


@pytest.mark.parametrize("rho, radius, action, new", [
    (0.75, 1.0, "take", 3.0), (0.75 - 1e-12, 1.0, "take", 1.0), (0.8, 5.0, "take", 5.0),
    (0.25, 1.0, "take", 1.0), (0.25 - 1e-12, 1.0, "take", 0.5), (0.0, 1.0, "take", 0.5),
    (0.1, 1e-5, "take", 1e-5), (0.1, 1e-5 * (1 + 1e-12), "take", 0.5e-5 * (1 + 1e-12)),
    (-1e-300, 1.0, "retry", 0.5), (float("nan"), 1.0, "retry", 0.5),
    (-1.0, 1e-5, "give up", 1e-5), (-1.0, 1e-5 * (1 + 1e-12), "retry", 0.5e-5 * (1 + 1e-12)),
])
def test_the_radius_rule_straddles_its_thresholds(rho, radius, action, new):
    """GTSAM's ONE_STEP_PER_ITERATION rule, the step's norm 1: Δ ← max(Δ, 3) at ρ ≥ 0.75, kept at
    0.25 ≤ ρ < 0.75, halved above Δ = 1e-5 at 0 ≤ ρ < 0.25; ρ < 0 (or NaN) retries, down to 1e-5."""
    got_action, got = dogleg.next_radius(rho, radius, 1.0)
    assert (got_action, got) == (action, pytest.approx(new, rel=1e-15))
