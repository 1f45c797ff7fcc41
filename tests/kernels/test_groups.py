"""The checks every group shares: one suite parametrized over the registry.

Every group of :mod:`lie_factors.kernels.registry` (the matrix groups so3, se3,
se2, sim2, sim3 and the unit quaternions and dual quaternions): its public
functions' names and shapes, broadcasting, the single-element path against the
batch path, bad tangents, elements that are not in the group (every function
taking elements refuses them, ``compose`` on either side: one rule for every
group), round trips (exp∘log, hat∘vee, compose∘inverse), dexp being the left
Jacobian (at 50 digits, to first order, by central differences), dexp·dlog = I,
Ad(exp x) = expm(ad x) and dexp against the power-series oracle (hypothesis
draws: rotation angles from 0 to near 2π, translations 1e-3…1e2, log-scales λ
in ±3). What is particular to a group (accuracy against the 50-digit oracle
across its own branch thresholds, GTSAM, errata) is in its own test file.
"""

from __future__ import annotations

import importlib
import inspect
import math

import mpmath as mp
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from lie_factors.errors import InputError
from lie_factors import se2, sim2, sim3
from lie_factors.kernels import coeffs as C, public, registry
from lie_factors.testing import reference as ref
from lie_factors.testing import series

MATRIX = list(registry.GROUPS)
ALL = MATRIX + list(registry.QUATERNIONS)
MODULES = {name: importlib.import_module(registry.group(name).module) for name in ALL}
PI = math.pi
SETTINGS = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def _ops(name):
    """The operations of the group's module (:data:`lie_factors.kernels.public.OPERATIONS`)."""
    info = registry.group(name)
    return [op for op in public.OPERATIONS
            if info.corner != registry.UNIT or op.name in public.QUATERNION_OPERATIONS]


def _tangents(name, n, seed=0, max_angle=3.0):
    """n tangent vectors: rotation angles uniform in [0, max_angle), the rest ~N(0, 1)."""
    info = registry.group(name)
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(n, info.dim))
    r = info.rotation_slice
    w = rng.normal(size=(n, r.stop - r.start))
    x[:, r] = w * (rng.uniform(0.0, max_angle, size=n) / np.linalg.norm(w, axis=1))[:, None]
    return x


def _elements(name, n, seed=0):
    return MODULES[name].exp(_tangents(name, n, seed))


# ------------------------------------------------------------------ the sweep of round trips

#: Rotation angles of every sweep; dexp and dlog also beyond π.
ANGLES = [0.0, 1e-200, 1e-15, 1e-8, 1e-4, 1e-2, 0.3, 1.0, 2.0, 3.0, PI - 1e-12]
BEYOND_PI = [PI * (1 + 1e-9), 4.0, 5.0, 6.0, 2 * PI - 1e-3]
NORMS = [1e-3, 1.0, 1e2]
LAMBDAS = [0.0, 1e-200, -1e-8, 1e-3, -0.3, 1.0, -5.0]
#: Each group's branch thresholds in θ (straddled by the sweep), and for Sim(2)/Sim(3) in
#: |z| = |λ + iθ| and in λ.
_ROTATION = [C.A_TAYLOR, C.C_TAYLOR, C.E_TAYLOR, C.QA_TAYLOR, C.QB_TAYLOR]
THETA_THRESHOLDS = {"so3": _ROTATION, "se3": _ROTATION + [C.EF_TAYLOR], "se2": [se2.ANGLE_TAYLOR, se2.C_TAYLOR],
                    "sim2": [], "sim3": _ROTATION + [sim3.SPECTRAL]}
Z_THRESHOLDS = {"sim2": [sim2.PHI_TAYLOR], "sim3": [sim3.Z_BAND, sim3.Z_BAND_W]}
LAMBDA_THRESHOLDS = {"sim3": [sim3.L_TAYLOR, sim3.LAM_SPECTRAL]}


def _straddle(t):
    return [t * (1 - 1e-9), t * (1 + 1e-9)]


