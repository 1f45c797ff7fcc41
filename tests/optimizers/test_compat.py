"""lie_factors.optimizers.compat: GTSAM's writeG2o / readG2o / InitializePose3 / lago on our factors.

Reference: GTSAM's own function on the same graph built from GTSAM's own
factor classes.  Each test also shows that GTSAM's function, handed our
factors directly, does not give that result (the failure being fixed).
"""

from __future__ import annotations

import gtsam
import numpy as np
import pytest

from lie_factors.errors import InputError
from lie_factors import factors as F
from lie_factors.optimizers import InitializePose3, compat, lago, readG2o, writeG2o
from lie_factors.optimizers.compat import (G2oWriteError, from_gtsam, from_gtsam_graph, to_gtsam, to_gtsam_graph)

rng = np.random.default_rng(16)


def _random(group: str):
    if group == "Rot3":
        return gtsam.Rot3.Expmap(rng.normal(size=3))
    if group == "Pose3":
        return gtsam.Pose3.Expmap(rng.normal(size=6))
    if group == "Pose2":
        return gtsam.Pose2.Expmap(rng.normal(size=3))
    if group == "Similarity2":
        return gtsam.Similarity2.Expmap(rng.normal(size=4))
    return gtsam.Similarity3.Expmap(rng.normal(size=7))


DIMS = {"Rot3": 3, "Pose3": 6, "Pose2": 3, "Similarity2": 4, "Similarity3": 7}


def _same_noise(a, b) -> bool:
    """Same noise model (a Robust model has no equals: its Gaussian part and its loss)."""
    if isinstance(a, gtsam.noiseModel.Robust) or isinstance(b, gtsam.noiseModel.Robust):
        if not (isinstance(a, gtsam.noiseModel.Robust) and isinstance(b, gtsam.noiseModel.Robust)):
            return False
        x = np.linspace(0.0, 10.0, 41)
        return (type(a.robust()) is type(b.robust()) and a.noise().equals(b.noise(), 0.0)
                and all(a.robust().loss(t) == b.robust().loss(t) for t in x))
    return a.equals(b, 0.0)


def _noise_models(n: int, rng=rng):
    A = rng.normal(size=(n, n))
    return [
        gtsam.noiseModel.Isotropic.Sigma(n, 0.1),
        gtsam.noiseModel.Diagonal.Sigmas(rng.uniform(0.05, 0.5, n)),
        gtsam.noiseModel.Gaussian.Information(A @ A.T + n * np.eye(n)),
        gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(1.345),
                                       gtsam.noiseModel.Isotropic.Sigma(n, 0.2)),
    ]


# --------------------------------------------------------------------------- #
# The conversion
# --------------------------------------------------------------------------- #

@pytest.mark.parametrize("group", sorted(DIMS))
def test_to_and_from_gtsam_keep_keys_measurement_noise_and_error(group):
    n = DIMS[group]
    values = gtsam.Values()
    values.insert(3, _random(group))
    values.insert(8, _random(group))
    for model in _noise_models(n):
        ours_b = getattr(F, f"BetweenFactor{group}")(3, 8, _random(group), model)
        ours_p = getattr(F, f"PriorFactor{group}")(8, _random(group), model)
        for ours, native_cls in ((ours_b, getattr(gtsam, f"BetweenFactor{group}")),
                                 (ours_p, getattr(gtsam, f"PriorFactor{group}"))):
            native = to_gtsam(ours)
            assert type(native) is native_cls
            assert list(native.keys()) == list(ours.keys())
            assert _same_noise(native.noiseModel(), model)
            value = native.measured() if hasattr(native, "measured") else native.prior()
            mine = ours.measured() if hasattr(ours, "measured") else ours.prior()
            assert np.array_equal(value.matrix(), mine.matrix())
            # GTSAM's Similarity Jacobians differ from ours (see factors.py), not the errors.
            assert native.error(values) == pytest.approx(ours.error(values), rel=1e-12)
            back = from_gtsam(native)
            assert type(back) is type(ours)
            assert list(back.keys()) == list(ours.keys())
            assert _same_noise(back.noiseModel(), model)
            assert back.error(values) == ours.error(values)


def test_other_factors_pass_through_unchanged():
    landmark = gtsam.BearingRangeFactor3D(0, 1, gtsam.Unit3(np.array([1.0, 0, 0])), 2.0,
                                          gtsam.noiseModel.Isotropic.Sigma(3, 0.1))
    custom = gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(1), [0], lambda *a: np.zeros(1))
    for f in (landmark, custom):
        assert to_gtsam(f) is f
        assert from_gtsam(f) is f


