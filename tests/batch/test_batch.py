"""lie_factors.batch against GTSAM's own Levenberg–Marquardt.

Two references on every graph: GTSAM's C++ LM on the *same* lie_factors factors
(the custom-factor path) and GTSAM's LM on GTSAM's native factors with the same
measurements and noise models.  Small graphs (loops with noisy closures) for
each group, a mixed graph (native factors, a non-group variable, a robust
lie_factors factor), the params semantics and the bad-input errors.
"""

from __future__ import annotations

from pathlib import Path

import gtsam
import numpy as np
import pytest

from lie_factors import batch, factors
from lie_factors.expressions.ready import from_gtsam
from lie_factors.errors import IndeterminantLinearSystem, InputError
from lie_factors.sparse.pattern import Pattern

RNG_SEED = 20261121
DATA = Path(__file__).resolve().parents[2] / "data"


def _noise(dim, rng):
    # A full-covariance Gaussian for some factors, diagonal for others: both whitening paths.
    sig = rng.uniform(0.05, 0.2, size=dim)
    return gtsam.noiseModel.Diagonal.Sigmas(sig)


def _full_noise(dim, rng):
    L = np.tril(rng.normal(scale=0.02, size=(dim, dim))) + np.diag(rng.uniform(0.05, 0.15, size=dim))
    return gtsam.noiseModel.Gaussian.Covariance(L @ L.T)


def _random_element(group, rng, scale=1.0):
    if group == "Pose3":
        return gtsam.Pose3.Expmap(scale * rng.normal(size=6))
    if group == "Rot3":
        return gtsam.Rot3.Expmap(scale * rng.normal(size=3))
    if group == "Pose2":
        return gtsam.Pose2.Expmap(scale * rng.normal(size=3))
    if group == "Similarity2":
        return gtsam.Similarity2.Expmap(scale * rng.normal(size=4) * np.array([1, 1, 1, 0.3]))
    if group == "Similarity3":
        return gtsam.Similarity3.Expmap(scale * rng.normal(size=7) * np.array([1, 1, 1, 1, 1, 1, 0.3]))
    raise AssertionError(group)


def _retract(value, xi):
    return value.compose(type(value).Expmap(xi))


DIMS = {"Pose3": 6, "Rot3": 3, "Pose2": 3, "Similarity2": 4, "Similarity3": 7}


def make_problem(group, n=12, seed=RNG_SEED, full=False):
    """(lie graph, native graph, initial): a ring with chords, noisy initial guess."""
    rng = np.random.default_rng(seed)
    d = DIMS[group]
    truth = [_random_element(group, rng, 0.8) for _ in range(n)]
    edges = [(i, i + 1) for i in range(n - 1)] + [(0, n - 1)] + [(a, b) for a, b in ((2, 7), (3, 9)) if b < n]
    lie, native = gtsam.NonlinearFactorGraph(), gtsam.NonlinearFactorGraph()
    LB = getattr(factors, f"BetweenFactor{group}")
    NB = getattr(gtsam, f"BetweenFactor{group}")
    for a, b in edges:
        z = truth[a].between(truth[b])
        z = _retract(z, rng.normal(scale=0.05, size=d))
        nm = _full_noise(d, rng) if (full and a % 2) else _noise(d, rng)
        lie.add(LB(a, b, z, nm))
        native.add(NB(a, b, z, nm))
    prior_nm = gtsam.noiseModel.Isotropic.Sigma(d, 0.01)
    lie.add(getattr(factors, f"PriorFactor{group}")(0, truth[0], prior_nm))
    native.add(getattr(gtsam, f"PriorFactor{group}")(0, truth[0], prior_nm))
    initial = gtsam.Values()
    for i, t in enumerate(truth):
        initial.insert(i, _retract(t, rng.normal(scale=0.3, size=d)))
    return lie, native, initial


def _gtsam_lm(graph, initial, params=None):
    params = params or gtsam.LevenbergMarquardtParams()
    opt = gtsam.LevenbergMarquardtOptimizer(graph, initial, params)
    values = opt.optimize()
    return values, opt.iterations(), graph.error(values)


def _stepwise_errors(opt, params, lambdas=None):
    """GTSAM's error after each iteration of ``opt`` (the initial one first), stepped as
    ``NonlinearOptimizer::defaultOptimize`` does; LM's λ after each appended to ``lambdas``."""
    errors = [opt.error()]
    if lambdas is not None:
        lambdas.append(opt.lambda_())
    while True:
        cur = opt.error()
        opt.iterate()
        errors.append(opt.error())
        if lambdas is not None:
            lambdas.append(opt.lambda_())
        if opt.iterations() >= params.getMaxIterations() or gtsam.checkConvergence(params, cur, opt.error()):
            return errors


