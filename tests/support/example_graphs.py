"""Graphs GTSAM's examples build, for tests that compare our optimizers with GTSAM's on them."""

from __future__ import annotations

import importlib.util
import os

import gtsam
import numpy as np


def sfm_data():
    """GTSAM's examples/SFMdata.py, loaded from its file (importing ``gtsam.examples`` would add a
    name to the ``gtsam`` package, which the drop-in's tests compare with its own)."""
    path = os.path.join(os.path.dirname(gtsam.__file__), "examples", "SFMdata.py")
    spec = importlib.util.spec_from_file_location("SFMdata", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def spherical_sfm():
    """SFMExample_SphericalCamera's graph and start: SphericalCamera poses and Point3 landmarks on
    SFMdata's cube (no pose variable), GTSAM's own factors."""
    X, L = gtsam.symbol_shorthand.X, gtsam.symbol_shorthand.L
    data = sfm_data()
    points, poses = data.createPoints(), data.createPoses()
    graph = gtsam.NonlinearFactorGraph()
    graph.push_back(gtsam.PriorFactorSphericalCamera(X(0), gtsam.SphericalCamera(poses[0]),
                                                     gtsam.noiseModel.Diagonal.Sigmas(np.full(6, 0.1))))
    noise = gtsam.noiseModel.Isotropic.Sigma(2, 0.01)
    for i, pose in enumerate(poses):
        for j, point in enumerate(points):
            graph.push_back(gtsam.GeneralSFMFactorSphericalCamera(gtsam.SphericalCamera(pose).project2(point), noise,
                                                                  X(i), L(j)))
    graph.push_back(gtsam.PriorFactorPoint3(L(0), points[0], gtsam.noiseModel.Isotropic.Sigma(3, 0.1)))
    rng = np.random.default_rng(42)
    initial = gtsam.Values()
    for i, pose in enumerate(poses):
        initial.insert(X(i), gtsam.SphericalCamera(pose.retract(0.1 * rng.standard_normal(6))))
    for j, point in enumerate(points):
        initial.insert(L(j), point + 0.1 * rng.standard_normal(3))
    return graph, initial


def rosenbrock(start=(-1.2, 1.0)):
    """Rosenbrock's function as two residuals [10(y − x²), 1 − x] of one 2-vector (a GTSAM
    CustomFactor with exact Jacobians), from ``start`` (the classic (−1.2, 1) by default): its
    curved valley makes the model agree well, badly and not at all with the error along the way,
    so Levenberg–Marquardt rejects tries and accepts steps, and dogleg takes every branch."""
    def error(this, values, H):
        x, y = values.atVector(this.keys()[0])
        if H is not None:
            H[0] = np.array([[-20.0 * x, 10.0], [-1.0, 0.0]])
        return np.array([10.0 * (y - x * x), 1.0 - x])

    graph = gtsam.NonlinearFactorGraph()
    graph.add(gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(2), [0], error))
    initial = gtsam.Values()
    initial.insert(0, np.array(start, dtype=float))
    return graph, initial