def test_graph_conversion_keeps_order_and_returns_a_graph_without_ours_itself():
    noise = gtsam.noiseModel.Isotropic.Sigma(6, 0.1)
    native_only = gtsam.NonlinearFactorGraph()
    native_only.add(gtsam.BetweenFactorPose3(0, 1, gtsam.Pose3(), noise))
    assert to_gtsam_graph(native_only) is native_only
    mixed = gtsam.NonlinearFactorGraph()
    mixed.add(gtsam.PriorFactorPose3(0, gtsam.Pose3(), noise))
    mixed.add(F.BetweenFactorPose3(0, 1, _random("Pose3"), noise))
    mixed.add(gtsam.BetweenFactorPoint3(1, 2, np.zeros(3), gtsam.noiseModel.Unit.Create(3)))
    out = to_gtsam_graph(mixed)
    assert [type(out.at(k)).__name__ for k in range(out.size())] == [
        "PriorFactorPose3", "BetweenFactorPose3", "BetweenFactorPoint3"]
    assert type(out.at(1)) is gtsam.BetweenFactorPose3
    assert out.at(0) is mixed.at(0) or out.at(0).equals(mixed.at(0), 0.0)
    back = from_gtsam_graph(out)
    assert [type(back.at(k)) for k in range(back.size())] == [
        F.PriorFactorPose3, F.BetweenFactorPose3, gtsam.BetweenFactorPoint3]


# --------------------------------------------------------------------------- #
# writeG2o
# --------------------------------------------------------------------------- #

def _pose_graph(group: str, ours: bool, n: int = 6):
    """A loop of ``n`` poses, one edge per noise model kind, and the values."""
    lib = F if ours else gtsam
    B = getattr(lib, f"BetweenFactor{group}")
    dim = DIMS[group]
    gen = np.random.default_rng(7)
    models = _noise_models(dim, gen)[:3]  # Gaussian ones: g2o holds an information matrix
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    for i in range(n):
        values.insert(i, gtsam.Pose2.Expmap(gen.normal(size=3)) if group == "Pose2"
                      else gtsam.Pose3.Expmap(gen.normal(size=6)))
    for i in range(n):
        j = (i + 1) % n
        if group == "Pose2":
            Z = gtsam.Pose2.Expmap(gen.normal(size=3))
        else:
            Z = gtsam.Pose3.Expmap(gen.normal(size=6))
        graph.add(B(i, j, Z, models[i % 3]))
    return graph, values


@pytest.mark.parametrize("group,is3D", [("Pose2", False), ("Pose3", True)])
def test_writeG2o_writes_our_factors_as_gtsam_writes_its_own(group, is3D, tmp_path):
    ours, values = _pose_graph(group, ours=True)
    native, _ = _pose_graph(group, ours=False)
    # The failure being fixed: GTSAM's writer leaves every one of our edges out.
    gtsam.writeG2o(ours, values, str(tmp_path / "dropped.g2o"))
    assert "EDGE" not in (tmp_path / "dropped.g2o").read_text()

    writeG2o(ours, values, str(tmp_path / "ours.g2o"))
    gtsam.writeG2o(native, values, str(tmp_path / "native.g2o"))
    text = (tmp_path / "ours.g2o").read_text()
    assert text == (tmp_path / "native.g2o").read_text()
    assert sum(line.startswith("EDGE") for line in text.splitlines()) == ours.size()

    # Round trip: our readG2o gives our factors back, with what GTSAM's reader reads.
    graph, initial = readG2o(str(tmp_path / "ours.g2o"), is3D)
    ref, ref_initial = gtsam.readG2o(str(tmp_path / "ours.g2o"), is3D)
    assert graph.size() == ours.size() and initial.size() == values.size()
    assert initial.equals(ref_initial, 0.0)
    for k in range(graph.size()):
        f, r, o = graph.at(k), ref.at(k), ours.at(k)
        assert type(f) is type(o)
        assert list(f.keys()) == list(o.keys())
        assert f.measured().equals(r.measured(), 0.0)
        assert f.noiseModel().equals(r.noiseModel(), 0.0)
        # g2o holds 6 significant digits (GTSAM writes with the stream's default precision).
        assert f.measured().equals(o.measured(), 1e-5)
        assert f.noiseModel().equals(o.noiseModel(), 1e-3)