def _sweep(name, beyond_pi=False, seed=0, angles=None):
    """Tangents (N, n) over every angle of ANGLES (and BEYOND_PI; or ``angles``), the group's
    thresholds straddled, translations of norms NORMS in random directions and, for
    Sim(2)/Sim(3), log-scales LAMBDAS, |λ + iθ| thresholds straddled in several directions and
    λ = ±θ → 0."""
    info = registry.group(name)
    rng = np.random.default_rng(seed)
    scaled = info.corner == registry.POSITIVE
    if angles is None:
        angles = ANGLES + [t for thr in THETA_THRESHOLDS[name] for t in _straddle(thr)]
        angles += BEYOND_PI if beyond_pi else []
        pairs = [(th, lam) for th in angles for lam in (LAMBDAS if scaled else [0.0])]
        for r in Z_THRESHOLDS.get(name, []):
            pairs += [(f * abs(math.sin(a)), f * math.cos(a)) for f in _straddle(r) for a in (0.0, 0.7, PI / 2, 2.5)]
        for lam in LAMBDA_THRESHOLDS.get(name, []):
            pairs += [(th, s * f) for f in _straddle(lam) for th in (0.0, 0.3, 2.0) for s in (1.0, -1.0)]
        if scaled:  # θ and λ → 0 together
            pairs += [(m, s * m) for m in (1e-200, 1e-10, 1e-5, 1e-3, 0.1, 2.0) for s in (1.0, -1.0)]
    else:
        pairs = [(th, lam) for th in angles for lam in (LAMBDAS if scaled else [0.0])]
    r = info.rotation_slice
    rest = np.ones(info.dim, dtype=bool)
    rest[r] = False
    if scaled:
        rest[-1] = False
    out = []
    for th, lam in pairs:
        for norm in NORMS:
            x = rng.normal(size=info.dim)
            w = x[r]
            x[r] = th * w / np.linalg.norm(w) if len(w) > 1 else th * (-1.0) ** len(out)  # ±θ
            if scaled:
                x[-1] = lam
            if rest.any():
                x[rest] *= norm / np.linalg.norm(x[rest])
            out.append(x)
    return np.array(out)


def _angles(name, x):
    return np.linalg.norm(x[:, registry.group(name).rotation_slice], axis=1)


# ------------------------------------------------------------------ names, shapes, broadcasting


@pytest.mark.parametrize("name", ALL)
def test_functions_are_named_documented_and_of_the_group(name):
    info = registry.group(name)
    for op in _ops(name):
        f = getattr(MODULES[name], op.name)
        assert f.__name__ == op.name and f.__module__ == info.module
        shapes = [public.shape(kind, info) for kind in op.args + (op.result,)]
        assert all(f"(..., {', '.join(map(str, s))})" in f.__doc__ for s in shapes), (op.name, f.__doc__)
        assert f"lie_factors.{name}" in f.__doc__ and "Raises InputError" in f.__doc__
        params = inspect.signature(f).parameters.values()
        assert [p.name for p in params] == list(public._names(op, info))
        assert all(p.kind is inspect.Parameter.POSITIONAL_ONLY for p in params)
        assert f.__doc__.startswith(f"{op.name}({', '.join(p.name for p in params)}): ")


def _arguments(name, batch, seed=0):
    """One valid argument of every kind, of batch shape ``batch``."""
    K = MODULES[name]
    x = _tangents(name, max(1, int(np.prod(batch))), seed)[: int(np.prod(batch))]
    x = x.reshape(batch + x.shape[1:])
    X = K.exp(x)
    return {public.TANGENT: x, public.ELEMENT: X, public.ALGEBRA: K.hat(x) if hasattr(K, "hat") else None}