def _max_diff(group, a: gtsam.Values, b: gtsam.Values):
    at = {"Pose3": "atPose3", "Rot3": "atRot3", "Pose2": "atPose2", "Similarity2": "atSimilarity2",
          "Similarity3": "atSimilarity3"}[group]
    return max(np.abs(getattr(a, at)(k).matrix() - getattr(b, at)(k).matrix()).max() for k in a.keys())


@pytest.mark.parametrize("linear_solver", ["cholmod", "gtsam"])
@pytest.mark.parametrize("group", ["Pose3", "Pose2", "Rot3", "Similarity2", "Similarity3"])
def test_matches_custom_and_native_lm(group, linear_solver):
    lie, native, initial = make_problem(group, full=True)
    v_custom, it_custom, e_custom = _gtsam_lm(lie, initial)
    v_native, it_native, e_native = _gtsam_lm(native, initial)
    res = batch.optimize(lie, initial, linear_solver=linear_solver)
    assert res.linear_solver == linear_solver
    assert res.iterations == it_custom
    assert res.final_error == pytest.approx(e_custom, rel=1e-9, abs=1e-12)
    assert lie.error(res.values) == pytest.approx(res.final_error, rel=1e-9, abs=1e-12)
    assert _max_diff(group, res.values, v_custom) < 1e-7
    if group in ("Similarity2", "Similarity3"):
        # GTSAM's native Similarity2 Jacobians are inexact (see docs/errata.md): its LM can
        # stop at a slightly worse point; for both similarity groups ours must be at least as good.
        assert res.final_error <= e_native * (1 + 1e-9)
    else:
        assert res.final_error == pytest.approx(e_native, rel=1e-6, abs=1e-12)
        assert _max_diff(group, res.values, v_native) < 1e-6
    assert res.converged
    assert len(res.errors) == res.iterations + 1
    assert res.errors[0] == pytest.approx(lie.error(initial), rel=1e-12)
    assert all(b <= a for a, b in zip(res.errors, res.errors[1:]))


@pytest.mark.parametrize("linear_solver", ["cholmod", "gtsam"])
@pytest.mark.parametrize("diagonal", [False, True])
def test_lambda_sequence_matches_gtsam(diagonal, linear_solver):
    lie, _, initial = make_problem("Pose3", seed=7)
    params = gtsam.LevenbergMarquardtParams()
    params.setDiagonalDamping(diagonal)
    params.setlambdaInitial(1e3)  # start far from Gauss-Newton: exercises λ updates
    opt = gtsam.LevenbergMarquardtOptimizer(lie, initial, params)
    lambdas = []
    errors = _stepwise_errors(opt, params, lambdas)
    res = batch.optimize(lie, initial, params, linear_solver=linear_solver)
    assert res.iterations == opt.iterations()
    np.testing.assert_allclose(res.errors, errors, rtol=1e-8)
    np.testing.assert_allclose(res.lambdas, lambdas, rtol=1e-12)


@pytest.mark.parametrize("linear_solver", ["cholmod", "gtsam"])
def test_mixed_graph_native_factors_and_other_variables(linear_solver):
    lie, native, initial = make_problem("Pose3", seed=3)
    rng = np.random.default_rng(5)
    # Native factors on managed keys, a Point3 variable only native factors touch,
    # and a lie_factors factor with a robust model (linearized through GTSAM).
    z = initial.atPose3(4).between(initial.atPose3(6))
    nm = gtsam.noiseModel.Isotropic.Sigma(6, 0.5)
    huber = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(1.0), nm)
    L = gtsam.symbol("l", 1)
    extra = [
        (gtsam.BetweenFactorPose3(4, 6, z, nm), gtsam.BetweenFactorPose3(4, 6, z, nm)),
        (factors.BetweenFactorPose3(5, 8, initial.atPose3(5).between(initial.atPose3(8)), huber),
         gtsam.BetweenFactorPose3(5, 8, initial.atPose3(5).between(initial.atPose3(8)), huber)),
        (gtsam.PriorFactorPoint3(L, np.array([1.0, 2.0, 3.0]), gtsam.noiseModel.Isotropic.Sigma(3, 0.1)),) * 2,
        (gtsam.BetweenFactorPoint3(L, gtsam.symbol("l", 2), np.array([0.5, 0, 0]),
                                   gtsam.noiseModel.Isotropic.Sigma(3, 0.1)),) * 2,
    ]
    for a, b in extra:
        lie.add(a)
        native.add(b)
    initial.insert(L, np.array([1.2, 1.9, 3.3]))
    initial.insert(gtsam.symbol("l", 2), rng.normal(size=3))
    _, it_custom, e_custom = _gtsam_lm(lie, initial)
    v_native, _, e_native = _gtsam_lm(native, initial)
    res = batch.optimize(lie, initial, linear_solver=linear_solver)
    assert res.iterations == it_custom
    assert res.final_error == pytest.approx(e_custom, rel=1e-9)
    assert res.final_error == pytest.approx(e_native, rel=1e-6)
    assert res.values.size() == initial.size()
    np.testing.assert_allclose(res.values.atPoint3(gtsam.symbol("l", 2)),
                               v_native.atPoint3(gtsam.symbol("l", 2)), atol=1e-6)


