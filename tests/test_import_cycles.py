"""No import circles among the modules of gflow_core, stages, pipeline and gflow.

A module imports another when one of its ``import`` / ``from ... import`` statements names it
(``from pkg import name`` names ``pkg.name`` when that is a module, else ``pkg``; relative
imports are resolved). Importing ``a.b.c`` also runs ``a/__init__`` and ``a/b/__init__``, but
that is not counted as an import of those packages (else every package that imports its own
submodules would be a circle).

Two graphs are checked:

* **module level**: the imports that run when the module is imported (the module body, with
  the bodies of its ``if`` / ``try`` / ``with`` / ``class`` statements; not under
  ``if TYPE_CHECKING:``). A circle here makes the import order matter and can fail at import time.
* **with function-level imports**: imports inside a function body too. Python tolerates a
  circle through a deferred import, but it is still two modules that need each other, so it is
  refused as well; the error says which edges are deferred (``(in a function)``).
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
TOPS = ("gflow_core", "gflow_msgs", "stages", "pipeline", "gflow")


def _modules() -> dict[str, Path]:
    mods = {}
    for top in TOPS:
        for path in (ROOT / top).rglob("*.py"):
            parts = path.relative_to(ROOT).with_suffix("").parts
            mods[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return mods


def _imports(tree: ast.Module, module: str, is_package: bool) -> list[tuple[int, str, bool]]:
    """(line, dotted name, inside a function) of every import of a module's source."""
    out: list[tuple[int, str, bool]] = []

    def names(node: ast.Import | ast.ImportFrom) -> list[str]:
        if isinstance(node, ast.Import):
            return [a.name for a in node.names]
        base = node.module or ""
        if node.level:
            pkg = module.split(".") if is_package else module.split(".")[:-1]
            pkg = pkg[:len(pkg) - (node.level - 1)]
            base = ".".join(pkg + ([node.module] if node.module else []))
        return [f"{base}.{a.name}" for a in node.names] + [base]

    def visit(body: list[ast.stmt], deferred: bool) -> None:
        for node in body:
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                out.extend((node.lineno, n, deferred) for n in names(node))
                continue
            if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
                visit(node.orelse, deferred)  # the TYPE_CHECKING branch never runs
                continue
            inner = deferred or isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef))
            for child in ast.iter_child_nodes(node):
                if isinstance(child, ast.stmt):
                    visit([child], inner)
                elif isinstance(child, ast.excepthandler):
                    visit(child.body, inner)

    visit(tree.body, False)
    return out


def import_graph(deferred: bool) -> dict[str, dict[str, tuple[int, bool]]]:
    """{module: {imported module: (line, inside a function)}} over the project's modules; with
    ``deferred`` False only the module-level imports."""
    mods = _modules()
    graph: dict[str, dict[str, tuple[int, bool]]] = {}
    for mod, path in mods.items():
        edges: dict[str, tuple[int, bool]] = {}
        for line, name, in_function in _imports(ast.parse(path.read_text(), str(path)), mod,
                                                path.name == "__init__.py"):
            if in_function and not deferred:
                continue
            if name not in mods:  # `from pkg import name` where name is no module: the edge is `pkg`
                continue
            if name != mod and (name not in edges or edges[name][1] and not in_function):
                edges[name] = (line, in_function)
        graph[mod] = edges
    return graph


def circles(graph: dict[str, dict[str, tuple[int, bool]]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    found: list[list[str]] = []

    def connect(v: str) -> None:  # recursion depth is the longest import chain: a few dozen
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                connect(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                found.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            connect(v)
    return found


def _describe(graph: dict[str, dict[str, tuple[int, bool]]], comp: list[str]) -> str:
    lines = [f"import circle among {', '.join(comp)}:"]
    for a in comp:
        for b, (line, in_function) in sorted(graph[a].items()):
            if b in comp:
                lines.append(f"  {a}:{line} imports {b}" + (" (in a function)" if in_function else ""))
    return "\n".join(lines)


def test_no_module_level_import_circles():
    graph = import_graph(deferred=False)
    assert len(graph) > 100 and any(graph.values())
    found = circles(graph)
    assert not found, "\n".join(_describe(graph, c) for c in found)


def test_no_import_circles_through_function_level_imports():
    graph = import_graph(deferred=True)
    found = circles(graph)
    assert not found, "\n".join(_describe(graph, c) for c in found)


def test_the_check_finds_a_circle():
    """The checker itself: a circle through a function-level import is found, and only in the
    graph that counts those imports."""
    graph = {"a": {"b": (1, False)}, "b": {"c": (3, False)}, "c": {"a": (7, True)}, "d": {"a": (2, False)}}
    assert circles(graph) == [["a", "b", "c"]]
    assert circles({m: {n: e for n, e in es.items() if not e[1]} for m, es in graph.items()}) == []
    tree = ast.parse("import os\nfrom . import sib\nif TYPE_CHECKING:\n    import x.y\n"
                     "def f():\n    from ..up import z\n")
    got = _imports(tree, "pkg.sub.mod", False)
    assert (2, "pkg.sub.sib", False) in got and (6, "pkg.up.z", True) in got
    assert not any(n.startswith("x") for _, n, _ in got)
