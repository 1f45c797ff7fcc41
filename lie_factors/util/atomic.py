"""Output files that are either complete or not there: probe before a long run, replace atomically."""

from __future__ import annotations

import os
import tempfile
from typing import Callable

from ..errors import InputError

__all__ = ["check_writable", "replace_atomically"]


def check_writable(path: str) -> None:
    """Raise :class:`InputError` unless a file can be created next to ``path``.

    Called before optimizing, so a long run is not wasted on a typo.  We create
    (and remove) a probe file instead of trusting ``os.access``, which says yes
    to root on read-only mounts.
    """
    if os.path.isdir(path):
        raise InputError(f"{path}: is a directory, expected a file name")
    directory = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(directory):
        raise InputError(f"{path}: directory {directory} does not exist")
    try:
        fd, probe = tempfile.mkstemp(dir=directory, prefix=".lie-factors-probe-")
    except OSError as exc:
        raise InputError(f"{path}: cannot write to {directory} ({exc.strerror})") from None
    os.close(fd)
    os.unlink(probe)


def replace_atomically(path: str, write: Callable[[str], None], suffix: str = "") -> None:
    """Call ``write(tmp)`` on a temporary file next to ``path``, then ``os.replace`` it.

    An existing ``path`` is untouched if ``write`` fails.
    """
    directory = os.path.dirname(os.path.abspath(path))
    try:
        fd, tmp = tempfile.mkstemp(dir=directory, prefix=".lie-factors-", suffix=suffix)
    except OSError as exc:
        raise InputError(f"{path}: cannot write to {directory} ({exc.strerror})") from None
    os.close(fd)
    try:
        write(tmp)
        if not os.path.exists(tmp) or os.path.getsize(tmp) == 0:
            raise InputError(f"{path}: writing produced an empty file")
        # mkstemp creates 0600; give the result the mode a plain open() would
        # (or keep the mode of the file being replaced).
        if os.path.exists(path):
            mode = os.stat(path).st_mode & 0o777
        else:
            umask = os.umask(0)
            os.umask(umask)
            mode = 0o666 & ~umask
        os.chmod(tmp, mode)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
