"""The whitening R (RᵀR = Λ) and the one-call preparation of an update's factors
(``batch.loops.prepare``), against numpy's LAPACK Cholesky and the refusals they must give."""

from __future__ import annotations

import numpy as np
import pytest

from lie_factors.batch.groups import whitening
from lie_factors.errors import InputError
from lie_factors.incremental.factor_arrays import FactorArrays


def _spd(rng, n, cond):
    Q, _ = np.linalg.qr(rng.normal(size=(n, n)))
    return (Q * np.geomspace(1.0, 1.0 / cond, n)) @ Q.T


@pytest.mark.parametrize("n", [1, 3, 6, 7])
@pytest.mark.parametrize("cond", [1.0, 1e4, 1e12])
def test_whitening_is_lapacks_cholesky(n, cond):
    rng = np.random.default_rng(n)
    A = np.stack([_spd(rng, n, cond) * 10.0 ** rng.integers(-3, 4) for _ in range(50)])
    R = whitening(A)
    L = np.linalg.cholesky(A)
    assert R.shape == A.shape
    assert np.all(np.tril(R, -1) == 0.0)
    for k in range(len(A)):
        scale = np.abs(L[k]).max()
        np.testing.assert_allclose(R[k], L[k].T, rtol=0, atol=1e-12 * cond ** 0.5 * scale)
        np.testing.assert_allclose(R[k].T @ R[k], A[k], rtol=0, atol=1e-14 * np.abs(A[k]).max())


def test_whitening_keeps_leading_shape_and_reads_the_lower_triangle():
    rng = np.random.default_rng(3)
    A = np.stack([_spd(rng, 6, 10.0) for _ in range(6)]).reshape(2, 3, 6, 6)
    assert whitening(A).shape == (2, 3, 6, 6)
    lower = np.tril(A[0, 0]) + np.triu(np.full((6, 6), 99.0), 1)  # LAPACK reads the lower triangle only
    np.testing.assert_array_equal(whitening(lower), whitening(A[0, 0]))


@pytest.mark.parametrize("bad", ["indefinite", "singular", "nan", "negative zero pivot"])
def test_whitening_refuses_what_is_not_positive_definite(bad):
    A = np.eye(6) * 4.0
    if bad == "indefinite":
        A[5, 5] = -1.0
    elif bad == "singular":
        A[2, 2] = 0.0
    elif bad == "nan":
        A[1, 1] = np.nan
    else:
        A[3, 3] = -0.0
    with pytest.raises(np.linalg.LinAlgError, match="not positive definite"):
        whitening(np.stack([np.eye(6), A]))
    message = "a measurement or information matrix is not finite" if bad == "nan" else \
        "an information matrix is not positive definite"
    with pytest.raises(InputError, match="between factors: " + message):
        FactorArrays("Pose3", [[0, 1], [1, 2]], np.stack([np.eye(4)] * 2), np.stack([np.eye(6), A]))


def test_prepare_matches_the_batch_problems_constants():
    """M⁻¹ and R from the one-call preparation equal the element inverse and whitening apart."""
    import gtsam

    rng = np.random.default_rng(9)
    M = np.stack([gtsam.Pose3.Expmap(rng.normal(size=6)).matrix() for _ in range(20)])
    info = np.stack([_spd(rng, 6, 100.0) for _ in range(20)])
    fa = FactorArrays("Pose3", np.stack([np.arange(20), np.arange(1, 21)], 1), M, info)
    np.testing.assert_allclose(fa.Minv, np.linalg.inv(M), rtol=0, atol=1e-12)
    np.testing.assert_array_equal(fa.R, whitening(info))


def test_prepare_reports_the_first_problem_in_the_stated_order():
    I4, I6 = np.eye(4), np.eye(6)
    nan6 = np.full((6, 6), np.nan)
    not_element = I4.copy()
    not_element[0, 0] = 2.0
    indefinite = -I6

    def refused(match, keys, M, info):
        with pytest.raises(InputError, match=match):
            FactorArrays("Pose3", keys, np.stack(M), np.stack(info))

    # a number that is not finite comes first, whatever else is wrong, on any factor
    refused("not finite", [[0, 0], [1, 2]], [not_element, I4], [indefinite, nan6])
    # then a self-loop, then the elements, then the information matrices
    refused("connects a key to itself", [[0, 1], [2, 2]], [not_element, I4], [indefinite, I6])
    refused(r"between 1 .*orthonormal|between 1", [[0, 1], [1, 2]], [I4, not_element], [indefinite, I6])
    refused("not positive definite", [[0, 1], [1, 2]], [I4, I4], [I6, indefinite])
    # priors: the same checks, named for priors
    with pytest.raises(InputError, match="prior factors: an information matrix is not positive definite"):
        FactorArrays("Pose3", prior_keys=[0], prior_measured=I4[None], prior_information=indefinite[None])
