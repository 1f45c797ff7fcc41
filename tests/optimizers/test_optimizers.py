"""lie_factors.optimizers: drop-ins for GTSAM's LM / Gauss–Newton / Dogleg.

Reference: GTSAM's own optimizer, stepped with iterate() on the same graph
(our factors, GTSAM's factors, mixed graphs).  The speed property has a
deterministic cause, tested here: the number of distinct Values objects the
callbacks receive.
"""

from __future__ import annotations

import gc
import weakref
from pathlib import Path

import gtsam
import numpy as np
import pytest

from lie_factors import factors
from lie_factors import optimizers
from support.example_graphs import rosenbrock

ROOT = Path(__file__).resolve().parents[2]
SMALL_3D = str(ROOT / "data" / "smallGrid3D.g2o")
SMALL_2D = gtsam.findExampleDataFile("w100.graph")

PRIOR_3D = gtsam.noiseModel.Diagonal.Variances(np.array([1e-6, 1e-6, 1e-6, 1e-4, 1e-4, 1e-4]))
PRIOR_2D = gtsam.noiseModel.Diagonal.Variances(np.array([1e-6, 1e-6, 1e-8]))


def load(is3d: bool, ours: bool):
    """The file's pose graph + a prior on its first pose, with our factors or GTSAM's."""
    if is3d:
        native, initial = gtsam.readG2o(SMALL_3D, True)
    else:
        native, initial = gtsam.load2D(SMALL_2D)
    group = "Pose3" if is3d else "Pose2"
    F = factors if ours else gtsam
    Between = getattr(F, f"BetweenFactor{group}")
    Prior = getattr(F, f"PriorFactor{group}")
    graph = gtsam.NonlinearFactorGraph()
    for i in range(native.size()):
        f = native.at(i)
        k1, k2 = f.keys()
        graph.add(Between(k1, k2, f.measured(), f.noiseModel()))
    first = min(initial.keys())
    at = getattr(initial, f"at{group}")
    graph.add(Prior(first, at(first), PRIOR_3D if is3d else PRIOR_2D))
    return graph, initial


def lm_params(diagonal=False, solver=None, fixed=None):
    p = gtsam.LevenbergMarquardtParams()
    p.setDiagonalDamping(diagonal)
    if solver is not None:
        p.setLinearSolverType(solver)
    if fixed is not None:
        p.setUseFixedLambdaFactor(fixed)
    return p


def assert_same_errors(ref, ours, rtol=1e-9):
    ref, ours = np.asarray(ref), np.asarray(ours)
    assert ref.shape == ours.shape, (ref, ours)
    np.testing.assert_allclose(ours, ref, rtol=rtol, atol=0)


def stepwise(opt, steps, extra=None):
    """Errors (and ``extra(opt)``) before and after each of ``steps`` iterate() calls."""
    rows = [(opt.iterations(), opt.error(), extra(opt) if extra else 0.0)]
    for _ in range(steps):
        opt.iterate()
        rows.append((opt.iterations(), opt.error(), extra(opt) if extra else 0.0))
    return rows


def compare_stepwise(make_ref, make_ours, steps, extra=None):
    ref = stepwise(make_ref(), steps, extra)
    ours = stepwise(make_ours(), steps, extra)
    assert [r[0] for r in ours] == [r[0] for r in ref]  # iteration counts, step by step
    assert_same_errors([r[1] for r in ref], [r[1] for r in ours])
    assert_same_errors([r[2] for r in ref], [r[2] for r in ours])


# ---------------------------------------------------------------------------- same iterations
@pytest.mark.parametrize("is3d", [True, False], ids=["Pose3", "Pose2"])
@pytest.mark.parametrize("ours", [True, False], ids=["our-factors", "gtsam-factors"])
@pytest.mark.parametrize("diagonal", [False, True], ids=["lambda-I", "diagonal-damping"])
def test_lm_iterations_identical(is3d, ours, diagonal):
    graph, initial = load(is3d, ours)
    compare_stepwise(
        lambda: gtsam.LevenbergMarquardtOptimizer(graph, initial, lm_params(diagonal)),
        lambda: optimizers.LevenbergMarquardtOptimizer(graph, initial, lm_params(diagonal)),
        steps=12, extra=lambda o: o.lambda_())