@pytest.mark.parametrize("batch", [(), (5,), (2, 3), (2, 1, 4), (0,)])
@pytest.mark.parametrize("name", ALL)
def test_batch_shapes_and_each_element_as_alone(name, batch):
    """Every function broadcasts over leading axes; each element of a batch is, bit for bit,
    what the element alone gives (the single-element path: the same cores)."""
    K, info = MODULES[name], registry.group(name)
    args = _arguments(name, batch)
    for op in _ops(name):
        f = getattr(K, op.name)
        a = [args[kind] for kind in op.args]
        out = f(*a)
        assert out.shape == batch + public.shape(op.result, info), op.name
        assert out.dtype == np.float64
        for idx in np.ndindex(*batch):
            assert np.array_equal(out[idx], f(*(v[idx] for v in a))), (op.name, idx)


@pytest.mark.parametrize("name", ALL)
def test_compose_broadcasts_batch_axes(name):
    K = MODULES[name]
    e = len(registry.group(name).element)
    X = K.exp(_tangents(name, 4, seed=1))[:, None]
    Y = K.exp(_tangents(name, 5, seed=2))
    Z = K.compose(X, Y)
    assert Z.shape[:2] == (4, 5) and Z.ndim == 2 + e
    for i in range(4):
        for j in range(5):
            assert np.array_equal(Z[i, j], K.compose(X[i, 0], Y[j]))


# ------------------------------------------------------------------ bad input


@pytest.mark.parametrize("name", ALL)
def test_bad_tangents_raise(name):
    """Wrong shapes, NaN and ±inf (at every position, any memory order, alone or in a batch)
    and what is no number raise InputError naming the problem, for every function of tangents."""
    K, n = MODULES[name], registry.group(name).dim
    x = _tangents(name, 1)[0]
    for op in _ops(name):
        if op.args[0] != public.TANGENT:
            continue
        f = getattr(K, op.name)
        for shape in ((n - 1,), (n + 1,), (1,), (), (2, n + 1)):
            with pytest.raises(InputError, match=rf"expected shape \(\.\.\., {n}\)"):
                f(np.zeros(shape))
        with pytest.raises(InputError, match=rf"expected shape \(\.\.\., {n}\)"):
            f(np.float64(1.0))
        with pytest.raises(InputError, match="convert"):
            f("abc")
        for bad_value in (np.nan, np.inf, -np.inf):
            for i in range(n):
                bad = x.copy()
                bad[i] = bad_value
                for arg in (bad, np.asfortranarray(bad), np.stack([x, bad])):
                    with pytest.raises(InputError, match="NaN or inf"):
                        f(arg)


def _matrix_defects(name):
    """(label, bad element, expected message) for every defect a matrix group checks."""
    info = registry.group(name)
    X = _elements(name, 1, seed=7)[0]
    d, m = info.rot_dim, info.mat
    out = []
    for i in range(m):
        for j in range(m):
            for v in (np.nan, np.inf):
                B = X.copy()
                B[i, j] = v
                out.append((f"{v} at {i},{j}", B, "NaN or inf"))
    B = X.copy()
    B[:d, :d] *= 1.0 + 1e-6
    out.append(("scaled rotation", B, "orthonormal"))
    B = X.copy()
    B[0, :d] = -B[0, :d]  # a reflection: still orthonormal, det = -1
    out.append(("reflection", B, "reflection"))
    if info.corner != registry.NO_CORNER:
        for j in range(m - 1):
            B = X.copy()
            B[m - 1, j] = 1e-300
            out.append((f"last row entry {j}", B, "last row"))
        if info.corner == registry.POSITIVE:
            for s in (0.0, -0.0, -1.0, -np.finfo(float).tiny):
                B = X.copy()
                B[m - 1, m - 1] = s
                out.append((f"scale corner {s}", B, "s > 0"))
        else:
            for s in (2.0, 1.0 + 2.0**-52, 0.0, -1.0):
                B = X.copy()
                B[m - 1, m - 1] = s
                out.append((f"corner {s}", B, "last row"))
    return out


def _element_takers(name):
    """Every function of the group that takes elements, as a function of one element (the
    other argument of compose a valid element): compose on either side."""
    K = MODULES[name]
    good = _elements(name, 1, seed=8)[0]
    fs = {op.name: getattr(K, op.name) for op in _ops(name) if op.args == (public.ELEMENT,)}
    fs["compose(bad, good)"] = lambda B: K.compose(B, good)
    fs["compose(good, bad)"] = lambda B: K.compose(good, B)
    return fs


