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