def test_all_native_graph_works():
    _, native, initial = make_problem("Pose2", seed=11)
    res = batch.optimize(native, initial)
    _, it, e = _gtsam_lm(native, initial)
    assert res.iterations == it
    assert res.final_error == pytest.approx(e, rel=1e-9)


def test_max_iterations_respected_and_silent_by_default(capfd):
    lie, _, initial = make_problem("Pose2", seed=2)
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(1)
    params.setlambdaInitial(1e4)
    res = batch.optimize(lie, initial, params)
    assert res.iterations == 1
    assert not res.converged
    params.setMaxIterations(0)
    res0 = batch.optimize(lie, initial, params)
    assert res0.iterations == 0 and res0.errors == [pytest.approx(lie.error(initial))]
    res_default = batch.optimize(lie, initial)
    assert res_default.converged
    out, err = capfd.readouterr()
    assert out == "" and err == ""


def test_error_tol_stops_immediately():
    lie, _, initial = make_problem("Rot3", seed=4)
    params = gtsam.LevenbergMarquardtParams()
    params.setErrorTol(1e30)
    res = batch.optimize(lie, initial, params)
    assert res.iterations == 0 and res.converged


def test_values_conversion_is_exact():
    lie, _, initial = make_problem("Pose3", seed=9)
    opt = batch.BatchLevenbergMarquardt(lie, initial)
    opt.iterate()
    out = opt.values()
    X = opt.blocks["Pose3"].X
    for j, k in enumerate(opt.blocks["Pose3"].keys):
        assert np.abs(out.atPose3(k).matrix() - X[j]).max() < 1e-13


def test_iterate_and_class_api():
    lie, _, initial = make_problem("Similarity2", seed=8)
    opt = batch.BatchLevenbergMarquardt(lie, initial)
    e0 = opt.error()
    opt.iterate()
    assert opt.iterations() == 1 and opt.error() < e0
    assert opt.values().size() == initial.size()


def test_missing_key_names_it():
    lie, _, initial = make_problem("Pose3", n=6, seed=1)
    X = gtsam.symbol("x", 3)
    lie.add(factors.BetweenFactorPose3(2, X, gtsam.Pose3(), gtsam.noiseModel.Unit.Create(6)))
    with pytest.raises(InputError, match="x3.*missing"):
        batch.optimize(lie, initial)


def test_missing_key_of_native_factor_names_it():
    lie, _, initial = make_problem("Pose2", n=6, seed=1)
    lie.add(gtsam.PriorFactorPoint2(gtsam.symbol("p", 7), np.zeros(2), gtsam.noiseModel.Unit.Create(2)))
    with pytest.raises(InputError, match="p7.*missing"):
        batch.optimize(lie, initial)


def test_wrong_value_type_names_key():
    lie, _, initial = make_problem("Pose2", n=6, seed=1)
    initial.erase(3)
    initial.insert(3, gtsam.Pose3())
    with pytest.raises(InputError, match="key 3 must hold a gtsam.Pose2"):
        batch.optimize(lie, initial)


def test_factor_that_cannot_be_evaluated_names_type():
    lie, _, initial = make_problem("Pose2", n=6, seed=1)

    def broken(this, values, H):
        raise ValueError("no")

    lie.add(gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(3), [1], broken))
    with pytest.raises(InputError, match="CustomFactor"):
        batch.optimize(lie, initial)


def test_bad_argument_types():
    with pytest.raises(TypeError, match="NonlinearFactorGraph"):
        batch.optimize([], gtsam.Values())
    with pytest.raises(TypeError, match="Values"):
        batch.optimize(gtsam.NonlinearFactorGraph(), {})


def test_front_door_runs_the_batch_solver_on_a_gtsam_graph():
    import lie_factors as lf
    from lie_factors.lm import IterationInfo

    lie, _, initial = make_problem("Pose2", seed=6)
    seen = []

    class Events(lf.Events):
        def iteration(self, info):
            seen.append(info)

    res = lf.optimize(lie, initial, max_iterations=50, events=Events())
    ref = batch.optimize(lie, initial)
    assert res.iterations == len(seen) == ref.iterations and all(isinstance(s, IterationInfo) for s in seen)
    assert res.error == pytest.approx(lie.error(res.values), rel=1e-9)
    assert res.error == ref.final_error and res.converged