def test_writeG2o_mixed_graph_and_landmarks_as_gtsam(tmp_path):
    noise6 = gtsam.noiseModel.Isotropic.Sigma(6, 0.1)
    noise3 = gtsam.noiseModel.Isotropic.Sigma(3, 0.05)
    Z = gtsam.Pose3(gtsam.Rot3.Rz(0.25), np.array([1.0, 0.5, 0.0]))
    values = gtsam.Values()
    values.insert(0, gtsam.Pose3())
    values.insert(1, Z)
    values.insertPoint3(gtsam.symbol("l", 0), np.array([2.0, 1.0, 0.5]))
    ours, native = gtsam.NonlinearFactorGraph(), gtsam.NonlinearFactorGraph()
    for graph, B in ((ours, F.BetweenFactorPose3), (native, gtsam.BetweenFactorPose3)):
        graph.add(gtsam.BetweenFactorPose3(1, 0, Z.inverse(), noise6))
        graph.add(B(0, 1, Z, noise6))
        graph.add(gtsam.BearingRangeFactor3D(1, gtsam.symbol("l", 0), gtsam.Unit3(np.array([1.0, 0, 0])),
                                             1.5, noise3))
    writeG2o(ours, values, str(tmp_path / "ours.g2o"))
    gtsam.writeG2o(native, values, str(tmp_path / "native.g2o"))
    text = (tmp_path / "ours.g2o").read_text()
    assert text == (tmp_path / "native.g2o").read_text()
    assert [line.split()[0] for line in text.splitlines() if line.startswith("EDGE")] == [
        "EDGE_SE3:QUAT", "EDGE_SE3:QUAT", "EDGE_SE3_TRACKXYZ"]


def _landmark_graph(ready: bool):
    """GTSAM's known_landmark_localization_20.g2o as GTSAM reads it (BetweenFactorPose3 odometry,
    BearingRangeFactor3D landmark measurements, fixed-size Point3 landmarks), its landmark
    measurements as the ready factors equal to them (``ready``) or as GTSAM's."""
    from lie_factors.expressions.ready import from_gtsam as ready_factor

    native, values = gtsam.readG2o(gtsam.findExampleDataFile("known_landmark_localization_20.g2o"), True)
    graph = gtsam.NonlinearFactorGraph()
    for k in range(native.size()):
        graph.add(ready_factor(native.at(k)) if ready else native.at(k))
    return graph, values


def test_writeG2o_writes_ready_bearing_range_factors_as_gtsam_writes_its_own(tmp_path):
    """The ready BearingRangeFactor3D is GTSAM's EDGE_SE3_TRACKXYZ: the file is the one GTSAM's
    writer writes for GTSAM's factors, byte for byte."""
    ours, values = _landmark_graph(ready=True)
    native, _ = _landmark_graph(ready=False)
    assert type(ours.at(0)).__module__ == "lie_factors.expressions.ready"
    writeG2o(ours, values, str(tmp_path / "ours.g2o"))
    gtsam.writeG2o(native, values, str(tmp_path / "native.g2o"))
    text = (tmp_path / "ours.g2o").read_bytes()
    assert text == (tmp_path / "native.g2o").read_bytes()
    assert text.count(b"EDGE_SE3_TRACKXYZ") == 80 and text.count(b"EDGE_SE3:QUAT") == 19


def test_ready_factors_become_gtsams_own_and_back():
    """``as_gtsam()`` of each ready factor equal to GTSAM's is GTSAM's class with the same keys,
    measurement and noise model object: the same error at any values."""
    from lie_factors.expressions import ready

    noise1, noise2, noise3 = (gtsam.noiseModel.Isotropic.Sigma(d, 0.1) for d in (1, 2, 3))
    L0 = gtsam.symbol("l", 0)
    natives = [gtsam.BearingRangeFactor3D(0, L0, gtsam.Unit3(np.array([1.0, 2, 3])), 2.5, noise3),
               gtsam.BearingRangeFactor2D(0, L0, gtsam.Rot2(0.4), 1.5, noise2),
               gtsam.RangeFactor3D(0, L0, 2.0, noise1), gtsam.RangeFactor2D(0, L0, 2.0, noise1),
               gtsam.RangeFactorPose3(0, 1, 2.0, noise1), gtsam.RangeFactorPose2(0, 1, 2.0, noise1),
               gtsam.GPSFactor(0, np.array([1.0, 2, 3]), noise3)]
    for native in natives:
        ours = ready.from_gtsam(native)
        assert type(ours) is getattr(ready, type(native).__name__)
        back = to_gtsam(ours)
        assert type(back) is type(native) and list(back.keys()) == list(native.keys())
        assert back.noiseModel() is native.noiseModel() or back.noiseModel().equals(native.noiseModel(), 0.0)
        is3d = "3D" in type(native).__name__ or "Pose3" in type(native).__name__ or isinstance(native, gtsam.GPSFactor)
        values = gtsam.Values()
        if is3d:
            values.insert(0, gtsam.Pose3(gtsam.Rot3.Rodrigues(0.1, 0.2, 0.3), np.array([0.5, -0.2, 0.1])))
            values.insert(1, gtsam.Pose3(gtsam.Rot3(), np.array([1.0, 1.5, 2.0])))
            values.insertPoint3(L0, np.array([1.0, 1.5, 2.0]))
        else:
            values.insert(0, gtsam.Pose2(0.5, -0.2, 0.3))
            values.insert(1, gtsam.Pose2(1.0, 1.5, 0.0))
            values.insert(L0, np.array([1.0, 1.5]))
        assert back.error(values) == pytest.approx(native.error(values), rel=1e-12)


