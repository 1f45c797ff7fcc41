"""The line a command prints when its process compiled numba kernels (a first run on this machine)."""

from __future__ import annotations

import sys


def report_compile(args) -> None:
    """One stderr line if this process compiled numba kernels (none with ``--quiet``)."""
    from lie_factors.util.timing import compile_seconds

    seconds = compile_seconds()
    if seconds > 0 and not args.quiet:
        print(f"lie-factors: compiled numba kernels in {seconds:.1f} s (first run on this machine; "
              "cached for later runs, not counted in the optimization time)", file=sys.stderr, flush=True)
