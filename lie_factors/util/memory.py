"""The process's memory: resident now and at its peak, as a long run reports it."""

from __future__ import annotations

import sys

__all__ = ["usage", "size", "describe"]


def usage() -> tuple[int | None, int | None]:
    """(resident bytes now, peak resident bytes) of this process; None where the system does not say.

    Linux: ``VmRSS`` and ``VmHWM`` of ``/proc/self/status``; elsewhere the peak from
    ``resource.getrusage`` (``ru_maxrss``: KiB on Linux, bytes on macOS).
    """
    try:
        with open("/proc/self/status") as fh:
            fields = dict(line.split(":", 1) for line in fh if line.startswith(("VmRSS", "VmHWM")))
        return int(fields["VmRSS"].split()[0]) * 1024, int(fields["VmHWM"].split()[0]) * 1024
    except (OSError, KeyError, ValueError):
        pass
    try:
        import resource
    except ImportError:
        return None, None
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return None, peak if sys.platform == "darwin" else peak * 1024


def size(nbytes: int | None) -> str:
    """``1.21 GiB``, ``845 MiB``; ``?`` for None."""
    if nbytes is None:
        return "?"
    if nbytes >= 1 << 30:
        return f"{nbytes / (1 << 30):.2f} GiB"
    return f"{nbytes / (1 << 20):.0f} MiB"


def describe() -> str:
    """``RSS 1.21 GiB, peak 4.93 GiB`` (or only the peak where the current size is unknown)."""
    rss, peak = usage()
    return f"peak {size(peak)}" if rss is None else f"RSS {size(rss)}, peak {size(peak)}"