def _unwritable():
    n3 = gtsam.noiseModel.Isotropic.Sigma(3, 0.1)
    n6 = gtsam.noiseModel.Isotropic.Sigma(6, 0.1)
    return {
        "our prior": F.PriorFactorPose2(0, gtsam.Pose2(), n3),
        "GTSAM's prior": gtsam.PriorFactorPose3(0, gtsam.Pose3(), n6),
        "our Rot3 between": F.BetweenFactorRot3(0, 1, gtsam.Rot3(), n3),
        "our Similarity3 between": F.BetweenFactorSimilarity3(0, 1, gtsam.Similarity3(),
                                                              gtsam.noiseModel.Unit.Create(7)),
        "GTSAM's 2-D bearing-range": gtsam.BearingRangeFactor2D(0, 1, gtsam.Rot2(0.1), 2.0,
                                                                gtsam.noiseModel.Unit.Create(2)),
        "a user's CustomFactor": gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(1), [0],
                                                    lambda *a: np.zeros(1)),
    }


@pytest.mark.parametrize("what", sorted(_unwritable()))
def test_writeG2o_refuses_what_gtsams_writer_drops(what, tmp_path):
    factor = _unwritable()[what]
    graph, values = _pose_graph("Pose2", ours=True, n=3)
    graph.add(factor)
    # GTSAM's own writer, given GTSAM's classes, writes the three edges and
    # silently leaves this one out ...
    gtsam.writeG2o(to_gtsam_graph(graph), values, str(tmp_path / "gtsam.g2o"))
    edges = [line for line in (tmp_path / "gtsam.g2o").read_text().splitlines()
             if line.strip() and not line.startswith(("VERTEX", "PARAMS"))]
    assert len(edges) == 3
    # ... ours names it and writes nothing.
    out = tmp_path / "ours.g2o"
    with pytest.raises(G2oWriteError, match=rf"factor 3 \({type(factor).__name__} on .*no g2o edge type"):
        writeG2o(graph, values, str(out))
    assert not out.exists()


def test_writeG2o_refuses_a_robust_noise_model_as_gtsam_does(tmp_path):
    robust = _noise_models(3)[3]
    graph = gtsam.NonlinearFactorGraph()
    graph.add(F.BetweenFactorPose2(0, 1, gtsam.Pose2(1, 0, 0), robust))
    values = gtsam.Values()
    values.insert(0, gtsam.Pose2())
    values.insert(1, gtsam.Pose2(1, 0, 0))
    with pytest.raises(ValueError, match="invalid noise model"):  # GTSAM's, on its own factor
        gtsam.writeG2o(to_gtsam_graph(graph), values, str(tmp_path / "gtsam.g2o"))
    with pytest.raises(G2oWriteError, match=r"factor 0 \(BetweenFactorPose2 on 0, 1\) has a Robust noise model"):
        writeG2o(graph, values, str(tmp_path / "ours.g2o"))
    assert issubclass(G2oWriteError, InputError) and issubclass(G2oWriteError, ValueError)
    assert not (tmp_path / "ours.g2o").exists()


@pytest.mark.parametrize("value", [gtsam.Rot3(), np.array([1.0, 2.0, 3.0]), gtsam.Similarity3()],
                         ids=["Rot3", "vector", "Similarity3"])
