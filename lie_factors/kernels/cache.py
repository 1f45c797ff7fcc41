"""What makes numba's on-disk cache of compiled kernels safe to load: unique symbols, whole-package keys.

Numba names the machine code of a compiled function after its module, its
qualified name, its argument types and a *unique id*, ``v<uid>`` in the
mangled symbol. The uid counts the functions compiled so far in the process
(``numba.core.bytecode.FunctionIdentity._unique_ids``, 1, 2, 3, …), so it is
unique within one process only. A cached library carries, besides its own
function, a copy of every compiled function it calls, under those symbols and
with weak linkage, and when a process loads libraries the first definition of a
symbol serves every library that names it.

Two functions can share a qualified name and argument types while having
different bodies: the functions a factory builds, such as numba's own
quicksort, whose ``make_quicksort_impl.<locals>.run_quicksort1`` is an in-place
sort under ``np.sort`` and an argsort under ``np.argsort``. When two processes
happen to compile both under the same uid and each writes a cached library, a
process that loads both runs one library's calls on the other's body (an
argsort that returns sorted values instead of indices, and so writes out of
bounds). Numba's issue numba/numba#10486 describes the same collision between
forked processes.

:func:`install` removes both ways to it:

- **Unique symbols.** Each process draws its uids from a random 63-bit start,
  above every uid it already used: two processes' symbols coincide with
  probability about ``n² / 2⁶³`` for ``n`` compilations, whatever the
  history of either.
- **Whole-package keys.** A kernel's cache entry is keyed by a digest of every
  source file of this package and of the numba, llvmlite and NumPy versions,
  not by the kernel's own file: a cached kernel never carries a copy of a callee
  that was edited since, nor a library written under another numbering.
"""

from __future__ import annotations

import hashlib
import itertools
import secrets
from functools import lru_cache
from pathlib import Path

import llvmlite
import numba
import numpy as np
from numba.core import caching
from numba.core.bytecode import FunctionIdentity

#: The package whose kernels these keys cover: its directory.
PACKAGE = Path(__file__).resolve().parents[1]


@lru_cache(maxsize=None)
def package_digest() -> str:
    """Digest of everything compiled code can depend on: every ``.py`` file of the package
    (its relative path and contents) and the numba, llvmlite and NumPy versions."""
    digest = hashlib.sha256()
    for version in (numba.__version__, llvmlite.__version__, np.__version__):
        digest.update(version.encode() + b"\0")
    for path in sorted(PACKAGE.rglob("*.py")):
        digest.update(path.relative_to(PACKAGE).as_posix().encode() + b"\0")
        digest.update(path.read_bytes())
    return digest.hexdigest()


def _in_package(path: str) -> bool:
    try:
        return Path(path).resolve().is_relative_to(PACKAGE)
    except OSError:
        return False


class PackageLocator(caching._CacheLocator):
    """Numba cache locator of the package's kernels: where numba would put the cache (the
    locator numba would have chosen decides), keyed by :func:`package_digest`."""

    def __init__(self, inner: caching._CacheLocator):
        self._inner = inner

    def ensure_cache_path(self):
        self._inner.ensure_cache_path()

    def get_cache_path(self):
        return self._inner.get_cache_path()

    def get_disambiguator(self):
        return self._inner.get_disambiguator()

    def get_source_stamp(self):
        return package_digest()

    def __getattr__(self, name):
        # numba reads attributes of the locator it chose (``_py_file`` and ``_lineno`` when it
        # warns that a function cannot be cached): they are the inner locator's
        return getattr(self._inner, name)

    @classmethod
    def from_function(cls, py_func, py_file):
        if not _in_package(py_file):
            return None
        for other in _locator_classes():
            if other is not cls:
                inner = other.from_function(py_func, py_file)
                if inner is not None:
                    return cls(inner)
        return None


def _locator_classes() -> list:
    """Numba's list of cache locators, tried in order (``CacheImpl`` in numba ≥ 0.66)."""
    impl = getattr(caching, "CacheImpl", None) or caching._CacheImpl
    return impl._locator_classes


class _UniqueIds:
    """Numba's uid counter, started at a random 63-bit value above every uid already drawn."""

    def __init__(self, previous):
        self._ids = itertools.count(next(previous) + secrets.randbits(63))

    def __iter__(self):
        return self

    def __next__(self) -> int:
        return next(self._ids)


def install() -> None:
    """Make this process's compiled symbols unique and the package's cache keys whole.
    Idempotent; must run before the package compiles anything (``kernels.jit`` runs it).

    A user who lists numba's locators in ``NUMBA_CACHE_LOCATOR_CLASSES`` lists
    ``lie_factors.kernels.cache.PackageLocator`` first among them to keep the
    whole-package keys."""
    if not isinstance(FunctionIdentity._unique_ids, _UniqueIds):
        FunctionIdentity._unique_ids = _UniqueIds(FunctionIdentity._unique_ids)
    classes = _locator_classes()
    if PackageLocator not in classes:
        classes.insert(0, PackageLocator)