def _landmark_graph(is3d, seed=21, landmarks=5):
    """A pose ring (lie_factors factors) observing Point2/Point3 landmarks with GTSAM's BearingRange factors."""
    group = "Pose3" if is3d else "Pose2"
    lie, native, initial = make_problem(group, n=8, seed=seed)
    rng = np.random.default_rng(seed)
    d = 3 if is3d else 2
    Factor = gtsam.BearingRangeFactor3D if is3d else gtsam.BearingRangeFactor2D
    nm = gtsam.noiseModel.Isotropic.Sigma(3 if is3d else 2, 0.05)  # (bearing, range)
    at = initial.atPose3 if is3d else initial.atPose2
    for j in range(landmarks):
        L = gtsam.symbol("l", j)
        p = rng.normal(scale=2.0, size=d)
        for i in rng.choice(8, size=3, replace=False):
            pose = at(int(i))
            f = Factor(int(i), L, pose.bearing(p), pose.range(p), nm)
            lie.add(f)
            native.add(f)
        initial.insert(L, p + rng.normal(scale=0.1, size=d))
    if is3d:
        f = gtsam.BetweenFactorPoint3(gtsam.symbol("l", 0), gtsam.symbol("l", 1),
                                      initial.atPoint3(gtsam.symbol("l", 1)) - initial.atPoint3(gtsam.symbol("l", 0)),
                                      gtsam.noiseModel.Isotropic.Sigma(3, 0.3))
        lie.add(f)
        native.add(f)
    return lie, native, initial


@pytest.mark.parametrize("linear_solver", ["cholmod", "gtsam"])
@pytest.mark.parametrize("is3d", [False, True])
def test_landmarks_point2_point3(is3d, linear_solver):
    lie, native, initial = _landmark_graph(is3d)
    params = gtsam.LevenbergMarquardtParams()
    # the batch solver evaluates GTSAM's bearing-range factors by their twin kinds, whose 3-D
    # Jacobians are exact where GTSAM's are not: GTSAM's steps with the ready factors equal to them
    opt = gtsam.LevenbergMarquardtOptimizer(_with_ready_factors(lie), initial, params)
    errors = _stepwise_errors(opt, params)
    res = batch.optimize(lie, initial, params, linear_solver=linear_solver)
    assert res.iterations == opt.iterations()
    np.testing.assert_allclose(res.errors, errors, rtol=1e-6)
    v = opt.values()
    for j in range(5):
        L = gtsam.symbol("l", j)
        got = res.values.atPoint3(L) if is3d else res.values.atPoint2(L)
        want = v.atPoint3(L) if is3d else v.atPoint2(L)
        np.testing.assert_allclose(got, want, atol=1e-6)


def _with_ready_factors(graph):
    """``graph`` with each of GTSAM's bearing-range, range or GPS factors as the ready factor equal
    to it (the same error; exact Jacobians where GTSAM's BearingRangeFactor3D's are not)."""
    out = gtsam.NonlinearFactorGraph()
    for i in range(graph.size()):
        out.add(from_gtsam(graph.at(i)))
    return out


def test_assembled_system_equals_gtsam_hessian_with_weights():
    """H and g (with per-factor weights) against GTSAM's linearization of each factor (of the
    ready factor equal to a GTSAM bearing-range one: the batch solver's twin of it)."""
    lie, _, initial = _landmark_graph(True, seed=4)
    opt = batch.BatchLevenbergMarquardt(lie, initial)
    rng = np.random.default_rng(1)
    w = rng.uniform(0.0, 2.0, size=lie.size())
    w[3] = 0.0
    opt.system.weights[:] = w
    opt.problem.linearize()
    opt.system.assemble()
    P = opt.problem
    n = P.total_dim
    H = np.zeros((n, n))
    g = np.zeros(n)
    for i in range(lie.size()):
        lf = from_gtsam(lie.at(i)).linearize(initial)
        A, b = lf.jacobian()
        J = np.zeros((A.shape[0], n))
        c = 0
        for k in lf.keys():
            o, d = P.offset[int(k)], int(P.var_dims[P.var_index[int(k)]])
            J[:, o:o + d] = A[:, c:c + d]
            c += d
        H += w[i] * J.T @ J
        g += w[i] * J.T @ b
    got = opt.system.to_dense()
    scale = np.abs(H).max()
    assert np.abs(got - H).max() < 1e-10 * scale
    np.testing.assert_allclose(opt.system.rhs, g, rtol=1e-9, atol=1e-9 * np.abs(g).max())
    # the per-factor residual hook: squared whitened norms, 2·error() each
    sq = np.empty(lie.size())
    total = P.error(sq_out=sq)
    np.testing.assert_allclose(sq, [2 * lie.at(i).error(initial) for i in range(lie.size())], rtol=1e-10)
    assert total == pytest.approx(lie.error(initial), rel=1e-12)