@pytest.mark.parametrize("solver", ["MULTIFRONTAL_QR", "SEQUENTIAL_CHOLESKY", "SEQUENTIAL_QR"])
def test_lm_linear_solvers(solver):
    graph, initial = load(True, True)
    compare_stepwise(
        lambda: gtsam.LevenbergMarquardtOptimizer(graph, initial, lm_params(solver=solver)),
        lambda: optimizers.LevenbergMarquardtOptimizer(graph, initial, lm_params(solver=solver)),
        steps=6, extra=lambda o: o.lambda_())


def test_lm_ceres_defaults_lambda_schedule():
    """CeresDefaults: diagonal damping, non-fixed λ factor (fidelity-driven λ), bounds."""
    graph, initial = load(False, True)
    compare_stepwise(
        lambda: gtsam.LevenbergMarquardtOptimizer(graph, initial, gtsam.LevenbergMarquardtParams.CeresDefaults()),
        lambda: optimizers.LevenbergMarquardtOptimizer(graph, initial, gtsam.LevenbergMarquardtParams.CeresDefaults()),
        steps=10, extra=lambda o: o.lambda_())


def test_lm_rejected_steps_and_upper_bound():
    """A start far from the optimum with a huge initial λ step: rejected tries, λ growth, giving up."""
    graph, initial = load(True, True)
    bad = gtsam.Values()
    rng = np.random.default_rng(3)
    for key in initial.keys():
        bad.insert(key, initial.atPose3(key).retract(rng.normal(0, 1.0, 6)))

    def params():
        p = lm_params(fixed=False)
        p.setlambdaInitial(1e-9)
        p.setlambdaUpperBound(1e3)
        return p

    compare_stepwise(lambda: gtsam.LevenbergMarquardtOptimizer(graph, bad, params()),
                     lambda: optimizers.LevenbergMarquardtOptimizer(graph, bad, params()),
                     steps=15, extra=lambda o: o.lambda_())


@pytest.mark.parametrize("batch", [False, True], ids=["dropin", "batch"])
def test_lm_factor_after_an_accepted_step_is_gtsams(batch):
    """Without a fixed λ factor, GTSAM 4.3 starts the rejections after an accepted step at a factor
    of 2 (λ: 8 accepted, 2.67 accepted, 0.889 rejected, 1.78 = 2·0.889 accepted, leaving 1.674):
    λ after every iteration."""
    from lie_factors.batch.optimizer import BatchLevenbergMarquardt

    graph, initial = rosenbrock()

    def params():
        p = lm_params(fixed=False)
        p.setlambdaInitial(1e-3)
        return p

    ours = BatchLevenbergMarquardt if batch else optimizers.LevenbergMarquardtOptimizer
    compare_stepwise(lambda: gtsam.LevenbergMarquardtOptimizer(graph, initial, params()),
                     lambda: ours(graph, initial, params()), steps=12, extra=lambda o: o.lambda_())
    opt = ours(graph, initial, params())
    for _ in range(3):
        opt.iterate()
    assert opt.lambda_() == pytest.approx(1.67443, rel=1e-5)