def test_writeG2o_refuses_values_gtsams_writer_drops(value, tmp_path):
    graph, values = _pose_graph("Pose2", ours=True, n=3)
    values.insert(gtsam.symbol("r", 4), value)
    gtsam.writeG2o(graph, values, str(tmp_path / "gtsam.g2o"))
    assert len((tmp_path / "gtsam.g2o").read_text().splitlines()) == 3  # the three poses only
    with pytest.raises(G2oWriteError, match="1 of the 4 values have no g2o vertex type.*not poses: r4$"):
        writeG2o(graph, values, str(tmp_path / "ours.g2o"))
    assert not (tmp_path / "ours.g2o").exists()


def test_writeG2o_bad_arguments_raise_gtsams_exceptions(tmp_path):
    graph, values = _pose_graph("Pose2", ours=True, n=3)
    for args in (([1, 2], values), (graph, {0: gtsam.Pose2()})):
        with pytest.raises(TypeError, match="incompatible function arguments"):
            gtsam.writeG2o(*args, str(tmp_path / "x.g2o"))
        with pytest.raises(TypeError, match="incompatible function arguments"):
            writeG2o(*args, str(tmp_path / "x.g2o"))
    # GTSAM's writer writes nothing, silently, into a directory that does not exist.
    gtsam.writeG2o(graph, values, str(tmp_path / "no" / "x.g2o"))
    assert not (tmp_path / "no").exists()
    with pytest.raises(FileNotFoundError):
        writeG2o(graph, values, str(tmp_path / "no" / "x.g2o"))


# --------------------------------------------------------------------------- #
# readG2o and GTSAM's other readers
# --------------------------------------------------------------------------- #

@pytest.mark.parametrize("kernel", ["KernelFunctionTypeNONE", "KernelFunctionTypeHUBER", "KernelFunctionTypeTUKEY"])
@pytest.mark.parametrize("name,is3D", [("noisyToyGraph.txt", False), ("pose3example-offdiagonal.txt", True),
                                       ("w100_30.g2o", False)])
def test_readG2o_is_gtsams_with_our_factors(name, is3D, kernel):
    path = gtsam.findExampleDataFile(name)
    kernel = getattr(gtsam.KernelFunctionType, kernel)
    graph, initial = readG2o(path, is3D, kernel)
    ref, ref_initial = gtsam.readG2o(path, is3D, kernel)
    assert initial.equals(ref_initial, 0.0)
    _assert_ours_of_gtsams(graph, ref, F.BetweenFactorPose3 if is3D else F.BetweenFactorPose2)
    assert graph.error(initial) == pytest.approx(ref.error(ref_initial), rel=1e-12)


def _assert_ours_of_gtsams(mine, ref, ours: type) -> None:
    """``mine`` (a graph or a list of factors) holds ``ours`` in place of ``ref``'s Between
    factors: same keys, measured value and noise model, in the same order."""
    mine = [mine.at(k) for k in range(mine.size())] if isinstance(mine, gtsam.NonlinearFactorGraph) else mine
    ref = [ref.at(k) for k in range(ref.size())] if isinstance(ref, gtsam.NonlinearFactorGraph) else ref
    assert len(mine) == len(ref) > 0
    for f, r in zip(mine, ref):
        assert type(f) is ours
        assert list(f.keys()) == list(r.keys())
        assert f.measured().equals(r.measured(), 0.0)
        assert _same_noise(f.noiseModel(), r.noiseModel())


@pytest.mark.parametrize("reader,name,ours", [
    ("load2D", "w100.graph", F.BetweenFactorPose2),
    ("load3D", "pose3example.txt", F.BetweenFactorPose3),
    ("parse2DFactors", "noisyToyGraph.txt", F.BetweenFactorPose2),
    ("parse3DFactors", "pose3example.txt", F.BetweenFactorPose3),
])
def test_gtsams_other_readers_return_our_factors(reader, name, ours):
    path = gtsam.findExampleDataFile(name)
    mine, ref = getattr(compat, reader)(path), getattr(gtsam, reader)(path)
    if isinstance(ref, tuple):  # (graph, initial)
        assert mine[1].equals(ref[1], 0.0)
        mine, ref = mine[0], ref[0]
    _assert_ours_of_gtsams(mine, ref, ours)


def test_readG2o_keeps_landmark_factors_gtsams_and_raises_gtsams_errors():
    path = gtsam.findExampleDataFile("edge_se3_trackxyz_example.g2o")
    graph, initial = readG2o(path, True)
    assert type(graph.at(0)) is gtsam.BearingRangeFactor3D and initial.size() == 2
    with pytest.raises(ValueError, match="can not find file"):
        readG2o("/nonexistent/graph.g2o")


