"""Every operation of the vocabulary: the chain rule's Jacobians against Richardson differences of
the definitions (GTSAM's right perturbation), on every group, at angles straddling the kernels'
branch thresholds."""

from __future__ import annotations

import numpy as np
import pytest

import lie_factors as lf
from lie_factors.expressions import ops
from lie_factors.expressions.types import value_type

from support.kinds import evaluate, group_exp, relative_error, richardson

GROUPS = ["Rot2", "Rot3", "Pose2", "Pose3", "Similarity2", "Similarity3"]
POSES = ["Pose2", "Pose3", "Similarity2", "Similarity3"]
ROTATIONS = ["Rot2", "Rot3"]
#: rotation angles straddling the coefficient kernels' bands (1e-3, 0.8, 2, π) and near 0; the
#: logarithm's outputs stay below 3 (a difference step must not cross its cut at π)
ANGLES = [0.0, 1e-9, 9.9e-4, 1.01e-3, 0.79, 0.81, 1.99, 2.01, 3.0]
INPUT_ANGLES = ANGLES + [np.pi - 1e-6]


def element(name: str, rng, angle: float) -> np.ndarray:
    """An element of ``name`` whose rotation turns by ``angle`` about a random axis, the rest random."""
    t = value_type(name)
    x = rng.normal(size=t.dim)
    if name == "Rot2":
        return group_exp(t, np.array([angle]))
    if t.rot == 3:
        axis = rng.normal(size=3)
        x[0:3] = angle * axis / np.linalg.norm(axis)
    else:
        x[2] = angle * rng.choice([-1.0, 1.0])
    return group_exp(t, x)


def vec(t: str, rng) -> np.ndarray:
    return rng.normal(size=value_type(t).dim)


def check(kind, values, constants, tol=1e-8):
    e, H = evaluate(kind, values, constants)
    assert np.all(np.isfinite(e))
    numeric = richardson(kind, values, constants)
    for j, (a, n) in enumerate(zip(H, numeric)):
        err = relative_error(a, n)
        assert err <= tol, (kind.name, j, err, a, n)


def near(rng, G, M):
    """A constant 0.3 away from M: localCoordinates(z, ·) of results near M stays far from its cut."""
    return M @ element(G, rng, 0.3)


def _group_ops(G):
    """(residual function, each part's result in numpy) of every group operation at once: each part
    localCoordinates(z_i, result_i), z_i a constant near its result."""
    t = value_type(G)
    inv = np.linalg.inv

    def residual(a, b, v, z0, z1, z2, z3, z4, z5):
        return ops.stack(z0.localCoordinates(a.compose(b)), z1.localCoordinates(a * b),
                         z2.localCoordinates(a.inverse()), z3.localCoordinates(a.between(b)),
                         z4.localCoordinates(a.retract(v)), z5.localCoordinates(ops.expmap(G, v)))

    def results(a, b, v):
        E = group_exp(t, v)
        return [a @ b, a @ b, inv(a), inv(a) @ b, a @ E, E]

    return residual, results


@pytest.mark.parametrize("group", GROUPS)
def test_group_operations_against_differences(group):
    """compose (and *), inverse, between, retract, expmap: the inputs' angles straddle every
    threshold, up to π − 1e-6."""
    t = value_type(group)
    residual, results = _group_ops(group)
    kind = lf.factor(group, group, f"Vector{t.dim}", **{f"z{i}": group for i in range(6)})(residual).kind
    rng = np.random.default_rng(GROUPS.index(group))
    for angle in INPUT_ANGLES:
        a, b = element(group, rng, angle), element(group, rng, angle)
        v = 0.5 * vec(f"Vector{t.dim}", rng)
        check(kind, [a, b, v], [near(rng, group, r) for r in results(a, b, v)])


@pytest.mark.parametrize("group", GROUPS)
def test_logmap_and_local_coordinates_straddle_the_log_thresholds(group):
    kind = lf.factor(group, group, group)(lambda a, base, b: ops.stack(a.logmap(), base.localCoordinates(b))).kind
    rng = np.random.default_rng(GROUPS.index(group))
    for angle in ANGLES:
        a = element(group, rng, angle)
        base = element(group, rng, rng.uniform(0, np.pi))
        check(kind, [a, base, base @ element(group, rng, angle)], [])


