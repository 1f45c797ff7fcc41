"""g2o files we write keep every digit of the poses and edges, in GTSAM's layout.

References: GTSAM's own reader (``gtsam.readG2o``) for the round trip, and GTSAM's own writer
(``gtsam.writeG2o``, six significant digits) for the tags, ids, order and the information's
(translation, rotation) order of a Pose3 edge.
"""

from __future__ import annotations

import numpy as np
import pytest

import gtsam

from lie_factors.g2o import write_g2o


def _graph(dim: int, seed: int):
    rng = np.random.default_rng(seed)
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    n = 6
    for k in range(n):
        if dim == 2:
            values.insert(k, gtsam.Pose2(*(rng.normal(size=3) * [1e3, 1e-3, 1.0])))
        else:
            values.insert(k, gtsam.Pose3(gtsam.Rot3.Expmap(rng.normal(size=3)), rng.normal(size=3) * 1e3))
    d = 3 if dim == 2 else 6
    for i, j in [(0, 1), (1, 2), (2, 3), (3, 4), (4, 5), (5, 0), (1, 4)]:
        L = np.tril(rng.normal(size=(d, d))) + np.diag(rng.uniform(1.0, 3.0, d)) * 7.0
        info = L @ L.T
        noise = gtsam.noiseModel.Gaussian.Information(info)
        if dim == 2:
            graph.add(gtsam.BetweenFactorPose2(i, j, gtsam.Pose2(*rng.normal(size=3) * [31.7, 0.123456789, 1.0]), noise))
        else:
            m = gtsam.Pose3(gtsam.Rot3.Expmap(rng.normal(size=3)), rng.normal(size=3) * 31.7)
            graph.add(gtsam.BetweenFactorPose3(i, j, m, noise))
    return graph, values


def _numbers(path, tag):
    return [np.array([float(t) for t in line.split()[1:]]) for line in open(path) if line.split()[0] == tag]


@pytest.mark.parametrize("dim,seed", [(2, 0), (2, 1), (3, 0), (3, 1)])
def test_round_trip_through_gtsams_reader_is_exact(tmp_path, dim, seed):
    graph, values = _graph(dim, seed)
    path = str(tmp_path / "g.g2o")
    write_g2o(path, graph, values)
    graph2, values2 = gtsam.readG2o(path, dim == 3)
    for key in values.keys():
        a = values.atPose2(key) if dim == 2 else values.atPose3(key)
        b = values2.atPose2(key) if dim == 2 else values2.atPose3(key)
        # The quaternion is normalized on reading and a Pose2's angle goes through atan2: a few ulps.
        assert np.allclose(a.matrix(), b.matrix(), rtol=0, atol=4e-16 * max(1.0, np.abs(a.matrix()).max()))
    assert graph2.size() == graph.size()
    for k in range(graph.size()):
        f, g = graph.at(k), graph2.at(k)
        assert f.keys() == g.keys()
        assert np.allclose(f.measured().matrix(), g.measured().matrix(), rtol=0, atol=1e-13)
        I1, I2 = f.noiseModel().information(), g.noiseModel().information()
        assert np.abs(I1 - I2).max() <= 1e-12 * np.abs(I1).max()


@pytest.mark.parametrize("dim", [2, 3])
def test_same_layout_as_gtsams_writer(tmp_path, dim):
    graph, values = _graph(dim, 2)
    ours, theirs = str(tmp_path / "ours.g2o"), str(tmp_path / "gtsam.g2o")
    write_g2o(ours, graph, values)
    gtsam.writeG2o(graph, values, theirs)
    tags = [line.split()[0] for line in open(ours)]
    assert tags == [line.split()[0] for line in open(theirs)]
    for tag in set(tags):
        a, b = _numbers(ours, tag), _numbers(theirs, tag)
        assert len(a) == len(b)
        for x, y in zip(a, b):
            assert np.array_equal(x[:2 if tag.startswith("EDGE") else 1], y[:2 if tag.startswith("EDGE") else 1])
            # GTSAM's six significant digits: agreement to its rounding, nowhere more.
            assert np.allclose(x, y, rtol=1e-5, atol=1e-5)


def test_more_digits_than_gtsams_writer(tmp_path):
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    values.insert(0, gtsam.Pose2(1234.56789012, 0.0, 0.0))
    path = str(tmp_path / "g.g2o")
    write_g2o(path, graph, values)
    assert _numbers(path, "VERTEX_SE2")[0][1] == 1234.56789012


def test_lie_factors_factors_are_written_as_gtsams_own(tmp_path):
    """Our BetweenFactorPose3 and the ready BearingRangeFactor3D, written as GTSAM's own classes
    would be: GTSAM's known_landmark_localization_20.g2o through our writer gives the same file
    with GTSAM's factors and with ours."""
    from lie_factors import factors
    from lie_factors.expressions.ready import from_gtsam

    native, values = gtsam.readG2o(gtsam.findExampleDataFile("known_landmark_localization_20.g2o"), True)
    ours = gtsam.NonlinearFactorGraph()
    for k in range(native.size()):
        f = native.at(k)
        ours.add(factors.BetweenFactorPose3(*f.keys(), f.measured(), f.noiseModel())
                 if isinstance(f, gtsam.BetweenFactorPose3) else from_gtsam(f))
    write_g2o(str(tmp_path / "native.g2o"), native, values)
    write_g2o(str(tmp_path / "ours.g2o"), ours, values)
    text = (tmp_path / "ours.g2o").read_bytes()
    assert text == (tmp_path / "native.g2o").read_bytes()
    assert text.count(b"EDGE_SE3_TRACKXYZ") == 80 and text.count(b"EDGE_SE3:QUAT") == 19
