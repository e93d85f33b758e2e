"""The type checker passes over the core, the stages, the Python API and the pipeline (``[tool.mypy]`` in
pyproject.toml), with no ``# type: ignore``: a third-party package that ships no types is named in
the configuration instead."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
CHECKED = ("gflow_core", "gflow_msgs", "stages", "gflow", "pipeline")


def test_mypy_passes() -> None:
    # mypy's own incremental cache, kept between runs in the checkout (.mypy_cache, ignored by git, where a plain
    # `mypy` run keeps it too): a module whose text, or whose dependencies' interfaces, changed is checked again, so
    # the verdict is a fresh run's; what never changes (numpy's, matplotlib's, OpenCV's and the standard library's
    # stubs: over half of the ~800 modules a fresh run reads) is not analysed again at every run (~20 s of CPU)
    api = pytest.importorskip("mypy.api", reason="mypy is in the test extras: pip install -e '.[test]'")
    out, err, status = api.run(["--config-file", str(ROOT / "pyproject.toml"), "--cache-dir", str(ROOT / ".mypy_cache"),
                                *(str(ROOT / p) for p in CHECKED)])
    assert status == 0, f"mypy found errors:\n{out}{err}"


def test_no_type_ignore_in_the_checked_packages() -> None:
    found = [f"{p.relative_to(ROOT)}:{n}" for top in CHECKED for p in sorted((ROOT / top).rglob("*.py"))
             for n, line in enumerate(p.read_text().splitlines(), 1) if re.search(r"#\s*type:\s*ignore", line)]
    assert not found, "type: ignore (give the type, or name a package without types in [tool.mypy]): " + \
        ", ".join(found)
