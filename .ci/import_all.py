"""Import every module of the package: each must import with the declared dependencies alone."""

import importlib
import pkgutil

import lie_factors

names = [m.name for m in pkgutil.walk_packages(lie_factors.__path__, "lie_factors.")]
for name in names:
    importlib.import_module(name)
print(f"imported {len(names)} modules")