# --------------------------------------------------------------------------- #
# InitializePose3 and lago
# --------------------------------------------------------------------------- #

def _g2o_graphs(name: str, is3D: bool, prior: bool = True):
    """(ours, GTSAM's, initial): the file's graph, with a prior on pose 0, in both factor classes."""
    native, initial = gtsam.readG2o(gtsam.findExampleDataFile(name), is3D)
    ours = from_gtsam_graph(native)
    if prior:
        if is3D:
            model = gtsam.noiseModel.Diagonal.Variances(np.array([1e-6, 1e-6, 1e-6, 1e-4, 1e-4, 1e-4]))
            native.add(gtsam.PriorFactorPose3(0, gtsam.Pose3(), model))
            ours.add(F.PriorFactorPose3(0, gtsam.Pose3(), model))
        else:
            model = gtsam.noiseModel.Diagonal.Variances(np.array([1e-6, 1e-6, 1e-8]))
            native.add(gtsam.PriorFactorPose2(0, gtsam.Pose2(), model))
            ours.add(F.PriorFactorPose2(0, gtsam.Pose2(), model))
    assert type(ours.at(0)) is not type(native.at(0))
    return ours, native, initial


def _assert_same_values(a, b):
    """Values (or VectorValues) equal to the last bit."""
    assert type(a) is type(b)
    assert a.size() == b.size() > 0
    if isinstance(a, gtsam.Values):
        assert list(a.keys()) == list(b.keys())
    assert a.equals(b, 0.0)


def _gtsam_result(call):
    try:
        return call()
    except Exception as exc:  # noqa: BLE001 - the outcome, whatever it is, is what we compare
        return exc


def _assert_finds_none_of_ours(call):
    """The failure being fixed: GTSAM's initializer, handed our factors, finds no between factor."""
    broken = _gtsam_result(call)
    assert isinstance(broken, Exception) or broken.size() == 0


@pytest.mark.parametrize("name", ["pose3example.txt", "pose3example-grid.txt"])
def test_InitializePose3_on_our_factors_is_gtsams(name):
    ours, native, _ = _g2o_graphs(name, True)
    _assert_finds_none_of_ours(lambda: gtsam.InitializePose3.initialize(ours))
    _assert_same_values(InitializePose3.initialize(ours), gtsam.InitializePose3.initialize(native))
    _assert_same_values(InitializePose3.initializeOrientations(ours),
                        gtsam.InitializePose3.initializeOrientations(native))
    pose3graph = InitializePose3.buildPose3graph(ours)
    ref_graph = gtsam.InitializePose3.buildPose3graph(native)
    assert pose3graph.equals(ref_graph, 0.0)
    rotations = InitializePose3.computeOrientationsChordal(pose3graph)
    _assert_same_values(rotations, gtsam.InitializePose3.computeOrientationsChordal(ref_graph))
    # The same functions given a graph of ours in place of GTSAM's pose3Graph.
    ours_pose3 = from_gtsam_graph(pose3graph)
    assert type(ours_pose3.at(0)) is F.BetweenFactorPose3
    _assert_same_values(InitializePose3.computeOrientationsChordal(ours_pose3), rotations)
    _, _, initial = _g2o_graphs(name, True)
    _assert_same_values(InitializePose3.initialize(ours, initial, True),  # gradient rotations
                        gtsam.InitializePose3.initialize(native, initial, True))
    _assert_same_values(InitializePose3.initialize(ours, initial, False),
                        gtsam.InitializePose3.initialize(native, initial, False))


def test_InitializePose3_raises_gtsams_exceptions():
    ours, native, _ = _g2o_graphs("pose3example.txt", True, prior=False)
    ref = _outcome(lambda: gtsam.InitializePose3.initialize(native))
    assert ref[:2] == ("raised", RuntimeError) and "Indeterminate" in ref[2]
    assert _outcome(lambda: InitializePose3.initialize(ours)) == ref
    # computeOrientationsGradient given the chordal rotations: GTSAM's IndexError, as GTSAM's.
    prior_ours, prior_native, _ = _g2o_graphs("pose3example.txt", True)
    pose3graph = gtsam.InitializePose3.buildPose3graph(prior_native)
    guess = gtsam.InitializePose3.computeOrientationsChordal(pose3graph)
    ref = _outcome(lambda: gtsam.InitializePose3.computeOrientationsGradient(pose3graph, guess, 50, True))
    assert ref[:2] == ("raised", IndexError)
    ours_pose3 = from_gtsam_graph(pose3graph)
    assert _outcome(lambda: InitializePose3.computeOrientationsGradient(ours_pose3, guess, 50, True)) == ref
    with pytest.raises(TypeError, match="incompatible function arguments"):
        InitializePose3.initialize([1, 2, 3])