def test_lm_optimize_and_ordering_argument():
    graph, initial = load(True, True)
    ordering = gtsam.Ordering(sorted(initial.keys(), reverse=True))
    ref = gtsam.LevenbergMarquardtOptimizer(graph, initial, ordering, lm_params())
    ours = optimizers.LevenbergMarquardtOptimizer(graph, initial, ordering, lm_params())
    hooks = {"ref": [], "ours": []}
    p_ref, p_ours = lm_params(), lm_params()
    p_ref.iterationHook = lambda i, a, b: hooks["ref"].append((i, a, b))
    p_ours.iterationHook = lambda i, a, b: hooks["ours"].append((i, a, b))
    r = gtsam.LevenbergMarquardtOptimizer(graph, initial, p_ref)
    o = optimizers.LevenbergMarquardtOptimizer(graph, initial, p_ours)
    vr, vo = r.optimize(), o.optimize()
    assert r.iterations() == o.iterations()
    assert len(hooks["ref"]) == len(hooks["ours"]) == r.iterations()
    np.testing.assert_allclose([h[1:] for h in hooks["ours"]], [h[1:] for h in hooks["ref"]], rtol=1e-9)
    assert vo.equals(vr, 1e-9)
    vr2, vo2 = ref.optimize(), ours.optimize()
    assert ref.iterations() == ours.iterations()
    assert abs(ref.error() - ours.error()) <= 1e-9 * ref.error()
    assert vo2.equals(vr2, 1e-9)


def _params_only_gtsam_runs(name: str, what: str, keys):
    """Params of GTSAM's ``{name}Optimizer`` that the drop-in's loop cannot run."""
    p = getattr(gtsam, f"{name}Params")()
    if what == "custom-ordering":  # stored where the wrapper cannot read it back
        p.setOrdering(gtsam.Ordering(sorted(keys, reverse=True)))
    elif what == "iterative":
        p.setLinearSolverType("ITERATIVE")
        pcg = gtsam.PCGSolverParameters()
        pcg.preconditioner = gtsam.DummyPreconditionerParameters()
        p.setIterativeParams(pcg)
    else:
        p.setLinearSolverType("CHOLMOD")  # GTSAM's optimizer rejects it when it solves
    p.setMaxIterations(5)
    return p


def _run(optimizer):
    """("values", values, iterations, error) after optimize(), or ("raised", type, message)."""
    try:
        values = optimizer.optimize()
    except Exception as exc:  # noqa: BLE001 - the outcome, whatever it is, is what we compare
        return ("raised", type(exc), str(exc))
    return ("values", values, optimizer.iterations(), optimizer.error())


@pytest.mark.parametrize("what", ["custom-ordering", "iterative", "cholmod"])
@pytest.mark.parametrize("name", ["LevenbergMarquardt", "GaussNewton", "Dogleg"])
def test_params_the_loop_cannot_run_give_gtsams_own_optimizer(name, what):
    graph, initial = load(False, True)
    ours = getattr(optimizers, f"{name}Optimizer")(graph, initial, _params_only_gtsam_runs(name, what, initial.keys()))
    native = getattr(gtsam, f"{name}Optimizer")
    assert type(ours) is native
    ref = native(graph, initial, _params_only_gtsam_runs(name, what, initial.keys()))
    a, b = _run(ours), _run(ref)
    assert a[0] == b[0]
    if a[0] == "raised":
        assert a[1:] == b[1:]
    else:
        assert a[1].equals(b[1], 0.0) and a[2:] == b[2:]
    # GTSAM's optimizers reject CHOLMOD when they solve, and Dogleg an iterative solver.
    assert (a[0] == "raised") == (what == "cholmod" or (name, what) == ("Dogleg", "iterative"))


