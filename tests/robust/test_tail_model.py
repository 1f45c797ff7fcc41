"""The final check's model of a closure's statistic: its fit to a graph's own statistics and its
thresholds, against Monte Carlo draws from the model and against planted false closures."""

from __future__ import annotations

import numpy as np
import pytest

import lie_factors as lf
from lie_factors.robust.rejection import TAIL_DOF, TailModel
from lie_factors.robust.statistics import DOF_RANGE, f_quantile, fit_scaled_f
from support.replay_graphs import SMALL


def _draws(rng, n, nu, size, s=0.3):
    """s·n·F(n, ν) draws (ν = inf: s·χ²_n)."""
    denominator = 1.0 if np.isinf(nu) else rng.chisquare(nu, size) / nu
    return s * n * (rng.chisquare(n, size) / n) / denominator


@pytest.mark.parametrize("n", [3, 6])
@pytest.mark.parametrize("nu", [3.0, 8.0, 30.0])
def test_the_fit_recovers_the_scale_and_the_degrees_of_freedom(n, nu):
    rng = np.random.default_rng(int(10 * nu) + n)
    s, fitted = fit_scaled_f(_draws(rng, n, nu, 20_000), n, 0.9999)
    assert s == pytest.approx(0.3, rel=0.05)
    assert fitted == pytest.approx(nu, rel=0.2)


@pytest.mark.parametrize("n", [3, 6])
def test_a_light_tail_fits_as_chi2(n):
    rng = np.random.default_rng(n)
    s, fitted = fit_scaled_f(_draws(rng, n, np.inf, 5_000), n, 0.9999)
    assert s == pytest.approx(0.3, rel=0.05)
    # the quantile at 0.9999 within 10 % of χ²_n's (F(n, 5)'s is 3.5–4.7× it)
    assert f_quantile(n, fitted, 0.9999) / f_quantile(n, DOF_RANGE[1], 0.9999) < 1.1


def test_outliers_do_not_fatten_the_tail_they_would_need():
    """5 % gross outliers (100–1000× the median) leave the fit where the inliers put it; a fit over
    every statistic lets them fatten the tail until they pass."""
    rng = np.random.default_rng(7)
    clean = _draws(rng, 6, np.inf, 2_000)
    dirty = np.concatenate([clean, np.median(clean) * rng.uniform(100, 1000, 100)])
    s, nu = fit_scaled_f(dirty, 6, 0.9999)
    s_clean, nu_clean = fit_scaled_f(clean, 6, 0.9999)
    assert s == pytest.approx(s_clean, rel=0.01)
    assert s * f_quantile(6, nu, 0.9999) == pytest.approx(s_clean * f_quantile(6, nu_clean, 0.9999), rel=0.02)
    assert np.count_nonzero(dirty > s * 6 * f_quantile(6, nu, 0.9999)) >= 100
    from lie_factors.robust.statistics import _fit_below

    _, nu_all = _fit_below(np.sort(dirty), 6.0, np.inf)
    assert nu_all < 5


def test_the_fit_refuses_too_few_statistics():
    with pytest.raises(ValueError, match="two or more"):
        fit_scaled_f(np.array([1.0, np.nan, -1.0]), 3, 0.9999)


@pytest.mark.parametrize("n", [3, 6])
def test_the_tail_is_never_heavier_than_the_data_allow_nor_than_tail_dof(n):
    rng = np.random.default_rng(30 + n)
    light = TailModel(n, _draws(rng, n, np.inf, 3_000), 0.9999)
    assert f_quantile(n, light.dof, 0.9999) / f_quantile(n, DOF_RANGE[1], 0.9999) < 1.1 and light.scale == pytest.approx(0.3, rel=0.05)
    heavy = TailModel(n, _draws(rng, n, 3.0, 3_000), 0.9999)
    assert heavy.dof == TAIL_DOF  # the fit's ν ≈ 3 is heavier than allowed: ν = TAIL_DOF, s from the median
    assert heavy.scale == pytest.approx(np.median(_draws(rng, n, 3.0, 200_000)) / (n * f_quantile(n, TAIL_DOF, 0.5)),
                                        rel=0.08)
    assert TailModel(n, np.array([np.nan]), 0.9999).scale == 1.0  # no statistic: the noise models' own scale
    with pytest.raises(ValueError, match="finite mean"):
        TailModel(n, np.ones(3), 0.9999, dof=2.0)


@pytest.mark.parametrize("n", [3, 6])
@pytest.mark.parametrize("nu", [TAIL_DOF, 30.0, np.inf])
def test_group_thresholds_against_sums_of_independent_closures(n, nu):
    """Monte Carlo of sums of g independent statistics of a model with known s and ν: heavy-tailed
    (ν = 5: one big jump) and light-tailed (χ²: the sum is χ²_gn) within the Monte Carlo's error;
    between them (ν = 30) neither limit holds and the threshold is up to 20 % low (stricter)."""
    rng = np.random.default_rng(40 + n + (0 if np.isinf(nu) else int(nu)))
    p, N, s = 0.9999, 4_000_000, 0.03  # the 0.9999 quantile of F(3, 5) to about 2 %
    model = TailModel(n, np.ones(4), p)
    model.scale, model.dof = s, (DOF_RANGE[1] if np.isinf(nu) else nu)
    total = np.zeros(N)
    for g in range(1, 11):
        total += _draws(rng, n, nu, N, s)
        if g in (1, 2, 5, 10):
            ratio = model.threshold(g) / np.quantile(total, p)
            assert (0.8 < ratio < 1.05) if nu == 30.0 else (0.92 < ratio < 1.08), (g, ratio)


def _recall_on_small_grid(kind: str, seed: int) -> tuple[float, float]:
    c = lf.corrupt(SMALL, fraction=0.2, kind=kind, seed=seed)
    r = lf.optimize(c.graph, gnc="tls")
    planted, out = set(c.planted.tolist()), set(int(e) for e in r.outliers)
    return len(planted & out) / len(planted), len(planted & out) / max(len(out), 1)


def test_false_closures_that_a_heavy_tail_would_pass_are_rejected_on_a_light_tailed_graph():
    """smallGrid3D's true closures are χ²-like (largest statistic 3× the median), its random false
    ones 10–230× the median: under F(6, 5), whose 0.9999 quantile is 73× the median, the final check
    took most of them back (recall 0.14); fitted to the graph's own statistics it rejects them."""
    recall, precision = _recall_on_small_grid("uniform", 1)
    assert recall == 1.0 and precision > 0.9


def test_a_settled_run_is_ok_and_a_stage_at_its_bound_is_uncertain():
    from types import SimpleNamespace

    from lie_factors.robust.rejection import uncertainty

    ok, done = SimpleNamespace(exact=True), SimpleNamespace(stop="binary weights")
    assert uncertainty(ok, done, True) == () and uncertainty(None, done, True) == ()
    reasons = uncertainty(SimpleNamespace(exact=False), SimpleNamespace(stop="maxIterations"), False)
    assert len(reasons) == 3
    assert "branch budget" in reasons[0] and "iteration limit" in reasons[1] and "rounds" in reasons[2]


def test_the_status_reaches_the_result_and_its_json():
    c = lf.corrupt(SMALL, fraction=0.2, kind="uniform", seed=1)
    r = lf.optimize(c.graph, gnc="tls")
    assert r.robust_status["status"] in ("ok", "uncertain")
    assert (r.robust_status["status"] == "ok") == (r.robust_status["reasons"] == [])
    assert r.to_dict()["robust_status"] == r.robust_status
    assert lf.optimize(c.graph).robust_status is None