@pytest.mark.parametrize("name", MATRIX)
def test_non_elements_raise(name):
    """Every function taking elements, compose on either side, refuses every defect, alone (the
    fast path) and in a batch (the general path), with the same message."""
    good = _elements(name, 1, seed=5)[0]
    for label, B, what in _matrix_defects(name):
        for fname, f in _element_takers(name).items():
            for arg in (B, np.asfortranarray(B)):
                with pytest.raises(InputError, match=what) as fast:
                    f(arg)
                with pytest.raises(InputError) as general:
                    f(arg[None])
                assert str(fast.value) == str(general.value), (fname, label)
            with pytest.raises(InputError, match=what):
                f(np.stack([good, B]))


@pytest.mark.parametrize("name", MATRIX)
def test_wrong_matrix_shapes_and_non_finite_algebra_raise(name):
    K, m = MODULES[name], registry.group(name).mat
    for f in list(_element_takers(name).values()) + [K.vee]:
        for shape in ((m - 1, m - 1), (m + 1, m + 1), (m, m + 1), (m * m,)):
            with pytest.raises(InputError, match="expected shape"):
                f(np.eye(*shape[:2]) if len(shape) == 2 else np.zeros(shape))
    H = K.hat(_tangents(name, 1)[0])
    for i in range(m):
        bad = H.copy()
        bad[i, -1] = np.nan
        with pytest.raises(InputError, match="NaN or inf"):
            K.vee(bad)


@pytest.mark.parametrize("name", ALL)
def test_compose_takes_group_elements_only_in_every_group(name):
    """The one rule of compose, for every group: both arguments must be elements of the group
    (a matrix, or a quaternion, off the group composes to garbage). The same for inverse."""
    K, info = MODULES[name], registry.group(name)
    X = _elements(name, 2, seed=9)
    off = X[0].copy()
    if info.corner == registry.UNIT:
        off *= 1.0 + 1e-6  # not of unit norm
    else:
        off[: info.rot_dim, : info.rot_dim] *= 1.0 + 1e-6  # not a rotation
    for args in ((off, X[1]), (X[1], off), (off[None], X), (X, off[None])):
        with pytest.raises(InputError, match="unit|orthonormal"):
            K.compose(*args)
    with pytest.raises(InputError, match="unit|orthonormal"):
        K.inverse(off)
    assert K.compose(X[0], X[1]).shape == info.element


@pytest.mark.parametrize("name", list(registry.QUATERNIONS))
def test_non_unit_quaternions_raise(name):
    K, info = MODULES[name], registry.group(name)
    q = K.exp(np.array([0.3, -0.2, 0.1, 1.0, 2.0, 3.0][: info.dim]))
    for f in (K.log, K.inverse, lambda p: K.compose(p, q), lambda p: K.compose(q, p)):
        for i in range(q.size):
            bad = q.copy()
            bad[i] = np.nan
            with pytest.raises(InputError, match="NaN or inf"):
                f(bad)
        with pytest.raises(InputError, match="unit"):
            f(q * (1.0 + 2e-9))
        with pytest.raises(InputError, match=rf"expected shape \(\.\.\., {q.size}\)"):
            f(q[:-1])
    if name == "dual_quaternion":
        bad = q.copy()
        bad[4:] += 1e-6 * q[:4]  # q_r · q_d ≠ 0: not a unit dual quaternion
        with pytest.raises(InputError, match="unit dual quaternions"):
            K.log(bad)
    K.log(q * (1.0 + 5e-10))  # inside the tolerance


# ------------------------------------------------------------------ round trips


@pytest.mark.parametrize("name", MATRIX)
def test_hat_vee_round_trip_exact(name):
    K = MODULES[name]
    x = _sweep(name)
    H = K.hat(x)
    assert np.array_equal(K.vee(H), x)
    hat = ref.GROUPS[name][1]
    for v, h in zip(x[::7], H[::7]):
        assert np.array_equal(h, ref.to_numpy(hat(ref.mpf_vec(v))))


