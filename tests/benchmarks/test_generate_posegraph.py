"""benchmarks/generate_posegraph.py: seeded, readable by GTSAM, vertices = composed odometry, closures one turn apart."""

from __future__ import annotations

import filecmp
import os
import subprocess
import sys

import gtsam
import numpy as np

ROOT = os.path.join(os.path.dirname(__file__), "..", "..")
SCRIPT = os.path.join(ROOT, "benchmarks", "generate_posegraph.py")


def _write(path, *extra):
    subprocess.run([sys.executable, SCRIPT, "--poses", "2500", "--lap", "500", "--output", str(path), *extra],
                   check=True, capture_output=True)


def test_same_seed_same_file_other_seed_other_file(tmp_path):
    _write(tmp_path / "a.g2o")
    _write(tmp_path / "b.g2o")
    _write(tmp_path / "c.g2o", "--seed", "1")
    assert filecmp.cmp(tmp_path / "a.g2o", tmp_path / "b.g2o", shallow=False)
    assert not filecmp.cmp(tmp_path / "a.g2o", tmp_path / "c.g2o", shallow=False)


def test_graph_as_gtsam_reads_it(tmp_path):
    _write(tmp_path / "a.g2o")
    graph, values = gtsam.readG2o(str(tmp_path / "a.g2o"), True)
    n, lap, every = 2500, 500, 10
    closures = len(range(lap, n, every))
    assert values.size() == n and graph.size() == n - 1 + closures
    for k in range(graph.size()):
        f = graph.at(k)
        a, b = f.keys()
        if k < n - 1:  # odometry: vertex b is vertex a composed with the measurement
            assert (a, b) == (k, k + 1)
            pred = values.atPose3(a).compose(f.measured())
            assert np.max(np.abs(pred.matrix() - values.atPose3(b).matrix())) < 1e-9
        else:  # a loop closure to the pose one turn below, measured with the stated noise
            assert b - a == lap and b % every == 0
    sigmas = graph.at(0).noiseModel().sigmas()
    assert np.allclose(sigmas, [0.01, 0.01, 0.01, 0.05, 0.05, 0.05])
    # The closures agree with the truth the odometry drifted from: LM from the file brings the error
    # to about its expected value (half the residual degrees of freedom, 6 per independent cycle).
    graph.add(gtsam.PriorFactorPose3(0, gtsam.Pose3(), gtsam.noiseModel.Isotropic.Sigma(6, 1e-3)))
    result = gtsam.LevenbergMarquardtOptimizer(graph, values, gtsam.LevenbergMarquardtParams()).optimize()
    dof = 6 * closures
    assert 0.5 * dof * 0.8 < graph.error(result) < 0.5 * dof * 1.2


def test_street_walks_have_local_closures_and_the_stated_noise(tmp_path):
    # city (SE(2)) and hills (SE(3)): odometry composes to the vertices, closures tie a pose to
    # one at least --min-gap back, and LM from the file reaches about its expected error
    for shape, dim in (("city", 3), ("hills", 6)):
        path = tmp_path / f"{shape}.g2o"
        subprocess.run([sys.executable, SCRIPT, "--shape", shape, "--poses", "1500", "--seed", "3", "--output",
                        str(path)], check=True, capture_output=True)
        graph, values = gtsam.readG2o(str(path), dim == 6)
        n = values.size()
        assert n == 1500
        at = values.atPose3 if dim == 6 else values.atPose2
        gaps = []
        for k in range(graph.size()):
            f = graph.at(k)
            a, b = f.keys()
            if k < n - 1:
                assert (a, b) == (k, k + 1)
                pred = at(a).compose(f.measured())
                assert np.max(np.abs(pred.matrix() - at(b).matrix())) < 1e-9
            else:
                gaps.append(b - a)
        assert len(gaps) > 100 and min(gaps) >= 50
        assert len(set(gaps)) > 20  # where the walk returns, not at one period
        if dim == 6:
            graph.add(gtsam.PriorFactorPose3(0, gtsam.Pose3(), gtsam.noiseModel.Isotropic.Sigma(6, 1e-3)))
        else:
            graph.add(gtsam.PriorFactorPose2(0, gtsam.Pose2(), gtsam.noiseModel.Isotropic.Sigma(3, 1e-3)))
        result = gtsam.LevenbergMarquardtOptimizer(graph, values, gtsam.LevenbergMarquardtParams()).optimize()
        half_dof = 0.5 * dim * len(gaps)
        assert 0.8 * half_dof < graph.error(result) < 1.2 * half_dof
