"""Sweeps: many graphs, false-closure kinds, fractions, seeds and methods, one Dask task a case.

- :func:`sweep` (``lf.sweep``, ``lie-factors sweep SPEC --out RESULTS``): run a spec's cases
  (:mod:`.spec`, :mod:`.cases`) on a ``LocalCluster`` or a running scheduler (:mod:`.run`),
  a row per case in a results file that a rerun resumes (:mod:`.results`);
- :func:`summary` and :func:`plot` (``lf.sweep_summary``, ``lf.plot_sweep``, ``lie-factors
  sweep --summary RESULTS [--plot FILE.png]``): the worst and the median per cell (:mod:`.summary`).

Importing this package imports neither Dask nor numba.
"""

from __future__ import annotations

from .results import COLUMNS, read_results
from .run import sweep
from .spec import Spec, parse_spec, read_spec
from .summary import plot, summary

#: The front door's names (``lf.sweep_summary``, ``lf.plot_sweep``).
sweep_summary = summary
plot_sweep = plot

__all__ = ["sweep", "summary", "plot", "sweep_summary", "plot_sweep", "read_results", "read_spec", "parse_spec",
           "Spec", "COLUMNS"]
