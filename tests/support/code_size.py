"""Size limits of the package's code, checked by tests/test_layout.py on the directories it names.

A function (or method) has at most :data:`MAX_FUNCTION_LINES` lines, from its ``def`` to its
last line, docstring included, and at most :data:`MAX_PARAMETERS` parameters (``self`` and
``cls`` not counted; ``*args`` and ``**kwargs`` count one each).  A module has at most
:data:`MAX_MODULE_LINES` lines, and at most :data:`SOFT_MODULE_LINES` unless it does one job
that does not divide (it is then named, with its reason, in the caller's list).
"""

from __future__ import annotations

import ast
from dataclasses import dataclass
from pathlib import Path

MAX_FUNCTION_LINES = 150
MAX_PARAMETERS = 12
SOFT_MODULE_LINES = 600
MAX_MODULE_LINES = 900


@dataclass(frozen=True)
class Function:
    """One ``def`` of a module: its qualified name, first line, length and parameter count."""

    module: Path
    name: str
    line: int
    lines: int
    parameters: int

    def __str__(self) -> str:
        return f"{self.module.name}:{self.line} {self.name} ({self.lines} lines, {self.parameters} parameters)"


def parameter_count(node: ast.FunctionDef | ast.AsyncFunctionDef) -> int:
    a = node.args
    names = [p.arg for p in a.posonlyargs + a.args + a.kwonlyargs]
    if names and names[0] in ("self", "cls"):
        names = names[1:]
    return len(names) + (a.vararg is not None) + (a.kwarg is not None)


def functions(path: Path) -> list[Function]:
    """Every function and method of the module ``path``, nested ones included."""
    found = []

    def visit(node, prefix):
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                name = f"{prefix}{child.name}"
                found.append(Function(path, name, child.lineno, child.end_lineno - child.lineno + 1,
                                      parameter_count(child)))
                visit(child, f"{name}.")
            elif isinstance(child, ast.ClassDef):
                visit(child, f"{prefix}{child.name}.")
            else:
                visit(child, prefix)

    visit(ast.parse(path.read_text(encoding="utf-8")), "")
    return found


def module_lines(path: Path) -> int:
    return len(path.read_text(encoding="utf-8").splitlines())


def oversized_functions(directory: Path) -> list[Function]:
    """The functions under ``directory`` over :data:`MAX_FUNCTION_LINES` lines or
    :data:`MAX_PARAMETERS` parameters."""
    return [f for path in sorted(directory.rglob("*.py")) for f in functions(path)
            if f.lines > MAX_FUNCTION_LINES or f.parameters > MAX_PARAMETERS]


def oversized_modules(directory: Path, one_job: dict[Path, str] | None = None) -> list[str]:
    """The modules under ``directory`` over :data:`MAX_MODULE_LINES` lines, or over
    :data:`SOFT_MODULE_LINES` and not in ``one_job`` (a module's path → why it does one job
    that does not divide)."""
    allowed = {Path(p).resolve() for p in (one_job or {})}
    out = []
    for path in sorted(directory.rglob("*.py")):
        n = module_lines(path)
        if n > MAX_MODULE_LINES or (n > SOFT_MODULE_LINES and path.resolve() not in allowed):
            out.append(f"{path.relative_to(directory).as_posix()} ({n} lines)")
    return out