@pytest.mark.parametrize("name", MATRIX)
def test_exp_log_round_trips(name):
    """log(exp(x)) = x for rotation angles below π; exp(log(X)) = X at π, where log picks one
    of the two logarithms."""
    K = MODULES[name]
    x = _sweep(name)
    x = x[_angles(name, x) < PI]
    y = K.log(K.exp(x))
    scale = np.maximum(1.0, np.max(np.abs(x), axis=1))
    assert np.max(np.max(np.abs(y - x), axis=1) / scale) <= 1e-14
    X = K.exp(_sweep(name, angles=[PI]))
    E = np.abs(K.exp(K.log(X)) - X)
    assert np.max(np.max(E, axis=(1, 2)) / np.maximum(1.0, np.max(np.abs(X), axis=(1, 2)))) <= 1e-14


@pytest.mark.parametrize("name", MATRIX)
def test_compose_inverse_against_50_digits(name):
    """compose and inverse to ≤ 1e-14 of the 50-digit product and inverse, and X·X⁻¹ = I to
    4e-15 of the scale of X and X⁻¹."""
    K = MODULES[name]
    X = K.exp(_sweep(name, seed=1))
    Xi = K.inverse(X)
    scale = np.maximum.reduce([np.ones(len(X)), np.max(np.abs(X), axis=(1, 2)), np.max(np.abs(Xi), axis=(1, 2))])
    E = np.abs(K.compose(X, Xi) - np.eye(K.MAT))
    assert np.max(np.max(E, axis=(1, 2)) / scale) <= 4e-15
    for A, B in zip(X[::5], X[::-5]):
        Am, Bm = mp.matrix(A.tolist()), mp.matrix(B.tolist())
        assert ref.rel_err(K.compose(A, B), Am * Bm) <= 1e-14
        assert ref.rel_err(K.inverse(A), mp.inverse(Am)) <= 1e-14


@pytest.mark.parametrize("name", MATRIX)
def test_ad_is_the_bracket(name):
    """ad(x) y = vee([hat x, hat y]) (Eade, Eq. 11)."""
    K = MODULES[name]
    x, y = _tangents(name, 20, seed=3), _tangents(name, 20, seed=4)
    Hx, Hy = K.hat(x), K.hat(y)
    bracket = K.vee(Hx @ Hy - Hy @ Hx)
    ours = np.einsum("nij,nj->ni", K.ad(x), y)
    assert np.max(np.abs(ours - bracket) / np.maximum(1.0, np.abs(bracket))) <= 1e-15


@pytest.mark.parametrize("name", MATRIX)
def test_Ad_of_exp_is_expm_of_ad_at_50_digits(name):
    """Ad(exp(x)) = expm(ad x) (Eade, Eq. 9), against the 50-digit matrix exponential."""
    K = MODULES[name]
    for x in _sweep(name, angles=[0.0, 1e-5, 0.7, 3.0])[::4]:
        assert ref.rel_err(K.Ad(K.exp(x)), mp.expm(ref.ad(name, ref.mpf_vec(x)))) <= 1e-14


@pytest.mark.parametrize("name", list(registry.QUATERNIONS))
def test_quaternion_round_trips(name):
    K, info = MODULES[name], registry.group(name)
    x = _sweep("so3" if name == "quaternion" else "se3")
    q = K.exp(x)
    below = _angles("so3", x[:, :3]) < PI - 1e-6
    scale = np.maximum(1.0, np.max(np.abs(x), axis=1))
    assert np.max((np.max(np.abs(K.log(q) - x), axis=1) / scale)[below]) <= 1e-13
    identity = np.zeros(info.element)
    identity[0] = 1.0
    E = np.abs(K.compose(q, K.inverse(q)) - identity)
    assert np.max(np.max(E, axis=1) / np.maximum(1.0, np.max(np.abs(q), axis=1))) <= 1e-15