@pytest.mark.parametrize("group", POSES)
def test_parts_of_an_element(group):
    t = value_type(group)
    rng = np.random.default_rng(10 + POSES.index(group))
    Rot = "Rot2" if t.rot == 2 else "Rot3"
    sim = group.startswith("Similarity")
    kind = lf.factor(group, measured=Rot)(lambda x, z: ops.stack(z.localCoordinates(x.rotation()), x.translation(),
                                                                  *([x.scale()] if sim else []))).kind
    for angle in INPUT_ANGLES:
        x = element(group, rng, angle)
        check(kind, [x], [x[:t.rot, :t.rot] @ element(Rot, rng, 0.3)])


@pytest.mark.parametrize("group", POSES)
def test_points_through_poses(group):
    t = value_type(group)
    P = "Point2" if t.rot == 2 else "Point3"
    kind = lf.factor(group, P)(lambda x, p: ops.stack(x.transformFrom(p), x.transformTo(p))).kind
    rng = np.random.default_rng(20 + POSES.index(group))
    for angle in INPUT_ANGLES:
        check(kind, [element(group, rng, angle), vec(P, rng)], [])


@pytest.mark.parametrize("group", ROTATIONS)
def test_points_through_rotations(group):
    P = "Point2" if group == "Rot2" else "Point3"
    kind = lf.factor(group, P)(lambda r, p: ops.stack(r.rotate(p), r.unrotate(p))).kind
    rng = np.random.default_rng(30 + ROTATIONS.index(group))
    for angle in INPUT_ANGLES:
        check(kind, [element(group, rng, angle), vec(P, rng)], [])


def test_vector_operations():
    rng = np.random.default_rng(40)
    M = rng.normal(size=(2, 3))
    kinds = [
        lf.factor("Point3", "Point3")(lambda a, b: ops.stack(a + b, a - b, -a, 2.5 * a, b / 4.0, M @ a,
                                                              a.dot(b), a.norm(), b[1], a[0:2])),
        lf.factor("Pose2", "Point2", "Pose3", "Pose3")(
            lambda x, p, c, d: ops.stack(x.range(p), x.bearing(p).logmap(), ops.bearing(p).logmap(), c.range(d))),
    ]
    for kind in kinds:
        k = kind.kind
        for _ in range(5):
            vals = [element(t.name, rng, rng.uniform(0, 3)) if t.is_group else rng.normal(size=t.dim)
                    for t in k.variables]
            consts = [element(t.name, rng, 0.5) for t in k.constants]
            check(k, vals, consts)


@pytest.mark.parametrize("calibration", ["Cal3_S2", "Cal3Bundler"])
def test_projection(calibration):
    rng = np.random.default_rng(50)
    const = lf.factor("Pose3", "Point3", K=calibration)(lambda x, p, K: ops.project(x, p, K)).kind
    var = lf.factor("Pose3", calibration, "Point3")(lambda x, K, p: ops.project(x, p, K)).kind
    for angle in INPUT_ANGLES[:8]:
        x = element("Pose3", rng, angle)
        p = x[:3, :3] @ np.array([rng.normal(), rng.normal(), rng.uniform(2, 5)]) + x[:3, 3]  # in front
        K = (np.array([500.0, 480.0, 0.1, 320.0, 240.0]) if calibration == "Cal3_S2"
             else np.array([500.0, 0.1, -0.02]))
        check(const, [x, p], [K])
        check(var, [x, K, p], [])


def test_random_compositions_of_two_to_six_operations():
    """Random chains of 2–6 operations on Pose3, Pose2 and Similarity3 variables and points,
    reduced to vectors, against differences: six kinds of four chains each."""
    rng = np.random.default_rng(60)
    for trial in range(6):
        G = ["Pose3", "Pose2", "Similarity3"][trial % 3]
        t = value_type(G)
        P = "Point2" if t.rot == 2 else "Point3"
        plans = [[int(k) for k in rng.integers(0, 5, size=rng.integers(2, 7))] for _ in range(4)]

        def chain(a, b, p, plan):
            x, q = a, p
            for k in plan:
                if k == 0:
                    x = x.compose(b)
                elif k == 1:
                    x = x.between(b)
                elif k == 2:
                    x = x.inverse()
                elif k == 3:
                    q = x.transformFrom(q)
                else:
                    q = x.transformTo(q)
            return ops.stack(b.localCoordinates(x) * 0.1, q)

        kind = lf.factor(G, G, P)(lambda a, b, p, plans=plans: ops.stack(*[chain(a, b, p, pl) for pl in plans])).kind
        vals = [element(G, rng, rng.uniform(0, 0.5)), element(G, rng, rng.uniform(0, 0.5)), rng.normal(size=t.rot)]
        check(kind, vals, [], tol=1e-7)
