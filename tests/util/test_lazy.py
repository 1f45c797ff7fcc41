"""lie_factors.util.lazy: a package's names imported on first use, in a fresh interpreter."""

from __future__ import annotations

import subprocess
import sys

import pytest


@pytest.mark.parametrize("package, name, submodule", [
    ("lie_factors.batch", "optimize", "optimizer"),
    ("lie_factors.incremental", "Smoother", "smoother"),
])
def test_a_package_loads_a_submodule_only_when_its_name_is_asked_for(package, name, submodule):
    code = (
        "import sys, importlib\n"
        f"p = importlib.import_module({package!r})\n"
        f"print({package + '.' + submodule!r} in sys.modules, 'numba' in sys.modules, 'gtsam' in sys.modules)\n"
        f"print({name!r} in dir(p), {name!r} in vars(p))\n"
        f"v = getattr(p, {name!r})\n"
        f"print(v.__module__, {name!r} in vars(p), {package + '.' + submodule!r} in sys.modules)\n"
        "try:\n"
        "    p.no_such_name\n"
        "except AttributeError as e:\n"
        "    print(e)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.splitlines()
    assert out[0] == "False False False"
    assert out[1] == "True False"
    assert out[2] == f"{package}.{submodule} True True"
    assert out[3] == f"module {package!r} has no attribute 'no_such_name'"