@pytest.mark.parametrize("batch_size", [1, 4, 7, 10_000])
def test_linearize_assemble_in_batches_equals_linearize_then_assemble(batch_size, monkeypatch):
    """The batched path (a buffer of ``BATCH`` factors) gives H, g, the factors' squared norms and
    the error of the whole-graph path, bit for bit, native factors and weights included; the
    groups' whole-graph Jacobians are never allocated."""
    from lie_factors.batch import system as system_module

    lie, _, initial = _landmark_graph(True, seed=4)
    whole = batch.BatchLevenbergMarquardt(lie, initial, linear_solver="gtsam")
    batched = batch.BatchLevenbergMarquardt(lie, initial)
    w = np.random.default_rng(2).uniform(0.0, 2.0, size=lie.size())
    w[5] = 0.0
    for opt in (whole, batched):
        opt.system.weights[:] = w
    error = whole.problem.linearize()
    whole.system.assemble()
    monkeypatch.setattr(system_module, "BATCH", batch_size)
    got, seconds_lin, seconds_asm = batched.system.linearize_assemble()
    assert got == error and seconds_lin >= 0 and seconds_asm >= 0
    assert batched.system.data.tobytes() == whole.system.data.tobytes()
    assert batched.system.rhs.tobytes() == whole.system.rhs.tobytes()
    assert batched.problem.linearized_sqnorms().tobytes() == whole.problem.linearized_sqnorms().tobytes()
    assert batched.system.hessian_diagonal().tobytes() == whole.system.hessian_diagonal().tobytes()
    assert all(g.A1 is None and g.b is None for g in batched.problem.groups)
    # the same run either way (CHOLMOD factors the same matrix)
    a = batch.optimize(lie, initial)
    monkeypatch.setattr(system_module, "BATCH", 10_000)
    b = batch.optimize(lie, initial)
    assert a.errors == b.errors


@pytest.mark.parametrize("linear_solver", ["cholmod", "gtsam"])
def test_gauss_newton_matches_gtsam(linear_solver):
    lie, _, initial = _landmark_graph(False, seed=9)
    params = gtsam.GaussNewtonParams()
    opt = gtsam.GaussNewtonOptimizer(lie, initial, params)
    errors = _stepwise_errors(opt, params)
    res = batch.optimize(lie, initial, params, linear_solver=linear_solver)
    assert res.iterations == opt.iterations()
    np.testing.assert_allclose(res.errors, errors, rtol=1e-6)
    assert set(res.lambdas) == {0.0}


@pytest.mark.parametrize("linear_solver", ["cholmod", "gtsam"])
def test_gauss_newton_without_prior_is_indeterminant(linear_solver, forbid_factorization):
    lie, native, initial = make_problem("Pose3", seed=5)
    # LM's damping makes the system solvable: the result is finite.
    for graph in (lie, native):
        gauge_free = gtsam.NonlinearFactorGraph()
        for i in range(graph.size()):
            if not isinstance(graph.at(i), (factors.PriorFactor, gtsam.PriorFactorPose3)):
                gauge_free.add(graph.at(i))
        res = batch.optimize(gauge_free, initial, linear_solver=linear_solver)
        assert np.isfinite(res.final_error) and res.final_error < res.errors[0]
    # Gauss–Newton refuses it on its structure, before any factorization
    forbid_factorization()
    free = r"^Gauss-Newton: the linear system is singular: the component of 0 \(12 variables\) has no prior: " \
           r"its gauge is free$"
    with pytest.raises(IndeterminantLinearSystem, match=free) as info:
        batch.optimize(gauge_free, initial, gtsam.GaussNewtonParams(), linear_solver=linear_solver)
    assert info.value.variable == 0
    import lie_factors as lf

    with pytest.raises(IndeterminantLinearSystem, match=free):
        lf.optimize(gauge_free, initial, gtsam.GaussNewtonParams(), linear_solver=linear_solver)


def test_gauge_free_intel_gauss_newton_refused_on_its_structure_levenberg_marquardt_solves_it(
        forbid_factorization):
    """GTSAM's Gauss–Newton raises on intel without a prior and its LM solves it; so do ours, GN
    on the graph's structure (no factorization runs, so no rounding decides)."""
    import lie_factors as lf

    pg = lf.read_g2o(str(DATA / "intel.g2o"))
    free = pg.factor_graph()
    with pytest.raises(RuntimeError, match="Indeterminate linear system"):
        gtsam.GaussNewtonOptimizer(free, pg.initial).optimize()
    reference = free.error(gtsam.LevenbergMarquardtOptimizer(free, pg.initial).optimize())
    for graph in (free, pg.factor_graph(factors)):
        res = batch.optimize(graph, pg.initial)
        assert res.final_error == pytest.approx(reference, rel=1e-8)
    forbid_factorization()
    for graph in (free, pg.factor_graph(factors)):
        with pytest.raises(IndeterminantLinearSystem, match=r"the component of 0 \(1728 variables\) has no prior"):
            batch.optimize(graph, pg.initial, gtsam.GaussNewtonParams())


