"""Similarity3 graphs in the batch solver, against GTSAM's own Levenberg–Marquardt.

The graph is the scale-drift scenario (lie_factors.app.demo_sim3, small): a drifting
dead-reckoned start, odometry and loop closures.  References: GTSAM's C++ LM on
the same lie_factors factors (same iterations, same optimum), and GTSAM's LM on
its native Similarity3 factors (inexact Jacobians: it may stop at a slightly
worse point, never a better one).
"""

from __future__ import annotations

import gtsam
import numpy as np
import pytest

from lie_factors import batch, factors
from lie_factors.app import demo_sim3


def _max_diff(a: gtsam.Values, b: gtsam.Values) -> float:
    return max(np.abs(a.atSimilarity3(k).matrix() - b.atSimilarity3(k).matrix()).max() for k in a.keys())


def test_batch_matches_gtsam_lm_on_a_sim3_graph():
    problem = demo_sim3.simulate(40, seed=5)
    lie = demo_sim3.build_graph(problem, factors)
    native = demo_sim3.build_graph(problem, gtsam)
    params = gtsam.LevenbergMarquardtParams()
    opt = gtsam.LevenbergMarquardtOptimizer(lie, problem.initial, params)
    v_custom = opt.optimize()
    e_native = native.error(gtsam.LevenbergMarquardtOptimizer(native, problem.initial, params).optimize())

    res = batch.optimize(lie, problem.initial, gtsam.LevenbergMarquardtParams())
    assert res.converged and res.iterations == opt.iterations()
    assert res.final_error == pytest.approx(lie.error(v_custom), rel=1e-9)
    assert lie.error(res.values) == pytest.approx(res.final_error, rel=1e-9)
    assert _max_diff(res.values, v_custom) < 1e-7
    assert res.final_error <= e_native * (1 + 1e-9)
    assert res.final_error < 1e-2 * lie.error(problem.initial)
    # values come back as gtsam.Similarity3 with positive scale
    assert all(res.values.atSimilarity3(k).scale() > 0 for k in range(40))
