"""The package layers import downwards only: gflow_core < gflow_msgs (the messages, which import
nothing of gflow) < stages < pipeline.io < pipeline.runtime
< pipeline.recording < pipeline.app (the application layer) < pipeline.evaluation (the benchmarks)
< pipeline.cli < gflow (the Python API, on top of all of them). A violation names the file, the
line and the import."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
ORDER = ["gflow_core", "gflow_msgs", "stages", "pipeline.io", "pipeline.runtime", "pipeline.recording", "pipeline.app",
         "pipeline.evaluation", "pipeline.cli", "gflow"]


def layer(module: str) -> int | None:
    """The index in ORDER of the layer a dotted module name belongs to (None: outside the project)."""
    best = None
    for i, name in enumerate(ORDER):
        if module == name or module.startswith(name + "."):
            best = i
    return best


def imports(path: Path) -> list[tuple[int, str]]:
    tree = ast.parse(path.read_text(), str(path))
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            out += [(node.lineno, f"{node.module}.{a.name}") for a in node.names]
    return out


def test_imports_point_down():
    bad = []
    files = [p for top in ("gflow_core", "gflow_msgs", "stages", "pipeline", "gflow") for p in (ROOT / top).rglob("*.py")]
    assert len(files) > 50
    for path in files:
        own = layer(".".join(path.relative_to(ROOT).with_suffix("").parts))
        if own is None:  # pipeline/__init__.py itself
            continue
        for line, name in imports(path):
            target = layer(name)
            if target is not None and target > own:
                bad.append(f"{path.relative_to(ROOT)}:{line} imports {name} ({ORDER[own]} may not import {ORDER[target]})")
    assert not bad, "\n".join(bad)


def test_messages_import_nothing_of_gflow():
    """The messages are the contract between stages, recordings and other programs: msgspec, numpy and
    the standard library only, so a reader of a recording needs none of gflow's mathematics."""
    bad = [f"{p.relative_to(ROOT)}:{line} imports {name}" for p in (ROOT / "gflow_msgs").rglob("*.py")
           for line, name in imports(p) if layer(name) is not None and not name.startswith("gflow_msgs")]
    assert not bad, "\n".join(bad)


def test_no_relative_imports_cross_packages():
    """Relative imports hide which layer a name comes from; only absolute imports are used."""
    bad = []
    for top in ("pipeline",):
        for path in (ROOT / top).rglob("*.py"):
            for node in ast.walk(ast.parse(path.read_text())):
                if isinstance(node, ast.ImportFrom) and node.level > 1:
                    bad.append(f"{path.relative_to(ROOT)}:{node.lineno}")
    assert not bad, "relative imports reaching a parent package: " + ", ".join(bad)