# ------------------------------------------------------------------ dexp: the left Jacobian


#: A point of each group where the left-Jacobian tests expand.
POINT = {
    "so3": [0.4, -1.1, 2.3],
    "se3": [0.4, -1.1, 2.3, 0.5, 2.0, -1.0],
    "se2": [0.4, -1.1, 1.3],
    "sim2": [0.4, -1.1, 1.3, -0.6],
    "sim3": [0.4, -1.1, 1.3, 0.7, -0.2, 2.0, -0.6],
}


@pytest.mark.parametrize("name", MATRIX)
def test_dexp_is_the_left_jacobian_at_50_digits(name):
    """exp(x + ε) exp(x)⁻¹ = I + hat(dexp(x) ε) + O(ε²), at 50 digits with ε = 1e-20."""
    K, n = MODULES[name], registry.group(name).dim
    x = np.array(POINT[name])
    eps = mp.mpf(10) ** -20
    J = K.dexp(x)
    E0i = mp.inverse(ref.exp(name, ref.mpf_vec(x)))
    vee = ref.GROUPS[name][2]
    for j in range(n):
        xe = ref.mpf_vec(x)
        xe[j] += eps
        col = [v / eps for v in vee(ref.exp(name, xe) * E0i - mp.eye(K.MAT))]
        assert max(abs(col[i] - J[i, j]) for i in range(n)) < 1e-14


@pytest.mark.parametrize("name", MATRIX)
def test_dexp_first_order_expansion(name):
    """exp(x + ε) ≈ exp(dexp(x) ε) · exp(x) to second order in ε = 1e-7."""
    K, n = MODULES[name], registry.group(name).dim
    x = np.array(POINT[name])
    eps = 1e-7 * np.array([0.3, 0.5, -0.2, 0.1, -0.4, 0.7, 0.2][:n])
    lhs = K.exp(x + eps)
    rhs = K.compose(K.exp(K.dexp(x) @ eps), K.exp(x))
    assert np.abs(lhs - rhs).max() < 1e-13


@pytest.mark.parametrize("name", MATRIX)
def test_dexp_times_dlog_is_identity_on_the_sweep(name):
    K = MODULES[name]
    x = _sweep(name, beyond_pi=True, seed=2)
    D, L = K.dexp(x), K.dlog(x)
    P = np.einsum("nij,njk->nik", D, L)
    scale = np.maximum(1.0, np.max(np.abs(L), axis=(1, 2)))
    assert np.max(np.max(np.abs(P - np.eye(K.DIM)), axis=(1, 2)) / scale) <= 1e-13


# ------------------------------------------------------------------ group-generic properties (hypothesis)


@st.composite
def tangents(draw, name, max_angle=np.pi * 0.999):
    info = registry.group(name)
    n = info.dim
    raw = np.array(draw(st.lists(st.floats(-1, 1), min_size=n, max_size=n)))
    log_angle = draw(st.floats(-12, 0))
    angle = draw(st.sampled_from([0.0, 10**log_angle * max_angle, max_angle * draw(st.floats(0, 1))]))
    log_trans = draw(st.floats(-3, 2))
    x = raw * 10**log_trans
    r = info.rotation_slice
    w = raw[r]
    big = np.max(np.abs(w))
    # Scaled by its largest entry first: the norm of subnormal entries loses digits, and the
    # "unit" axis would carry the angle past the bound.
    w = w / big if big > 0 else np.eye(len(w))[0]
    x[r] = angle * w / np.linalg.norm(w)
    if info.corner == registry.POSITIVE:
        x[-1] = draw(st.floats(-3, 3))
    return x


def expm(A):
    """exp(A) = I + A·dexp(A), with dexp from the independent power-series oracle."""
    return np.eye(A.shape[-1]) + A @ series.dexp(A)


def rel(A, B):
    return np.max(np.abs(A - B)) / max(1.0, np.max(np.abs(B)))