def _two_poses(w: float):
    """x0 and x1 at the identity, a between factor (identity) of unit information and a prior
    (identity) of information w·I on x0: each scalar of Λ is [[1 + w, −1], [−1, 1]]."""
    X0, X1 = gtsam.symbol("x", 0), gtsam.symbol("x", 1)
    graph = gtsam.NonlinearFactorGraph()
    graph.add(factors.BetweenFactorPose2(X0, X1, gtsam.Pose2(), gtsam.noiseModel.Unit.Create(3)))
    graph.add(factors.PriorFactorPose2(X0, gtsam.Pose2(), gtsam.noiseModel.Gaussian.Information(w * np.eye(3))))
    values = gtsam.Values()
    values.insert(X0, gtsam.Pose2())
    values.insert(X1, gtsam.Pose2())
    return graph, values


@pytest.mark.parametrize("w, refused", [(1e-14, True), (1e-12, False)])
def test_gauss_newton_refuses_a_pivot_not_above_1e_13_of_its_diagonal_entry(w, refused, cholmod_way):
    """The pivot of x1 (x0 eliminated first) is 1 − 1/(1 + w) of its diagonal 1, that of x0 (x1
    first) (1 + w) − 1 of 1 + w: w/(1 + w) either way, rounded by about 2e-16.  w = 1e-14 is
    refused by the pivot rule (10 times past 1e-13), w = 1e-12 is not (10 times inside), on
    any machine.  (The poses are the optimum: errorTol −1 makes Gauss–Newton iterate.)"""
    graph, values = _two_poses(w)
    params = gtsam.GaussNewtonParams()
    params.setErrorTol(-1.0)
    if refused:
        with pytest.raises(IndeterminantLinearSystem, match=r"^Gauss-Newton: the linear system is singular near "
                                                            r"variable x[01]: .* to double precision") as info:
            batch.optimize(graph, values, params, linear_solver="cholmod")
        assert info.value.variable in (0, 1)
    else:
        res = batch.optimize(graph, values, params, linear_solver="cholmod")
        assert res.iterations == 1 and res.final_error == 0.0


def test_levenberg_marquardt_keeps_the_sign_rule(cholmod_way):
    """GTSAM's LM counts a factorization as failed only where a pivot is not positive.  On the two
    poses with w = 1e-14 and λ starting at 1e-30, the gauge's pivot is about 1e-14 of its
    diagonal entry: positive (far above the rounding, 2e-16), below the 1e-13 Gauss–Newton
    refuses.  Every λ tried is accepted and λ only decreases, as with the sign rule; the rule of
    Gauss–Newton would have failed the first tries and raised λ."""
    graph, values = _two_poses(1e-14)
    values.update(gtsam.symbol("x", 1), gtsam.Pose2(0.1, 0.05, 0.02))
    params = gtsam.LevenbergMarquardtParams()
    params.setlambdaInitial(1e-30)
    res = batch.optimize(graph, values, params, linear_solver="cholmod")
    assert res.inner_iterations == res.iterations >= 1
    assert all(b < a for a, b in zip(res.lambdas, res.lambdas[1:]))
    assert res.final_error < 1e-15


def test_gauss_newton_refuses_a_variable_with_fewer_rows_than_its_dimension(forbid_factorization):
    """x2 (Pose2) is only in a CustomFactor of one row; a key in no factor is left where it is,
    as GTSAM's Gauss–Newton leaves it."""
    X = lambda i: gtsam.symbol("x", i)  # noqa: E731
    unit = gtsam.noiseModel.Unit.Create(3)
    graph = gtsam.NonlinearFactorGraph()
    graph.add(factors.PriorFactorPose2(X(0), gtsam.Pose2(), unit))
    graph.add(factors.BetweenFactorPose2(X(0), X(1), gtsam.Pose2(1.0, 0.0, 0.0), unit))
    values = gtsam.Values()
    for i in range(3):
        values.insert(X(i), gtsam.Pose2(float(i), 0.1, 0.0))
    res = batch.optimize(graph, values, gtsam.GaussNewtonParams())
    reference = gtsam.GaussNewtonOptimizer(graph, values, gtsam.GaussNewtonParams()).optimize()
    assert res.values.atPose2(X(2)).equals(reference.atPose2(X(2)), 0.0)
    assert res.final_error == pytest.approx(graph.error(reference), abs=1e-12)

    def y_error(this, v, H):
        if H is not None:
            H[0] = np.array([[0.0, 1.0, 0.0]])
        return np.array([v.atPose2(X(2)).y()])

    graph.add(gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(1), [X(2)], y_error))
    forbid_factorization()
    with pytest.raises(IndeterminantLinearSystem, match="singular: x2 has 1 row of factors for its 3 dimensions") \
            as info:
        batch.optimize(graph, values, gtsam.GaussNewtonParams())
    assert info.value.variable == 2


