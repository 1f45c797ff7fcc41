"""Our factors, and graphs holding them, print what GTSAM's own factors print.

The reference is GTSAM's own factor of the same class, keys, value and noise
model, printed by GTSAM (its C++ ``print`` through the wrapper): never a
hard-coded string.

GTSAM leaves ``std::cout``'s precision where a print set it (printing a
diagonal noise model sets 9 digits for every later print), so each print
compared here starts from the same state: :func:`settled`.
"""

from __future__ import annotations

import gtsam
import numpy as np
import pytest

from lie_factors import factors
from lie_factors.kernels import registry

GROUPS = [info.gtsam for info in registry.GROUPS.values()]
X1 = gtsam.symbol("x", 1)


def noise_models(dim: int) -> dict:
    rng = np.random.default_rng(dim)
    A = rng.normal(size=(dim, dim))
    return {
        "unit": gtsam.noiseModel.Unit.Create(dim),
        "isotropic": gtsam.noiseModel.Isotropic.Sigma(dim, 0.25),
        "diagonal": gtsam.noiseModel.Diagonal.Sigmas(np.linspace(0.1, 0.7, dim)),
        "gaussian": gtsam.noiseModel.Gaussian.Covariance(A @ A.T + dim * np.eye(dim)),
        "robust": gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(1.345),
                                                 gtsam.noiseModel.Unit.Create(dim)),
    }


def pairs(group: str, noise) -> list:
    """(ours, GTSAM's) for a Between and a Prior factor on ``group``."""
    rng = np.random.default_rng(len(group))
    value = getattr(gtsam, group).Expmap(rng.normal(size=registry.group(group).dim))
    between = (getattr(factors, f"BetweenFactor{group}")(X1, 2, value, noise),
               getattr(gtsam, f"BetweenFactor{group}")(X1, 2, value, noise))
    prior = (getattr(factors, f"PriorFactor{group}")(5, value, noise),
             getattr(gtsam, f"PriorFactor{group}")(5, value, noise))
    return [between, prior]


_SETTLE = gtsam.noiseModel.Diagonal.Sigmas(np.array([0.5, 0.25]))


def settled(call):
    """``call()`` after a print that puts ``std::cout`` in one known state."""
    _SETTLE.__repr__()
    return call()


def printed(capfd, call) -> str:
    capfd.readouterr()
    settled(call)
    return capfd.readouterr().out


def formatter(key: int) -> str:
    return f"<{key}>"


@pytest.mark.parametrize("kind", ["unit", "isotropic", "diagonal", "gaussian", "robust"])
@pytest.mark.parametrize("group", GROUPS)
def test_factor_prints_as_gtsams(group, kind, capfd):
    for ours, native in pairs(group, noise_models(registry.group(group).dim)[kind]):
        assert settled(lambda: str(ours)) == settled(lambda: str(native))
        assert settled(lambda: repr(ours)) == settled(lambda: repr(native))
        assert settled(lambda: ours.__repr__("s: ", formatter)) == settled(lambda: native.__repr__("s: ", formatter))
        assert settled(lambda: ours.__repr__(s="t ")) == settled(lambda: native.__repr__(s="t "))
        expected = printed(capfd, native.print)
        assert "measured" in expected or "prior mean" in expected
        assert printed(capfd, ours.print) == expected
        assert printed(capfd, lambda: ours.print("s: ", formatter)) == printed(
            capfd, lambda: native.print("s: ", formatter))
        assert printed(capfd, lambda: print(ours)) == printed(capfd, lambda: print(native))


class Custom(gtsam.CustomFactor):
    """A user's own CustomFactor: printed by C++'s CustomFactor::print, as before."""

    def __init__(self):
        super().__init__(gtsam.noiseModel.Unit.Create(3), [7], lambda this, values, H: np.zeros(3))


def test_graph_prints_as_with_gtsams_factors(capfd):
    ours, native = gtsam.NonlinearFactorGraph(), gtsam.NonlinearFactorGraph()
    custom = Custom()
    for group in GROUPS:
        for a, b in pairs(group, noise_models(registry.group(group).dim)["diagonal"]):
            ours.add(a)
            native.add(b)
        other = gtsam.PriorFactorPoint3(9, np.array([1.0, 2.0, 3.0]), gtsam.noiseModel.Unit.Create(3))
        ours.add(other)
        native.add(other)
    ours.add(custom)
    native.add(custom)
    ours.remove(1)  # a null slot keeps its index
    native.remove(1)
    assert "CustomFactor on 7" in str(native) and "nullptr" in str(native)
    assert settled(lambda: str(ours)) == settled(lambda: str(native))
    assert settled(lambda: repr(ours)) == settled(lambda: repr(native))
    assert settled(lambda: ours.__repr__("g ", formatter)) == settled(lambda: native.__repr__("g ", formatter))
    assert printed(capfd, ours.print) == printed(capfd, native.print)
    assert printed(capfd, lambda: ours.print("g ", formatter)) == printed(
        capfd, lambda: native.print("g ", formatter))
    assert printed(capfd, lambda: print(ours)) == printed(capfd, lambda: print(native))


def test_graph_without_our_factors_is_printed_by_gtsam_on_itself():
    graph = gtsam.NonlinearFactorGraph()
    graph.add(gtsam.PriorFactorPose2(0, gtsam.Pose2(1, 2, 0.3), gtsam.noiseModel.Unit.Create(3)))
    assert factors.as_printed(graph) is graph
    assert settled(lambda: str(graph)) == settled(lambda: gtsam.NonlinearFactorGraph.__repr__._gtsam_method(graph))


def test_as_gtsam_is_gtsams_factor_with_the_same_error():
    noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([0.1, 0.2, 0.3]))
    values = gtsam.Values()
    values.insert(X1, gtsam.Pose2(0.1, 0.2, 0.3))
    values.insert(2, gtsam.Pose2(1.1, 0.7, 1.3))
    values.insert(5, gtsam.Pose2(-0.4, 0.5, -2.0))
    for ours, native in pairs("Pose2", noise):
        twin = ours.as_gtsam()
        assert type(twin) is type(native)
        assert list(twin.keys()) == list(native.keys())
        assert twin.noiseModel() is noise or twin.noiseModel().equals(noise, 0.0)
        assert twin.error(values) == native.error(values)
