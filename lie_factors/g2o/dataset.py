"""Where a g2o file is, and its bytes: a path, or the name of a file shipped with GTSAM."""

from __future__ import annotations

import os

import gtsam

from ..errors import InputError


def _is_a_directory(path: str) -> InputError:
    return InputError(f"{path}: is a directory, expected a g2o file")


def _unreadable(path: str, exc: OSError) -> InputError:
    """The one-line error of a file that cannot be opened or read."""
    if isinstance(exc, IsADirectoryError):
        return _is_a_directory(path)
    return InputError(f"{path}: cannot read ({exc.strerror or exc})")


def resolve_dataset(name: str) -> str:
    """Return a readable file path for ``name``: an existing path, else a GTSAM example.

    Raises :class:`InputError` if it is neither.
    """
    if os.path.isdir(name):
        raise _is_a_directory(name)
    if os.path.isfile(name):
        return name
    # Only bare names are looked up among GTSAM's examples: a path with a
    # directory that does not exist is a typo, not a dataset name.
    if os.path.dirname(name) == "":
        try:
            return gtsam.findExampleDataFile(name)
        except (RuntimeError, OSError, ValueError):  # the wrapper raises FileNotFoundError
            pass
        raise InputError(
            f"{name}: no such file, and not a dataset shipped with GTSAM "
            f"(gtsam.findExampleDataFile)"
        )
    raise InputError(f"{name}: no such file")


def read_bytes(path: str) -> bytes:
    """The whole file; :class:`InputError` (one line) if it cannot be read."""
    try:
        with open(path, "rb") as fh:
            return fh.read()
    except OSError as exc:
        raise _unreadable(path, exc) from None
