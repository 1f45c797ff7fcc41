"""What the package imports at run time is what pyproject.toml declares.

The imports are read from the source (every ``import`` and ``from … import`` of every module,
those inside functions included), so a deferred import of an undeclared package fails here,
not on a user's machine.  Compiled code has one import the source does not show: numba's
BLAS and LAPACK come from scipy, so a kernel that calls NumPy's linear algebra needs scipy
declared.  ``.ci/user-install`` runs every command in an environment made by the main-job
install alone, which checks the same from the other side.
"""

from __future__ import annotations

import ast
import functools
import importlib.metadata
import re
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "lie_factors"
PROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]

#: The decorators that make a function numba-compiled code (lie_factors.kernels.jit's, and numba's own).
JIT_DECORATORS = {"kernel", "dense_kernel", "parallel_kernel", "inline_kernel", "njit", "jit"}


def _name(requirement: str) -> str:
    return re.match(r"[A-Za-z0-9_.\-]+", requirement).group(0).lower().replace("_", "-")


def _declared() -> set[str]:
    return {_name(r) for r in PROJECT["dependencies"]}


def _extras() -> dict[str, str]:
    """Distribution → the optional extra declaring it (the test extra is not the package's)."""
    return {_name(r): extra for extra, reqs in PROJECT["optional-dependencies"].items() if extra != "test"
            for r in reqs}


def _modules():
    for path in sorted(PACKAGE.rglob("*.py")):
        yield path, ast.parse(path.read_text(encoding="utf-8"), str(path))


def _guarded(tree: ast.AST) -> set[int]:
    """Line numbers of the imports inside a ``try`` that catches ImportError."""
    lines = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Try) and any(
                h.type is not None and "ImportError" in ast.unparse(h.type) for h in node.handlers):
            lines |= {n.lineno for b in node.body for n in ast.walk(b) if isinstance(n, (ast.Import, ast.ImportFrom))}
    return lines


def _third_party_imports():
    """(module path, line, top-level name, guarded) of every absolute import outside the standard library."""
    for path, tree in _modules():
        guarded = _guarded(tree)
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module]
            else:
                continue
            for name in names:
                top = name.split(".")[0]
                if top in sys.stdlib_module_names or top in ("lie_factors", "__future__"):
                    continue
                yield path.relative_to(ROOT), node.lineno, top, node.lineno in guarded


@functools.cache
def _providers() -> dict:
    return importlib.metadata.packages_distributions()


def _distribution(module: str) -> str:
    """The distribution providing ``module``; for one not installed here (an optional extra),
    the module's own name."""
    dists = _providers().get(module) or [module]
    return dists[0].lower().replace("_", "-")


def test_every_import_is_a_declared_dependency_or_a_guarded_optional_extra():
    declared, extras = _declared(), _extras()
    undeclared, unguarded = [], []
    for path, line, module, guarded in _third_party_imports():
        dist = _distribution(module)
        if dist in declared:
            continue
        if dist in extras:
            if not guarded:
                unguarded.append(f"{path}:{line} imports {module} (extra {extras[dist]!r}) outside a try/except ImportError")
            continue
        undeclared.append(f"{path}:{line} imports {module} ({dist}), which pyproject.toml does not declare")
    assert not undeclared, "\n".join(undeclared)
    assert not unguarded, "\n".join(unguarded)


def _compiled_linear_algebra() -> list[str]:
    """Kernels whose source calls NumPy's linear algebra (``np.dot``, ``np.linalg.*``, ``@``),
    which numba compiles into BLAS/LAPACK calls found through scipy."""
    found = []
    for path, tree in _modules():
        for fn in ast.walk(tree):
            if not isinstance(fn, ast.FunctionDef):
                continue
            decorators = {ast.unparse(d).split("(")[0].split(".")[-1] for d in fn.decorator_list}
            if not decorators & JIT_DECORATORS:
                continue
            for node in ast.walk(fn):
                text = ast.unparse(node) if isinstance(node, ast.Attribute) else ""
                if (text in ("np.dot", "numpy.dot") or text.startswith(("np.linalg.", "numpy.linalg."))
                        or (isinstance(node, ast.BinOp) and isinstance(node.op, ast.MatMult))):
                    found.append(f"{path.relative_to(ROOT)}:{fn.name}")
                    break
    return found


def test_kernels_with_blas_calls_have_scipy_declared():
    users = _compiled_linear_algebra()
    assert users, "no kernel calls NumPy's linear algebra: then say why scipy is still declared, or drop it"
    assert "scipy" in _declared(), f"these kernels need numba's BLAS, which needs scipy: {users}"


def test_the_reader_of_imports_sees_deferred_and_guarded_imports(tmp_path):
    """The reader itself: an import inside a function is seen, and a guarded one is told apart."""
    tree = ast.parse("def f():\n    import scipy.linalg\n\ntry:\n    import pypardiso\nexcept ImportError:\n    pass\n")
    seen = sorted(n.lineno for n in ast.walk(tree) if isinstance(n, ast.Import))
    assert seen == [2, 5] and _guarded(tree) == {5}
