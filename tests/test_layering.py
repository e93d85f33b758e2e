"""The package layers import downwards only: gflow_core < gflow_msgs (the messages, which import
nothing of gflow) < stages < pipeline.io < pipeline.runtime
< pipeline.recording < pipeline.app (the application layer) < pipeline.evaluation (the benchmarks)
< pipeline.cli < gflow (the Python API, on top of all of them), and a stage imports of a tracker's
package only the modules of its stages' interface. A violation names the file, the line and the
import."""

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


#: what a stage may import of a tracker's package: the modules that are its stages' interface (its
#: protocol object, parameters, observation rules and snapshot state; for G-flow, what running it split
#: across processes needs). Everything else in the package is the tracker's own: a stage that needs
#: more goes through one of these. The correlation-filter and appearance trackers' stages are made
#: from their specs alone (``stages/spec_box.py``).
STAGE_INTERFACE = {
    "gflow_core.gflow": {"", "tracker", "split", "state_fields"},
    "gflow_core.contour": {"", "params", "dynamics", "features_filter", "observation", "state", "tracker"},
    "gflow_core.m2": {"model", "tracking", "lost", "patch_protocol", "patch_tracking"},
    "gflow_core.dcf": set(),
    "gflow_core.appearance": set(),
}


def imported_modules(source: str) -> list[tuple[int, str]]:
    """(line, module) of every absolute import in ``source``: ``from a.b import c`` is the module ``a.b.c``
    when that is a module of the project, else ``a.b``."""
    out = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            for a in node.names:
                sub = ROOT.joinpath(*f"{node.module}.{a.name}".split("."))
                is_module = sub.with_suffix(".py").is_file() or (sub / "__init__.py").is_file()
                out.append((node.lineno, f"{node.module}.{a.name}" if is_module else node.module))
    return out


def internals(source: str, where: str) -> list[str]:
    """The imports in ``source`` (the file ``where``) of a tracker package's modules outside
    :data:`STAGE_INTERFACE`."""
    bad = []
    for line, module in imported_modules(source):
        for package, allowed in STAGE_INTERFACE.items():
            if module == package or module.startswith(package + "."):
                if module[len(package) + 1:].split(".")[0] not in allowed:
                    bad.append(f"{where}:{line} imports {module}")
    return bad


def test_no_stage_imports_a_trackers_internals():
    bad = [b for p in (ROOT / "stages").rglob("*.py") for b in internals(p.read_text(), str(p.relative_to(ROOT)))]
    assert not bad, "\n".join(bad)


def test_the_internals_check_finds_one():
    probe = ("from gflow_core.gflow.filter import concatenate_proposals\nfrom gflow_core.dcf import spec\n"
             "from gflow_core.gflow.split import joined_proposals\nfrom gflow_core.gflow import GFlowParams\n")
    assert internals(probe, "probe.py") == ["probe.py:1 imports gflow_core.gflow.filter",
                                            "probe.py:2 imports gflow_core.dcf.spec"]