def test_unknown_linear_solver_rejected():
    lie, _, initial = make_problem("Pose2", n=5, seed=1)
    with pytest.raises(InputError, match="linear_solver"):
        batch.optimize(lie, initial, linear_solver="lu")


@pytest.mark.parametrize("order", [None, [3, 1, 0, 2], [0, 1, 2, 3]])
def test_pattern_scatter_map_addresses_csc_entries(order):
    """Every entry of every stored block has one place in the lower-triangle CSC, where the
    pattern's rows and columns say it is, in the given order of the blocks (default: CHOLMOD's)."""
    dims = np.array([3, 6, 2, 6])
    pat = Pattern(dims, np.array([[0, 3], [2, 1], [3, 0]]), None if order is None else np.array(order))
    if order is not None:
        assert pat.order.tolist() == order
    assert sorted(pat.order.tolist()) == [0, 1, 2, 3] and np.all(pat.position[pat.order] == np.arange(4))
    column_of = np.empty(pat.n, dtype=np.int64)  # δ index → matrix column
    column_of[pat.scalar_order] = np.arange(pat.n)
    seen = []
    for a, b in [(3, 0), (2, 1), (0, 0), (1, 1), (2, 2), (3, 3)]:
        base, stride, a_is_row = pat.lookup(np.array([a]), np.array([b]))
        row, col = (a, b) if a_is_row[0] else (b, a)
        assert pat.position[row] >= pat.position[col]
        for j in range(dims[col]):
            for i in range(j if row == col else 0, dims[row]):
                p = base[0] + j * stride[0] - j * (j + 1) // 2 + i
                c = column_of[pat.offsets[col] + j]
                assert pat.colptr[c] <= p < pat.colptr[c + 1]
                assert pat.scalar_order[pat.rowind[p]] == pat.offsets[row] + i
                seen.append(int(p))
    assert sorted(seen) == list(range(pat.nnz))  # every stored entry, once
    assert pat.nnz == 6 + 21 + 3 + 21 + 3 * 6 + 2 * 6
    cols = pat.colind()
    assert np.all(pat.rowind >= cols) and pat.rowind.dtype == np.int32 and pat.colptr.dtype == np.int32
    assert np.all((np.diff(pat.rowind) > 0) | (np.diff(cols) > 0))  # rows sorted within columns
    assert np.all(pat.rowind[pat.diagpos] == column_of) and np.all(cols[pat.diagpos] == column_of)


def test_pardiso_solver_matches_cholmod():
    """The optional MKL PARDISO backend (extra "pardiso") gives CHOLMOD's run."""
    pytest.importorskip("pypardiso")  # optional extra, not installed by .[test]
    lie, _, initial = _landmark_graph(True, seed=3)
    a = batch.optimize(lie, initial, linear_solver="cholmod")
    b = batch.optimize(lie, initial, linear_solver="pardiso")
    assert b.linear_solver == "pardiso" and a.iterations == b.iterations
    np.testing.assert_allclose(b.errors, a.errors, rtol=1e-9)


def test_falls_back_to_gtsam_without_cvxopt_and_says_so_once(monkeypatch):
    from lie_factors.batch import small, solvers

    monkeypatch.setattr(solvers, "cholmod_available", lambda: False)
    monkeypatch.setattr(solvers, "_fallback_warned", False)
    lie, _, initial = make_problem("Pose2", n=6, seed=2)
    import warnings

    with warnings.catch_warnings():  # the small path factors in compiled code: it needs no CHOLMOD
        warnings.simplefilter("error")
        assert batch.optimize(lie, initial).linear_solver == "small"
    monkeypatch.setattr(small, "MAX_UNKNOWNS", 0)  # the general path from here on
    with pytest.warns(RuntimeWarning, match="cvxopt.*GTSAM"):
        res = batch.optimize(lie, initial)
    assert res.linear_solver == "gtsam" and res.converged
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert batch.optimize(lie, initial).linear_solver == "gtsam"
    with pytest.raises(InputError, match="needs cvxopt"):
        batch.optimize(lie, initial, linear_solver="cholmod")


