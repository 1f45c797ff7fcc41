"""lie_factors.dropin: gtsam's namespace with our factors and drop-ins in place of GTSAM's."""

from __future__ import annotations

import importlib

import gtsam
import numpy as np
import pytest

import lie_factors.dropin as dropin
from lie_factors import factors, optimizers
from lie_factors.optimizers import compat

GROUPS = ("Rot3", "Pose2", "Pose3", "Similarity2", "Similarity3")


def test_factor_classes_are_ours():
    for group in GROUPS:
        for kind in ("BetweenFactor", "PriorFactor"):
            name = kind + group
            assert getattr(dropin, name) is getattr(factors, name)
            assert dropin.REPLACED[name] == "lie_factors.factors"


def test_compat_functions_are_ours():
    assert dropin.writeG2o is compat.writeG2o
    assert dropin.readG2o is compat.readG2o
    assert dropin.InitializePose3 is compat.InitializePose3
    assert dropin.lago is compat.lago


def test_every_other_name_is_gtsams_own_object():
    public = [n for n in dir(gtsam) if not n.startswith("_")]
    assert len(public) > 500
    for name in public:
        if name in dropin.REPLACED:
            assert getattr(dropin, name) is not getattr(gtsam, name)
        else:
            assert getattr(dropin, name) is getattr(gtsam, name), name
    assert set(dir(gtsam)) <= set(dir(dropin))


def test_replaced_names_are_exactly_ours_and_optimizers_dropins():
    from_optimizers = {n for n in dir(optimizers) if not n.startswith("_") and hasattr(gtsam, n)
                       and not isinstance(getattr(optimizers, n), type(gtsam))}
    from_factors = {k + g for k in ("BetweenFactor", "PriorFactor") for g in GROUPS}
    assert set(dropin.REPLACED) == from_optimizers | from_factors
    assert {"writeG2o", "readG2o", "InitializePose3", "lago"} <= from_optimizers
    for name, module in dropin.REPLACED.items():
        assert getattr(dropin, name) is getattr(__import__(module, fromlist=[name]), name)


def test_submodules_reachable_as_attributes():
    assert dropin.noiseModel is gtsam.noiseModel
    assert dropin.symbol_shorthand is gtsam.symbol_shorthand
    assert dropin.imuBias is gtsam.imuBias
    assert dropin.utilities is gtsam.utilities
    assert dropin.utils is importlib.import_module("gtsam.utils")
    assert dropin.symbol_shorthand.X(3) == gtsam.symbol("x", 3)


