"""No function in the code is over MAX_LINES lines: a longer one is split into steps a reader can name.

A function's length is what :mod:`ast` says it spans, ``end_lineno - lineno + 1``: from its ``def``
line (decorators not counted) to its last line, docstring and comments included. A failure names
every function over the limit as ``file:line name length``, with ``name`` the qualified name
(``Class.method``, ``outer.inner``).
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("gflow_core", "stages", "pipeline", "gflow")
MAX_LINES = 100


def function_lengths(path: Path) -> list[tuple[int, str, int]]:
    """(line, qualified name, length in lines) of every function and method in the file at ``path``."""
    out: list[tuple[int, str, int]] = []

    def visit(node: ast.AST, prefix: str) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                name = prefix + child.name
                if not isinstance(child, ast.ClassDef):
                    assert child.end_lineno is not None
                    out.append((child.lineno, name, child.end_lineno - child.lineno + 1))
                visit(child, name + ".")
            else:
                visit(child, prefix)

    visit(ast.parse(path.read_text(), str(path)), "")
    return out


def long_functions() -> dict[tuple[str, str], str]:
    """Every function over MAX_LINES in PACKAGES: (file, qualified name) -> ``file:line name length``."""
    found = {}
    files = sorted(p for top in PACKAGES for p in (ROOT / top).rglob("*.py"))
    assert len(files) > 50, f"found only {len(files)} Python files under {', '.join(PACKAGES)}"
    for path in files:
        rel = path.relative_to(ROOT).as_posix()
        for line, name, length in function_lengths(path):
            if length > MAX_LINES:
                found[(rel, name)] = f"{rel}:{line} {name} {length}"
    return found


def test_no_function_over_the_limit() -> None:
    bad = [text for _, text in sorted(long_functions().items())]
    assert not bad, f"functions over {MAX_LINES} lines (split them into named steps):\n" + "\n".join(bad)


def test_lengths_are_measured_as_ast_spans(tmp_path: Path) -> None:
    """The measure counts from the def line to the last line, nested functions and methods by qualified name."""
    src = tmp_path / "m.py"
    src.write_text("@dec\ndef f():\n    def g():\n        return 1\n    return g\n\n\nclass C:\n    async def h(self):\n"
                   "        '''doc'''\n        pass\n")
    assert function_lengths(src) == [(2, "f", 4), (3, "f.g", 2), (9, "C.h", 3)]