def test_reweight_and_cost_hooks_reproduce_gtsam_robust_huber():
    """IRLS through the hooks (w = Huber weight, cost = Σ ρ) == GTSAM's LM on Robust(Huber) factors."""
    k = 1.5
    rng = np.random.default_rng(17)
    d = 3
    truth = [gtsam.Pose2.Expmap(rng.normal(size=3)) for _ in range(10)]
    plain, robust = gtsam.NonlinearFactorGraph(), gtsam.NonlinearFactorGraph()
    huber = gtsam.noiseModel.mEstimator.Huber.Create(k)
    edges = [(i, i + 1) for i in range(9)] + [(0, 5), (2, 8), (1, 9), (3, 7)]
    for n, (a, b) in enumerate(edges):
        z = _retract(truth[a].between(truth[b]), rng.normal(scale=0.05 if n % 4 else 0.8, size=d))
        nm = gtsam.noiseModel.Diagonal.Sigmas(np.array([0.1, 0.1, 0.05]))
        plain.add(factors.BetweenFactorPose2(a, b, z, nm))
        robust.add(gtsam.BetweenFactorPose2(a, b, z, gtsam.noiseModel.Robust.Create(huber, nm)))
    prior = gtsam.noiseModel.Isotropic.Sigma(d, 0.01)
    plain.add(factors.PriorFactorPose2(0, truth[0], prior))
    robust.add(gtsam.PriorFactorPose2(0, truth[0], prior))
    initial = gtsam.Values()
    for i, t in enumerate(truth):
        initial.insert(i, _retract(t, rng.normal(scale=0.2, size=d)))

    is_robust = np.arange(plain.size()) < len(edges)  # the prior (last) stays Gaussian

    def weight(sq):
        r = np.sqrt(sq)
        return np.where(is_robust & (r > k), k / np.maximum(r, k), 1.0)

    def cost(sq):
        r = np.sqrt(sq)
        return float(np.sum(np.where(is_robust & (r > k), k * r - 0.5 * k * k, 0.5 * sq)))

    params = gtsam.LevenbergMarquardtParams()
    opt = gtsam.LevenbergMarquardtOptimizer(robust, initial, params)
    errors = _stepwise_errors(opt, params)
    res = batch.optimize(plain, initial, params, reweight=weight, cost=cost)
    assert res.iterations == opt.iterations()
    np.testing.assert_allclose(res.errors, errors, rtol=1e-6)
    assert res.final_error < 0.9 * errors[0]
    assert any(weight(np.array([2 * plain.at(i).error(res.values)]))[0] < 1 for i in range(plain.size()))


class _DenseSystem:
    """A LinearSystem stand-in holding one dense symmetric matrix (one variable of dimension n)."""

    def __init__(self, H, g):
        from lie_factors.sparse.pattern import Pattern

        self.H = np.asarray(H, dtype=float)
        n = self.H.shape[0]
        self.pattern = Pattern(np.array([n]), np.zeros((0, 2), dtype=np.int64))
        self.rhs = np.asarray(g, dtype=float)
        self.data = np.concatenate([self.H[j:, j] for j in range(n)])  # the lower triangle, by columns

    def damp(self, scale):
        return self.data

    def in_matrix_order(self, v):
        return v

    def from_matrix_order(self, v):
        return v

    def holding(self, data, rhs):  # no hard constraint pins a variable here
        import contextlib

        return contextlib.nullcontext()


@pytest.mark.parametrize("H, definite", [
    ([[4.0, 1.0], [1.0, 3.0]], True),
    ([[1.0, 2.0], [2.0, 1.0]], False),   # indefinite: LDLᵀ gives d = (1, −3) without stopping
    ([[-1.0, 0.0], [0.0, 2.0]], False),
    ([[2.0, 0.0, 0.0], [0.0, 1.0, 1.0], [0.0, 1.0, -5.0]], False),
])
def test_cholmod_simplicial_factor_detects_indefinite_systems(H, definite, cholmod_way):
    from cvxopt import cholmod

    from lie_factors.batch.solvers import CholmodSolver
    from lie_factors.errors import NotPositiveDefinite

    g = np.arange(1.0, len(H) + 1.0)
    solver = CholmodSolver(_DenseSystem(H, g))
    if definite:
        np.testing.assert_allclose(solver.solve(None), np.linalg.solve(H, g), rtol=1e-14)
    else:
        with pytest.raises(NotPositiveDefinite, match="not positive definite"):
            solver.solve(None)
    # The case under test is CHOLMOD's simplicial LDLᵀ (cvxopt's diag() accepts supernodal factors only).
    if cholmod_way == "direct":
        assert solver.factor.supernodal is False
    else:
        with pytest.raises(ValueError, match="supernodal"):
            cholmod.diag(solver.factor._impl._F)


def test_cholmod_leaves_cvxopt_options_alone(cholmod_way):
    from cvxopt import cholmod

    from lie_factors.batch.solvers import CholmodSolver

    cholmod.options["supernodal"] = 2
    try:
        CholmodSolver(_DenseSystem([[4.0, 1.0], [1.0, 3.0]], [1.0, 2.0]))
        assert cholmod.options == {"supernodal": 2}
    finally:
        cholmod.options.clear()