def test_submodule_gtsam_rebinds_later_is_gtsams_current_one():
    # ``import gtsam.symbol_shorthand`` replaces gtsam's attribute (the compiled submodule) by the
    # Python module of that name; the drop-in must follow, whichever import came first.
    import subprocess
    import sys

    code = ("import lie_factors.dropin as d, gtsam\n"
            "before = d.symbol_shorthand\n"
            "import gtsam.symbol_shorthand\n"
            "assert before is not gtsam.symbol_shorthand\n"
            "assert d.symbol_shorthand is gtsam.symbol_shorthand\n"
            "from lie_factors.dropin import symbol_shorthand\n"
            "assert symbol_shorthand is gtsam.symbol_shorthand\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    with pytest.raises(AttributeError, match="has no attribute 'no_such_name'"):
        dropin.no_such_name  # noqa: B018
    # A module, not a package: no second copy of gtsam's submodules under another name.
    assert not hasattr(dropin, "__path__")
    with pytest.raises(ModuleNotFoundError, match="not a package"):
        importlib.import_module("lie_factors.dropin.utils")


def test_from_import_and_a_mixed_graph():
    from lie_factors.dropin import (BetweenFactorPose2, NonlinearFactorGraph, Pose2, PriorFactorPose2, Values, noiseModel)

    graph = NonlinearFactorGraph()
    noise = noiseModel.Diagonal.Sigmas(np.array([0.1, 0.1, 0.05]))
    graph.add(PriorFactorPose2(0, Pose2(), noise))
    graph.add(BetweenFactorPose2(0, 1, Pose2(1, 0, 0.1), noise))
    graph.add(gtsam.BetweenFactorPose2(1, 2, Pose2(1, 0, 0.1), noise))  # GTSAM's own, beside ours
    values = Values()
    for k in range(3):
        values.insert(k, Pose2(0.9 * k, 0.05, 0.0))
    result = dropin.LevenbergMarquardtOptimizer(graph, values, dropin.LevenbergMarquardtParams()).optimize()
    assert result.atPose2(2).equals(Pose2(1, 0, 0.1).compose(Pose2(1, 0, 0.1)), 1e-9)
    assert type(graph.at(1)) is factors.BetweenFactorPose2


def test_star_import_gives_gtsams_names_with_ours():
    ns: dict = {}
    exec("from lie_factors.dropin import *", ns)
    assert {n for n in ns if not n.startswith("_")} == {n for n in dir(gtsam) if not n.startswith("_")}
    assert ns["BetweenFactorPose3"] is factors.BetweenFactorPose3
    assert ns["writeG2o"] is compat.writeG2o
    assert ns["Pose3"] is gtsam.Pose3


# --------------------------------------------------------------------------- #
# However a user swaps them in
# --------------------------------------------------------------------------- #

_POISONED_FIRST = r'''
import json, os, sys, tempfile
import numpy as np
import gtsam

native = gtsam.gtsam  # GTSAM's own classes, for the workload and the references


def refuse(name):
    def call(*args, **kwargs):
        raise AssertionError(f"gtsam.{name} was looked up in gtsam's namespace")
    return call


for name in json.loads(sys.argv[1]):
    setattr(gtsam, name, refuse(name))

# lie_factors imported only now, after the assignment
import lie_factors.dropin as dropin
from lie_factors import factors, optimizers

assert all(getattr(dropin, n) is getattr(optimizers, n, None) or getattr(dropin, n) is getattr(factors, n)
           for n in dropin.REPLACED)
noise = native.noiseModel.Diagonal.Sigmas(np.array([0.1, 0.1, 0.05]))
graph = native.NonlinearFactorGraph()
graph.add(factors.PriorFactorPose2(0, native.Pose2(), noise))
initial = native.Values()
for k in range(6):
    if k:
        graph.add(factors.BetweenFactorPose2(k - 1, k, native.Pose2(1, 0, 0.1), noise))
    initial.insert(k, native.Pose2(0.9 * k, 0.1, 0.05 * k))
ref = native.LevenbergMarquardtOptimizer(graph, initial).optimize()
for name in ("LevenbergMarquardt", "GaussNewton", "Dogleg"):
    assert getattr(optimizers, name + "Optimizer")(graph, initial).optimize().equals(ref, 1e-6), name
custom = native.LevenbergMarquardtParams()
custom.setOrdering(native.Ordering(list(range(6))))
assert optimizers.LevenbergMarquardtOptimizer(graph, initial, custom).optimize().equals(ref, 1e-6)
params = native.ISAM2Params()
params.evaluateNonlinearError = True
isam, isam_ref = optimizers.ISAM2(params), native.ISAM2(params)
for update in ((graph, initial), ()):
    errors = isam.update(*update)
    errors_ref = isam_ref.update(*update)
    assert abs(errors.getErrorAfter() - errors_ref.getErrorAfter()) <= 1e-9
assert isam.calculateEstimate().equals(isam_ref.calculateEstimate(), 1e-9)
smoother, smoother_ref = optimizers.IncrementalFixedLagSmoother(10.0), native.IncrementalFixedLagSmoother(10.0)
for s in (smoother, smoother_ref):
    s.update(graph, initial, {k: float(k) for k in range(6)})
assert smoother.calculateEstimate().equals(smoother_ref.calculateEstimate(), 1e-9)
body = native.NonlinearFactorGraph()
for k in range(1, graph.size()):
    body.add(graph.at(k))
path = os.path.join(tempfile.mkdtemp(), "chain.g2o")
optimizers.writeG2o(body, ref, path)
read, values = optimizers.readG2o(path)
assert type(read.at(0)) is factors.BetweenFactorPose2 and values.equals(ref, 1e-5)
assert optimizers.lago.initialize(graph).equals(ref, 1e-6)
print("ok")
'''


def test_drop_ins_never_call_what_is_assigned_into_gtsams_namespace():
    """Every name we replace is made to raise in ``gtsam``'s namespace before lie_factors is
    imported: the drop-ins, imported after, still run (they hold GTSAM's own classes)."""
    import json
    import subprocess
    import sys

    proc = subprocess.run([sys.executable, "-c", _POISONED_FIRST, json.dumps(sorted(dropin.REPLACED))],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0 and proc.stdout.strip() == "ok", proc.stderr[-3000:]


def test_gtsams_logging_optimizer_takes_our_optimizer_classes():
    """``gtsam.utils.logging_optimizer`` looks up an optimizer class's params class in a dict
    keyed by GTSAM's classes: ours are in it, and the hooks see GTSAM's errors."""
    from gtsam.utils.logging_optimizer import gtsam_optimize, optimize_using

    graph = gtsam.NonlinearFactorGraph()
    noise = gtsam.noiseModel.Unit.Create(3)
    for r in (gtsam.Rot3.Expmap(np.array([0.1, 0, 0])), gtsam.Rot3.Expmap(np.array([-0.1, 0, 0]))):
        graph.add(factors.PriorFactorRot3(0, r, noise))
    initial = gtsam.Values()
    initial.insert(0, gtsam.Rot3.Expmap(np.array([0.1, 0.2, 0])))
    for name in ("LevenbergMarquardt", "GaussNewton", "Dogleg"):
        ours, native = getattr(optimizers, f"{name}Optimizer"), getattr(gtsam, f"{name}Optimizer")
        logs = {}
        for side, cls in (("ours", ours), ("gtsam", native)):
            log = logs[side] = []
            result = optimize_using(cls, lambda opt, error: log.append(error), graph, initial)
            assert result.atRot3(0).equals(gtsam.Rot3(), 1e-6)
            params = getattr(gtsam, f"{name}Params")()
            gtsam_optimize(cls(graph, initial, params), params, lambda opt, error: log.append(error))
        np.testing.assert_allclose(logs["ours"], logs["gtsam"], rtol=1e-9, atol=1e-15)
