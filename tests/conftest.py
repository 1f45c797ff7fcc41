"""Fixtures shared by several test modules."""

from __future__ import annotations

import pytest


@pytest.fixture(params=["direct", "cvxopt"])
def cholmod_way(request, monkeypatch):
    """Both ways into CHOLMOD: direct (ctypes), and cvxopt's API."""
    from lie_factors.sparse import cholmod

    if request.param == "cvxopt":
        monkeypatch.setenv("LIE_FACTORS_CHOLMOD", "cvxopt")
    cholmod._direct.cache_clear()
    assert cholmod.direct_available() == (request.param == "direct")
    yield request.param
    monkeypatch.delenv("LIE_FACTORS_CHOLMOD", raising=False)
    cholmod._direct.cache_clear()


@pytest.fixture
def forbid_factorization(monkeypatch):
    """A function that, once called, fails the test at any numeric factorization: CHOLMOD's, GTSAM's
    elimination in the batch solver, the smoother's block factor.  A refusal that happens after it
    was decided by the structure of the graph alone, independent of the machine's rounding."""
    def forbid():
        from lie_factors.batch.solvers import GtsamSolver
        from lie_factors.incremental.cholesky import BlockFactor
        from lie_factors.sparse.cholmod import Cholesky

        def factorization(*args, **kwargs):
            pytest.fail("a numeric factorization ran: the structure alone must decide")

        for cls, name in ((Cholesky, "factorize"), (GtsamSolver, "solve"), (BlockFactor, "update"),
                          (BlockFactor, "update_arrays")):
            monkeypatch.setattr(cls, name, factorization)

    return forbid
