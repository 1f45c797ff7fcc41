"""Names of a package imported on first use (PEP 562).

A package lists its public names and the submodule defining each; importing the
package then loads none of them (nor numba, nor GTSAM), and importing one
submodule does not load the others.
"""

from __future__ import annotations

import importlib
from typing import Callable


def exports(package: str, names: dict[str, str]) -> tuple[Callable[[str], object], Callable[[], list[str]]]:
    """The ``__getattr__`` and ``__dir__`` of ``package`` whose public ``names`` map to submodules.

    ``names``: public name → submodule (relative to ``package``).  A name is looked
    up once, then stored in the package's namespace; an unknown name raises
    ``AttributeError`` as a module attribute would.
    """
    module = importlib.import_module(package)

    def __getattr__(name: str):
        sub = names.get(name)
        if sub is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(f"{package}.{sub}"), name)
        setattr(module, name, value)
        return value

    def __dir__() -> list[str]:
        return sorted(set(vars(module)) | set(names))

    return __getattr__, __dir__