def test_ordering_argument_overrides_a_custom_ordering_in_params():
    graph, initial = load(False, True)
    ordering = gtsam.Ordering(sorted(initial.keys(), reverse=True))
    p = _params_only_gtsam_runs("LevenbergMarquardt", "custom-ordering", initial.keys())
    ours = optimizers.LevenbergMarquardtOptimizer(graph, initial, ordering, p)
    assert type(ours) is optimizers.LevenbergMarquardtOptimizer  # the loop runs
    ref = gtsam.LevenbergMarquardtOptimizer(graph, initial, ordering, lm_params())
    assert ours.optimize().equals(ref.optimize(), 1e-9)
    assert ours.iterations() == ref.iterations()
    # GTSAM's GaussNewtonOptimizer/DoglegOptimizer wrappers take no ordering: with params only
    # GTSAM's optimizer runs, the drop-in raises the wrapper's TypeError for an ordering argument.
    gn = gtsam.GaussNewtonParams()
    gn.setLinearSolverType("CHOLMOD")
    with pytest.raises(TypeError, match="incompatible constructor arguments"):
        optimizers.GaussNewtonOptimizer(graph, initial, gn, ordering=ordering)
    with pytest.raises(TypeError):
        optimizers.GaussNewtonOptimizer(graph, initial, gn, ordering, "too many")


@pytest.mark.parametrize("is3d", [True, False], ids=["Pose3", "Pose2"])
@pytest.mark.parametrize("ours", [True, False], ids=["our-factors", "gtsam-factors"])
def test_gauss_newton_iterations_identical(is3d, ours):
    graph, initial = load(is3d, ours)
    compare_stepwise(lambda: gtsam.GaussNewtonOptimizer(graph, initial, gtsam.GaussNewtonParams()),
                     lambda: optimizers.GaussNewtonOptimizer(graph, initial, gtsam.GaussNewtonParams()),
                     steps=6)
    ref = gtsam.GaussNewtonOptimizer(graph, initial)
    ours_opt = optimizers.GaussNewtonOptimizer(graph, initial)
    assert ours_opt.optimize().equals(ref.optimize(), 1e-9)
    assert ours_opt.iterations() == ref.iterations()


@pytest.mark.parametrize("is3d", [True, False], ids=["Pose3", "Pose2"])
@pytest.mark.parametrize("ours", [True, False], ids=["our-factors", "gtsam-factors"])
@pytest.mark.parametrize("delta0", [1.0, 1e-3, 100.0])
def test_dogleg_iterations_identical(is3d, ours, delta0):
    graph, initial = load(is3d, ours)

    def params():
        p = gtsam.DoglegParams()
        p.setDeltaInitial(delta0)
        return p

    compare_stepwise(lambda: gtsam.DoglegOptimizer(graph, initial, params()),
                     lambda: optimizers.DoglegOptimizer(graph, initial, params()),
                     steps=8, extra=lambda o: o.getDelta())


def test_dogleg_sequential():
    graph, initial = load(True, True)

    def params():
        p = gtsam.DoglegParams()
        p.setLinearSolverType("SEQUENTIAL_CHOLESKY")
        return p

    compare_stepwise(lambda: gtsam.DoglegOptimizer(graph, initial, params()),
                     lambda: optimizers.DoglegOptimizer(graph, initial, params()),
                     steps=5, extra=lambda o: o.getDelta())


# ---------------------------------------------------------------------------- the cause: Values objects
class Recorder:
    """A plain gtsam.CustomFactor (a user's own): Between on Pose2 via GTSAM's own Pose2 methods,
    recording every Values object its callback receives."""

    def __init__(self):
        self.seen = []

    def factor(self, k1, k2, measured, noise):
        def evaluate(this, values, H):
            self.seen.append(values)  # the object itself: keeps it alive, so ids stay unique
            x1, x2 = values.atPose2(k1), values.atPose2(k2)
            if H is None:
                return measured.localCoordinates(x1.between(x2))
            J1, J2 = np.zeros((3, 3), order="F"), np.zeros((3, 3), order="F")
            rel = x1.between(x2, J1, J2)
            Jl = np.zeros((3, 3), order="F")
            e = measured.localCoordinates(rel, np.zeros((3, 3), order="F"), Jl)
            H[0] = Jl @ J1
            H[1] = Jl @ J2
            return e

        return gtsam.CustomFactor(noise, [k1, k2], evaluate)


