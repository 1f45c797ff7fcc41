"""numba's check for BLAS, without importing ``scipy.linalg`` for it.

The first function a process compiles or loads from numba's cache imports ``numba.np.arraymath``,
which decides whether BLAS is available by importing ``scipy.linalg.cython_blas``
(``numba.np.linalg.ensure_blas``).  Python imports a submodule's package first, and the
``scipy.linalg`` package imports SciPy's array-API layer, which touches every attribute of numpy
and so imports ``numpy.f2py``: that import is most of numba's fixed cost in a process, paid whether
a kernel calls BLAS or not.

:func:`check_blas` runs numba's check with the extension module ``cython_blas`` loaded on its own
(it needs nothing of its package) and held in ``sys.modules`` only while the check runs.  The
process's modules are then what they were, so the first kernel that does call BLAS or LAPACK
imports ``scipy.linalg`` as numba's helper library always does, at that call.  Where any step
does not go as described (another numba, SciPy without that file), numba is left to check as it
does by itself.
"""

from __future__ import annotations

import importlib.machinery
import importlib.util
import sys

__all__ = ["check_blas"]

_BLAS = "scipy.linalg.cython_blas"


def check_blas() -> None:
    """Import ``numba.np.arraymath`` (numba's BLAS check) with ``scipy.linalg.cython_blas``
    loaded alone, unless ``scipy.linalg`` or numba's check is already imported."""
    if "numba.np.arraymath" in sys.modules or "scipy.linalg" in sys.modules or _BLAS in sys.modules:
        return
    module = _load_alone(_BLAS)
    if module is None:
        return
    sys.modules[_BLAS] = module
    try:
        import numba.np.arraymath  # noqa: F401  (its import runs the check)
    finally:
        if sys.modules.get(_BLAS) is module:
            del sys.modules[_BLAS]


def _load_alone(name: str):
    """The extension module ``name`` (package.sub.module) loaded from its file without importing
    its package, or None."""
    try:
        scipy = importlib.util.find_spec("scipy")
        if scipy is None or not scipy.submodule_search_locations:
            return None
        package, _, leaf = name.rpartition(".")
        where = [loc + "/" + package.split(".", 1)[1].replace(".", "/") for loc in scipy.submodule_search_locations]
        for path in where:
            finder = importlib.machinery.FileFinder(path, (importlib.machinery.ExtensionFileLoader,
                                                           importlib.machinery.EXTENSION_SUFFIXES))
            spec = finder.find_spec(name)
            if spec is not None and spec.loader is not None:
                module = importlib.util.module_from_spec(spec)
                spec.loader.exec_module(module)
                return module
    except Exception:  # anything unexpected: numba's own check imports as it always does
        return None
    return None
