"""The ways a user swaps lie_factors' drop-ins into code written for ``gtsam``.

Shared by the runners of GTSAM's shipped examples (``run_gtsam_example.py``) and
unit tests (``run_gtsam_tests.py``):

* ``original``: the code as GTSAM ships it;
* ``swapped``: its import lines changed, as README tells users: ``import gtsam``
  becomes ``import lie_factors.dropin as gtsam`` and ``from gtsam import ...``
  becomes ``from lie_factors.dropin import ...`` (``from gtsam.X import`` lines
  are left alone: nothing in GTSAM's submodules is replaced);
* ``assigned``: the code as shipped, with every name lie_factors.dropin replaces
  assigned into ``gtsam``'s namespace before it runs (``gtsam.ISAM2 =
  lie_factors.optimizers.ISAM2``, ...), the way to swap a class into a code base
  whose modules each ``import gtsam``. It changes the ``gtsam`` module for the
  rest of the process: the runners run in processes of their own;
* ``smoother``: the code as shipped, with lie_factors' own smoother assigned in
  ISAM2's place (``gtsam.ISAM2 = lf.Smoother``, ``gtsam.IncrementalFixedLagSmoother =
  lf.IncrementalFixedLagSmoother``).
"""

from __future__ import annotations

import re

MODES = ("original", "swapped", "assigned", "smoother")

IMPORT = re.compile(r"(?m)^(\s*)import gtsam\s*$")
FROM_IMPORT = re.compile(r"(?m)^(\s*)from gtsam import ")


def swap_imports(source: str) -> tuple[str, int]:
    """``source`` with its gtsam import lines pointed at lie_factors.dropin, and how many were changed."""
    source, n1 = IMPORT.subn(r"\1import lie_factors.dropin as gtsam", source)
    source, n2 = FROM_IMPORT.subn(r"\1from lie_factors.dropin import ", source)
    return source, n1 + n2


def assign_ours() -> list[str]:
    """Assign every name lie_factors.dropin replaces into ``gtsam``'s namespace; the names."""
    import gtsam

    import lie_factors.dropin as dropin

    for name in dropin.REPLACED:
        setattr(gtsam, name, getattr(dropin, name))
    return sorted(dropin.REPLACED)


def assign_smoother() -> None:
    """Assign lie_factors' incremental smoother and its fixed-lag smoother in place of GTSAM's."""
    import gtsam

    import lie_factors as lf

    gtsam.ISAM2 = lf.Smoother
    gtsam.IncrementalFixedLagSmoother = lf.IncrementalFixedLagSmoother


def start(mode: str) -> None:
    """Check ``mode``; in ``assigned`` mode, :func:`assign_ours` (once per process, before any code runs)."""
    if mode not in MODES:
        raise SystemExit(f"mode must be one of {', '.join(MODES)}, not {mode!r}")
    if mode == "assigned":
        assign_ours()
    elif mode == "smoother":
        assign_smoother()


def prepare(mode: str, source: str, what: str) -> str:
    """``source`` to run in ``mode``: in ``swapped`` mode with its import lines changed."""
    if mode == "swapped":
        source, changed = swap_imports(source)
        if not changed:
            raise RuntimeError(f"{what}: no gtsam import line to change")
    return source