def mixed_graph(recorder: Recorder):
    """GTSAM's own factors, our factors and a user's CustomFactor in one Pose2 graph."""
    native, initial = load(False, False)
    graph = gtsam.NonlinearFactorGraph()
    for i in range(native.size()):
        f = native.at(i)
        if i % 3 == 0:
            graph.add(f)  # GTSAM's BetweenFactorPose2 / PriorFactorPose2
        elif i % 3 == 1 and isinstance(f, gtsam.BetweenFactorPose2):
            graph.add(recorder.factor(*f.keys(), f.measured(), f.noiseModel()))
        elif isinstance(f, gtsam.BetweenFactorPose2):
            graph.add(factors.BetweenFactorPose2(*f.keys(), f.measured(), f.noiseModel()))
        else:
            graph.add(f)
    return graph, initial


@pytest.mark.parametrize("kind", ["lm", "gn", "dogleg"])
def test_callbacks_receive_only_the_optimizers_values(kind):
    make = {"lm": (gtsam.LevenbergMarquardtOptimizer, optimizers.LevenbergMarquardtOptimizer),
            "gn": (gtsam.GaussNewtonOptimizer, optimizers.GaussNewtonOptimizer),
            "dogleg": (gtsam.DoglegOptimizer, optimizers.DoglegOptimizer)}[kind]
    steps = 4
    runs = {}
    for side, cls in zip(("gtsam", "ours"), make):
        rec = Recorder()
        graph, initial = mixed_graph(rec)
        n_user = sum(1 for i in range(graph.size())
                     if type(graph.at(i)) is gtsam.CustomFactor)
        opt = cls(graph, initial)
        evals = [len(rec.seen)]
        for _ in range(steps):
            opt.iterate()
            evals.append(len(rec.seen))
        runs[side] = (rec, n_user, opt, evals)
    rec, n_user, _, evals = runs["gtsam"]
    # GTSAM's optimizer: in the iterations every callback gets a new copy of the whole
    # Values (its constructor evaluates the error on the user's own object).
    iterating = rec.seen[evals[0]:]
    assert len(iterating) > 0 and len({id(v) for v in iterating}) == len(iterating)
    rec, n_user, opt, evals = runs["ours"]
    distinct = {id(v) for v in rec.seen}
    # Ours: one object per graph evaluation (each linearization or trial point), each
    # seen by all n_user callbacks of that evaluation.
    assert len(rec.seen) % n_user == 0
    chunks = [rec.seen[i:i + n_user] for i in range(0, len(rec.seen), n_user)]
    assert all(len({id(v) for v in chunk}) == 1 for chunk in chunks)
    assert len(distinct) <= len(chunks)  # an accepted trial point is then linearized: one object
    # and that object is the optimizer's own: the last one evaluated is its current values.
    assert rec.seen[-1] is opt._values
    # same arithmetic as GTSAM's on the mixed graph
    assert abs(runs["gtsam"][2].error() - opt.error()) <= 1e-9 * opt.error()


def test_linearization_point_object_is_stable_across_tries():
    """LM: every callback of one linearization, and of the accepted trial, sees one object."""
    rec = Recorder()
    graph, initial = mixed_graph(rec)
    opt = optimizers.LevenbergMarquardtOptimizer(graph, initial)
    start = len(rec.seen)
    opt.iterate()
    objs = rec.seen[start:]
    # one linearization + at least one trial error evaluation: ≥ 2 objects, and their
    # count is the number of graph evaluations, not the number of callbacks.
    assert 2 <= len({id(v) for v in objs}) <= 1 + opt.getInnerIterations()


# ---------------------------------------------------------------------------- lifetimes, errors
def test_dropped_optimizer_is_freed_and_user_values_survive():
    graph, initial = load(False, True)
    opt = optimizers.LevenbergMarquardtOptimizer(graph, initial)
    opt.iterate()
    result = opt.values()
    ref = weakref.ref(opt)
    del opt
    gc.collect()
    assert ref() is None
    # the user's objects are still theirs
    assert initial.size() == result.size() == 100
    assert np.isfinite(graph.error(result)) and graph.error(result) < graph.error(initial)
    # and mutating the result does not reach into another optimizer
    opt2 = optimizers.GaussNewtonOptimizer(graph, initial)
    v = opt2.values()
    v.update(0, gtsam.Pose2(5, 5, 1))
    assert opt2.values().atPose2(0).equals(initial.atPose2(0), 0)