@pytest.mark.parametrize("name", ["noisyToyGraph.txt", "w100_30.g2o"])
def test_lago_on_our_factors_is_gtsams(name):
    ours, native, initial = _g2o_graphs(name, False)
    _assert_finds_none_of_ours(lambda: gtsam.lago.initialize(ours))
    _assert_same_values(lago.initialize(ours), gtsam.lago.initialize(native))
    _assert_same_values(lago.initialize(ours, False), gtsam.lago.initialize(native, False))
    _assert_same_values(lago.initialize(ours, useOdometricPath=False),
                        gtsam.lago.initialize(native, useOdometricPath=False))
    _assert_same_values(lago.initialize(ours, initial), gtsam.lago.initialize(native, initial))
    _assert_same_values(lago.initializeOrientations(ours), gtsam.lago.initializeOrientations(native))


def test_lago_raises_gtsams_exceptions():
    ours, native, _ = _g2o_graphs("noisyToyGraph.txt", False, prior=False)
    ref = _outcome(lambda: gtsam.lago.initialize(native))
    assert ref[:2] == ("raised", IndexError)
    assert _outcome(lambda: lago.initialize(ours)) == ref
    with pytest.raises(TypeError, match="incompatible function arguments"):
        lago.initialize("not a graph")


def test_lago_exposes_what_gtsam_lago_exposes():
    public = {n for n in dir(gtsam.lago) if not n.startswith("_")}
    assert public <= {n for n in vars(lago) if not n.startswith("_")}
    assert {n for n in dir(gtsam.InitializePose3) if not n.startswith("_")} <= set(dir(InitializePose3))


def _outcome(call):
    """``("values", Values)`` or ``("raised", type, message)``."""
    result = _gtsam_result(call)
    if isinstance(result, Exception):
        return ("raised", type(result), str(result))
    return ("values", result)


@pytest.mark.parametrize("name,is3D", [("pose3example.txt", True), ("noisyToyGraph.txt", False)])
def test_initializers_on_robust_factors_do_what_gtsam_does_with_its_own(name, is3D):
    # A robust model stays robust in the conversion: GTSAM's initializer then
    # treats our factor exactly as it treats its own with that model.
    # (GTSAM's readG2o takes no kernel for 3-D files: the models are wrapped here.)
    plain, _ = gtsam.readG2o(gtsam.findExampleDataFile(name), is3D)
    huber = gtsam.noiseModel.mEstimator.Huber.Create(1.345)
    native = gtsam.NonlinearFactorGraph()
    for k in range(plain.size()):
        f = plain.at(k)
        native.add(type(f)(*f.keys(), f.measured(), gtsam.noiseModel.Robust.Create(huber, f.noiseModel())))
    ours = from_gtsam_graph(native)
    assert isinstance(ours.at(0).noiseModel(), gtsam.noiseModel.Robust)
    if is3D:
        model = gtsam.noiseModel.Isotropic.Sigma(6, 1e-3)
        native.add(gtsam.PriorFactorPose3(0, gtsam.Pose3(), model))
        ours.add(F.PriorFactorPose3(0, gtsam.Pose3(), model))
        calls = [(InitializePose3.initialize, gtsam.InitializePose3.initialize)]
    else:
        model = gtsam.noiseModel.Diagonal.Sigmas(np.array([1e-3, 1e-3, 1e-4]))
        native.add(gtsam.PriorFactorPose2(0, gtsam.Pose2(), model))
        ours.add(F.PriorFactorPose2(0, gtsam.Pose2(), model))
        calls = [(lago.initialize, gtsam.lago.initialize)]
    for mine, theirs in calls:
        a, b = _outcome(lambda: mine(ours)), _outcome(lambda: theirs(native))
        assert a[0] == b[0]
        if a[0] == "values":
            _assert_same_values(a[1], b[1])
        else:
            assert a[1:] == b[1:]


# --------------------------------------------------------------------------- #
# GTSAM's other functions and classes that pick factors by class
# --------------------------------------------------------------------------- #