@pytest.mark.parametrize("name", MATRIX)
def test_exp_log_round_trip_drawn(name):
    G = MODULES[name]

    @SETTINGS
    @given(tangents(name))
    def check(x):
        X = G.exp(x)
        assert rel(G.exp(G.log(X)), X) <= 1e-14
        assert rel(G.log(X), x) <= 1e-12 * max(1.0, np.linalg.norm(x))

    check()


@pytest.mark.parametrize("name", MATRIX)
def test_round_trips_drawn_uniformly(name):
    """Tangents with every entry uniform in ±100 (rotation angle in (−π, π), log-scale in ±5):
    log(exp(x)) = x and dexp(x)·dlog(x) = I to 1e-13 of max(1, max|x|)."""
    G, info = MODULES[name], registry.group(name)

    @settings(max_examples=200, deadline=None)
    @given(st.lists(st.floats(-100, 100), min_size=info.dim, max_size=info.dim),
           st.floats(-math.pi + 1e-9, math.pi - 1e-9), st.floats(-5, 5))
    def check(entries, angle, lam):
        v = np.array(entries)
        r = info.rotation_slice
        w = v[r]
        v[r] = angle * (w / np.linalg.norm(w) if np.linalg.norm(w) > 0 else np.eye(len(w))[0])
        if info.corner == registry.POSITIVE:
            v[-1] = lam
        scale = max(1.0, np.abs(v).max())
        assert np.max(np.abs(G.log(G.exp(v)) - v)) <= 1e-13 * scale
        assert np.max(np.abs(G.dexp(v) @ G.dlog(v) - np.eye(info.dim))) <= 1e-13 * scale

    check()


@pytest.mark.parametrize("name", MATRIX)
def test_derivative_identities_drawn(name):
    """At rotation angles up to 0.9·2π: dexp·dlog = I (to the conditioning), Ad(exp(x)) =
    expm(ad x), dexp(x) = Ad(exp(x))·dexp(−x) (left and right Jacobians differ by the
    adjoint), and dexp, dlog against the power series of ad_x."""
    G = MODULES[name]

    @SETTINGS
    @given(tangents(name, max_angle=2 * np.pi * 0.9))
    def check(x):
        D, L = G.dexp(x), G.dlog(x)
        cond = np.linalg.norm(D, 2) * np.linalg.norm(L, 2)
        assert np.max(np.abs(D @ L - np.eye(G.DIM))) <= 1e-14 * cond
        assert rel(G.Ad(G.exp(x)), expm(G.ad(x))) <= 1e-12
        assert rel(D, G.Ad(G.exp(x)) @ G.dexp(-x)) <= 1e-13
        assert rel(D, series.dexp(G.ad(x))) <= 1e-13
        assert rel(L, series.dlog(G.ad(x))) <= 1e-12 * np.linalg.cond(D)

    check()


@pytest.mark.parametrize("name", MATRIX)
def test_dexp_central_differences(name):
    """Eade, Eq. 1: d/dε log(exp(x+ε)·exp(x)⁻¹) at ε = 0, by central differences."""
    G = MODULES[name]

    @settings(max_examples=25, deadline=None)
    @given(tangents(name, max_angle=np.pi * 0.9))
    def check(x):
        h = 1e-6 * max(1.0, np.linalg.norm(x))
        Xinv = G.inverse(G.exp(x))
        J = np.empty((G.DIM, G.DIM))
        for j in range(G.DIM):
            e = np.zeros(G.DIM)
            e[j] = h
            plus = G.log(G.compose(G.exp(x + e), Xinv))
            minus = G.log(G.compose(G.exp(x - e), Xinv))
            J[:, j] = (plus - minus) / (2 * h)
        assert rel(J, G.dexp(x)) <= 1e-6

    check()


def test_series_rejects_bad_input():
    with pytest.raises(ValueError, match=r"\(\.\.\., n, n\)"):
        series.dexp(np.zeros((3, 4)))
    with pytest.raises(ValueError, match="NaN"):
        series.dexp(np.full((3, 3), np.nan))