class Boom(Exception):
    pass


@pytest.mark.parametrize("cls", ["LevenbergMarquardtOptimizer", "GaussNewtonOptimizer", "DoglegOptimizer"])
def test_callback_exception_propagates_like_gtsam(cls):
    graph, initial = load(False, True)
    calls = {"n": 0}

    def evaluate(this, values, H):
        calls["n"] += 1
        if calls["n"] > 3:
            raise Boom("from the callback")
        if H is not None:
            H[0] = np.eye(3)
        return np.zeros(3)

    graph.add(gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(3), [0], evaluate))
    raised = {}
    for side, mod in (("gtsam", gtsam), ("ours", optimizers)):
        calls["n"] = 0
        opt = getattr(mod, cls)(graph, initial)
        with pytest.raises(Exception) as info:
            opt.optimize()
        raised[side] = info.type
    assert raised["gtsam"] is raised["ours"] is Boom


def both_raise(make):
    classes = {}
    for side, mod in (("gtsam", gtsam), ("ours", optimizers)):
        with pytest.raises(Exception) as info:
            make(mod)
        classes[side] = info.type
    assert classes["gtsam"] is classes["ours"], classes
    return classes["ours"]


@pytest.mark.parametrize("ours", [True, False], ids=["our-factors", "gtsam-factors"])
def test_wrong_key_type_raises_like_gtsam(ours):
    graph, initial = load(False, ours)
    wrong = gtsam.Values(initial)
    wrong.erase(5)
    wrong.insert(5, gtsam.Pose3())
    for cls in ("LevenbergMarquardtOptimizer", "GaussNewtonOptimizer", "DoglegOptimizer"):
        both_raise(lambda mod: getattr(mod, cls)(graph, wrong).optimize())


@pytest.mark.parametrize("ours", [True, False], ids=["our-factors", "gtsam-factors"])
def test_missing_key_raises_like_gtsam(ours):
    graph, initial = load(False, ours)
    missing = gtsam.Values(initial)
    missing.erase(7)
    for cls in ("LevenbergMarquardtOptimizer", "GaussNewtonOptimizer", "DoglegOptimizer"):
        both_raise(lambda mod: getattr(mod, cls)(graph, missing).optimize())


def test_indeterminant_system_like_gtsam():
    """No prior: Gauss–Newton and Dogleg raise GTSAM's exception; LM damps and goes on, in both."""
    graph, initial = load(False, True)
    free = gtsam.NonlinearFactorGraph()
    for i in range(graph.size() - 1):  # drop the prior
        free.add(graph.at(i))
    assert both_raise(lambda mod: mod.GaussNewtonOptimizer(free, initial).optimize()) is RuntimeError
    assert both_raise(lambda mod: mod.DoglegOptimizer(free, initial).optimize()) is RuntimeError
    compare_stepwise(lambda: gtsam.LevenbergMarquardtOptimizer(free, initial),
                     lambda: optimizers.LevenbergMarquardtOptimizer(free, initial),
                     steps=4, extra=lambda o: o.lambda_())


def test_bad_arguments():
    graph, initial = load(False, True)
    with pytest.raises(TypeError):
        optimizers.LevenbergMarquardtOptimizer(graph, initial, gtsam.GaussNewtonParams())
    with pytest.raises(TypeError):
        optimizers.GaussNewtonOptimizer(graph, {0: 1})
    with pytest.raises(TypeError):
        optimizers.DoglegOptimizer([], initial)
    p = lm_params()
    p.setLinearSolverType("CHOLMOD")
    both_raise(lambda mod: mod.LevenbergMarquardtOptimizer(graph, initial, p).optimize())