@pytest.mark.parametrize("group", sorted(DIMS))
def test_fastSync_on_our_factors_is_gtsams(group):
    values = [_random(group) for _ in range(3)]
    model = gtsam.noiseModel.Isotropic.Sigma(DIMS[group], 0.1)  # FastSync needs isotropic noise
    edges = [(i, j, values[i].between(values[j]).retract(0.01 * rng.normal(size=DIMS[group])))
             for i, j in ((0, 1), (1, 2), (2, 0))]
    graphs = {}
    for side, classes in (("ours", F), ("gtsam", gtsam)):
        Between, Prior = getattr(classes, f"BetweenFactor{group}"), getattr(classes, f"PriorFactor{group}")
        g = graphs[side] = gtsam.NonlinearFactorGraph()
        for i, j, measured in edges:
            g.add(Between(i, j, measured, model))
        g.add(Prior(0, values[0], model))
    sync = getattr(gtsam, f"fastSync{group}")
    # The failure being fixed: GTSAM's, handed our factors, finds no between factor.
    with pytest.raises(ValueError, match="at least one between"):
        sync(graphs["ours"])
    mine = getattr(compat, f"fastSync{group}")
    for args in ((), (gtsam.Ordering([2, 0, 1]),)):
        # GTSAM's on the converted graph to the bit; on the graph built with GTSAM's
        # classes to rounding (our Similarity factors return their measured value
        # rebuilt from its matrix: the same matrix, its rotation rounded differently).
        result = mine(graphs["ours"], *args)
        at = f"at{group}"  # Similarity's equals(·, 0) is never true: the matrices are compared
        same = sync(to_gtsam_graph(graphs["ours"]), *args)
        for k in range(3):
            assert np.array_equal(getattr(result, at)(k).matrix(), getattr(same, at)(k).matrix())
        assert result.equals(sync(graphs["gtsam"], *args), 1e-12)


def test_save2D_writes_our_factors_as_gtsam_writes_its_own(tmp_path):
    ours, native, initial = _g2o_graphs("noisyToyGraph.txt", False, prior=False)
    model = gtsam.noiseModel.Diagonal.Sigmas(np.array([0.1, 0.1, 0.05]))
    gtsam.save2D(ours, initial, model, str(tmp_path / "gtsam-on-ours.txt"))
    compat.save2D(ours, initial, model, str(tmp_path / "ours.txt"))
    gtsam.save2D(native, initial, model, str(tmp_path / "gtsam.txt"))
    expected = (tmp_path / "gtsam.txt").read_text()
    assert "EDGE2" in expected and (tmp_path / "ours.txt").read_text() == expected
    assert "EDGE2" not in (tmp_path / "gtsam-on-ours.txt").read_text()  # the failure being fixed


@pytest.mark.parametrize("d", [2, 3])
def test_ShonanAveraging_takes_a_list_of_our_factors(d):
    name = "noisyToyGraph.txt" if d == 2 else "pose3example.txt"
    path = gtsam.findExampleDataFile(name)
    native = getattr(gtsam, f"parse{d}DFactors")(path)
    ours = getattr(compat, f"parse{d}DFactors")(path)
    assert type(ours[0]) is (F.BetweenFactorPose2 if d == 2 else F.BetweenFactorPose3)
    Params = getattr(gtsam, f"ShonanAveragingParameters{d}")
    Shonan = getattr(gtsam, f"ShonanAveraging{d}")
    with pytest.raises(TypeError):  # the failure being fixed: the wrapper takes a list of GTSAM's classes
        Shonan(ours, Params(gtsam.LevenbergMarquardtParams()))
    mine = getattr(compat, f"ShonanAveraging{d}")(ours, Params(gtsam.LevenbergMarquardtParams()))
    ref = Shonan(native, Params(gtsam.LevenbergMarquardtParams()))
    assert isinstance(mine, Shonan)
    assert mine.nrUnknowns() == ref.nrUnknowns() > 0
    assert mine.numberMeasurements() == ref.numberMeasurements()
    np.testing.assert_array_equal(mine.denseD(), ref.denseD())
    np.testing.assert_array_equal(mine.denseQ(), ref.denseQ())
    initial = ref.initializeRandomly()
    assert mine.cost(initial) == ref.cost(initial)
    # Everything else the constructor takes is passed on as it is.
    from_file = getattr(compat, f"ShonanAveraging{d}")(path)
    assert from_file.nrUnknowns() == Shonan(path).nrUnknowns()
