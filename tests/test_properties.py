"""Group-generic properties, one suite parametrized over so3, se3, se2, sim2 and sim3.

Each identity is checked on hypothesis-drawn tangent vectors (rotation angles
spanning tiny to near 2π, translations 1e-3…1e2, Sim(2)/Sim(3) log-scales λ in ±3) and on
batches with random leading shapes.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from lie_factors import se2, se3, sim2, sim3, so3
from lie_factors.testing import series
from lie_factors.app.crosscheck import rotation_slice

GROUPS = {"so3": so3, "se3": se3, "se2": se2, "sim2": sim2, "sim3": sim3}
SETTINGS = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@st.composite
def tangents(draw, name, max_angle=np.pi * 0.999):
    G = GROUPS[name]
    n = G.DIM
    raw = np.array(draw(st.lists(st.floats(-1, 1), min_size=n, max_size=n)))
    log_angle = draw(st.floats(-12, 0))
    angle = draw(st.sampled_from([0.0, 10**log_angle * max_angle, max_angle * draw(st.floats(0, 1))]))
    log_trans = draw(st.floats(-3, 2))
    x = raw * 10**log_trans
    r = rotation_slice(name)
    w = raw[r]
    norm = np.linalg.norm(w)
    x[r] = angle * (w / norm if norm > 0 else np.eye(len(w))[0])
    if name == "sim2":
        x[3] = draw(st.floats(-3, 3))
    if name == "sim3":
        x[6] = draw(st.floats(-3, 3))
    return x


def expm(A):
    """exp(A) = I + A·dexp(A), with dexp from the independent power-series oracle."""
    return np.eye(A.shape[-1]) + A @ series.dexp(A)


def rel(A, B):
    return np.max(np.abs(A - B)) / max(1.0, np.max(np.abs(B)))


@pytest.mark.parametrize("name", list(GROUPS))
def test_exp_log_round_trip(name):
    G = GROUPS[name]

    @SETTINGS
    @given(tangents(name))
    def check(x):
        X = G.exp(x)
        assert rel(G.exp(G.log(X)), X) <= 1e-14
        assert rel(G.log(X), x) <= 1e-12 * max(1.0, np.linalg.norm(x))

    check()


@pytest.mark.parametrize("name", list(GROUPS))
def test_dexp_times_dlog_is_identity(name):
    G = GROUPS[name]

    @SETTINGS
    @given(tangents(name, max_angle=2 * np.pi * 0.9))
    def check(x):
        D, L = G.dexp(x), G.dlog(x)
        cond = np.linalg.norm(D, 2) * np.linalg.norm(L, 2)
        assert np.max(np.abs(D @ L - np.eye(G.DIM))) <= 1e-14 * cond

    check()


@pytest.mark.parametrize("name", list(GROUPS))
def test_Ad_of_exp_is_expm_of_ad(name):
    G = GROUPS[name]

    @SETTINGS
    @given(tangents(name, max_angle=2 * np.pi * 0.9))
    def check(x):
        assert rel(G.Ad(G.exp(x)), expm(G.ad(x))) <= 1e-12

    check()


@pytest.mark.parametrize("name", list(GROUPS))
def test_dexp_left_right_relation(name):
    """dexp(x) = Ad(exp(x))·dexp(−x): left and right Jacobians differ by the adjoint."""
    G = GROUPS[name]

    @SETTINGS
    @given(tangents(name, max_angle=2 * np.pi * 0.9))
    def check(x):
        assert rel(G.dexp(x), G.Ad(G.exp(x)) @ G.dexp(-x)) <= 1e-13

    check()


@pytest.mark.parametrize("name", list(GROUPS))
def test_dexp_matches_power_series_oracle(name):
    G = GROUPS[name]

    @SETTINGS
    @given(tangents(name, max_angle=2 * np.pi * 0.9))
    def check(x):
        assert rel(G.dexp(x), series.dexp(G.ad(x))) <= 1e-13
        assert rel(G.dlog(x), series.dlog(G.ad(x))) <= 1e-12 * np.linalg.cond(G.dexp(x))

    check()


@pytest.mark.parametrize("name", list(GROUPS))
def test_dexp_first_principles(name):
    """Seed Eq. 1: d/dε log(exp(x+ε)·exp(x)⁻¹) at ε = 0, by central differences."""
    G = GROUPS[name]

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


@pytest.mark.parametrize("name", list(GROUPS))
@pytest.mark.parametrize("fname", ["exp", "dexp", "dlog", "ad", "hat"])
def test_batch_equals_elementwise(name, fname):
    G = GROUPS[name]
    rng = np.random.default_rng(7)
    for shape in [(5,), (2, 3), (1, 1, 4)]:
        x = rng.normal(size=shape + (G.DIM,))
        out = getattr(G, fname)(x)
        flat = x.reshape(-1, G.DIM)
        each = np.stack([getattr(G, fname)(v) for v in flat])
        assert out.shape[: len(shape)] == shape
        assert np.array_equal(out.reshape(each.shape), each)
    empty = getattr(G, fname)(np.zeros((0, G.DIM)))
    assert empty.shape[0] == 0


@pytest.mark.parametrize("name", list(GROUPS))
def test_log_Ad_batch_equals_elementwise(name):
    G = GROUPS[name]
    rng = np.random.default_rng(8)
    X = G.exp(rng.normal(size=(3, 2, G.DIM)))
    for f in (G.log, G.Ad, G.inverse):
        out = f(X)
        each = np.stack([f(M) for M in X.reshape((-1,) + X.shape[2:])])
        assert np.array_equal(out.reshape(each.shape), each)


def test_series_rejects_bad_input():
    with pytest.raises(ValueError, match=r"\(\.\.\., n, n\)"):
        series.dexp(np.zeros((3, 4)))
    with pytest.raises(ValueError, match="NaN"):
        series.dexp(np.full((3, 3), np.nan))