def test_dropin_backend_runs_the_drop_in(monkeypatch):
    """``backend="dropin"`` (``--backend dropin``) optimizes with the drop-in LM: GTSAM's result."""
    import lie_factors as lf

    made = []

    class Spy(optimizers.LevenbergMarquardtOptimizer):
        def __init__(self, *args, **kwargs):
            made.append(self)
            super().__init__(*args, **kwargs)

    monkeypatch.setattr(optimizers, "LevenbergMarquardtOptimizer", Spy)
    graph, initial = load(True, True)
    res = lf.optimize(graph, initial, backend="dropin")
    assert len(made) == 1
    ref = gtsam.LevenbergMarquardtOptimizer(graph, initial)
    ref.optimize()
    assert res.iterations == ref.iterations()
    assert res.error == pytest.approx(ref.error(), rel=1e-9)


@pytest.mark.parametrize("is3d", [True, False], ids=["Pose3", "Pose2"])
def test_evaluation_plan_gives_the_callbacks_own_numbers(is3d):
    """Inside plan.prepared(values) the factors answer from one kernel call per group: the
    linearization and error are bit-for-bit those of the per-callback path; other Values
    objects (and a Values missing a key) take the per-callback path."""
    graph, initial = load(is3d, True)
    values = gtsam.Values(initial)
    plan = factors.EvaluationPlan(graph)
    assert plan
    plain_linear = graph.linearize(values)
    plain_error = graph.error(values)
    with plan.prepared(values):
        assert factors._prepared is plan
        prepared_linear = graph.linearize(values)
        prepared_error = graph.error(values)
        other = gtsam.Values(values)  # not the prepared object: evaluated per callback
        assert graph.error(other) == plain_error
    assert factors._prepared is None
    assert prepared_error == plain_error
    a, b = plain_linear.sparseJacobian_(), prepared_linear.sparseJacobian_()
    assert np.array_equal(a, b)
    missing = gtsam.Values(values)
    missing.erase(3)
    with plan.prepared(missing):
        assert factors._prepared is None
        with pytest.raises(Exception) as info:
            graph.error(missing)
    with pytest.raises(info.type):
        graph.error(missing)


def _rss_bytes() -> int:
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * 4096


@pytest.mark.slow
def test_rss_flat_over_create_drop_cycles():
    """1 000 drop-ins created, iterated once and dropped: no Values (100 poses) left behind."""
    graph, initial = load(False, True)
    for _ in range(20):  # allocator and caches settle
        optimizers.LevenbergMarquardtOptimizer(graph, initial).iterate()
    gc.collect()
    before = _rss_bytes()
    for i in range(1000):
        opt = [optimizers.LevenbergMarquardtOptimizer, optimizers.GaussNewtonOptimizer,
               optimizers.DoglegOptimizer][i % 3](graph, initial)
        opt.iterate()
        del opt
    gc.collect()
    grown = _rss_bytes() - before
    # A leaked optimizer would keep ≥ 2 Values of 100 Pose2 (≈ 20 kB): ≥ 20 MB over 1 000 cycles.
    assert grown < 8 * 2**20, f"RSS grew by {grown / 2**20:.1f} MiB"


def test_graph_changed_after_construction_is_not_seen_like_gtsam():
    graph, initial = load(False, True)
    ref = gtsam.LevenbergMarquardtOptimizer(graph, initial)
    ours = optimizers.LevenbergMarquardtOptimizer(graph, initial)
    graph.add(factors.PriorFactorPose2(5, gtsam.Pose2(100, 100, 1), PRIOR_2D))
    ref.iterate()
    ours.iterate()
    assert ours.graph().size() == ref.graph().size() == graph.size() - 1
    assert abs(ours.error() - ref.error()) <= 1e-9 * ref.error()
