"""benchmarks/outliers.py --suite --sweep: the suite's cases as a sweep's spec, checked as any spec is."""

from __future__ import annotations

import argparse
import os

import pytest

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", ".."))


@pytest.fixture
def outliers(monkeypatch):
    monkeypatch.syspath_prepend(os.path.join(ROOT, "benchmarks"))
    import outliers as module

    return module


def test_the_suite_as_a_spec(outliers):
    from lie_factors.sweeps.cases import cases_of
    from lie_factors.sweeps.spec import parse_spec

    args = argparse.Namespace(graphs=["intel", "sphere2500"], seeds=[1, 2], native_timeout=90.0, no_native=False)
    spec = parse_spec(outliers.sweep_spec(args, [0.2, 0.5], ["uniform", "group"]), os.path.join(ROOT, "s.toml"))
    assert [g.path for g in spec.graphs] == [os.path.join(ROOT, "data", f"{n}.g2o") for n in args.graphs]
    assert spec.timeout == 90.0 and (spec.kinds, spec.fractions, spec.seeds) == (("uniform", "group"), (0.2, 0.5),
                                                                                 (1, 2))
    methods = {m.name: (m.run, m.options) for m in spec.methods}
    assert methods == {"gtsam-gnc": ("optimize", {"backend": "native", "gnc": "tls", "consistency": False}),
                       "lie-factors": ("optimize", {"gnc": "tls"}),
                       "lie-factors-online": ("replay", {"gnc": "tls"})}
    assert len(cases_of(spec)) == 2 * 2 * 2 * 2 * 3
    args.no_native = True
    spec = parse_spec(outliers.sweep_spec(args, [0.2], ["near"]), os.path.join(ROOT, "s.toml"))
    assert [m.name for m in spec.methods] == ["lie-factors", "lie-factors-online"]
    with pytest.raises(SystemExit, match="chainN"):
        outliers.graph_path("chain1000")
