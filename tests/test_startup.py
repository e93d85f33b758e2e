"""What a stage process pays for at start-up: only its own stage's imports (issue 11)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


def _fresh(code: str) -> str:
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120, cwd=ROOT)
    assert r.returncode == 0, r.stderr
    return r.stdout.strip()


def test_a_source_or_recorder_process_does_not_import_scipy():
    out = _fresh("import sys, pipeline.runtime.node\n"
                 "from stages.registry import get_stage_class\n"
                 "get_stage_class('source'); get_stage_class('particle.proposal')\n"
                 "print(sorted(m for m in sys.modules if m == 'scipy' or m.startswith('scipy.')))")
    assert out == "[]", f"scipy imported at start-up: {out[:300]}"


def test_every_kind_resolves_lazily_to_its_stage_class():
    from stages.base import Stage
    from stages.registry import STAGES, get_stage_class

    kinds = list(STAGES)
    assert {"source", "preprocess", "particle.filter", "particle.proposal", "appearance.filter",
            "gflow.filter", "gflow.proposal"} <= set(kinds)
    for kind in kinds:
        cls = get_stage_class(kind)
        assert issubclass(cls, Stage) and cls.kind == kind
    with pytest.raises(KeyError, match="known kinds: .*particle.filter"):
        get_stage_class("no.such.kind")


def test_malloc_is_tuned_for_frame_sized_buffers():
    from pipeline.runtime.memory import keep_freed_memory

    if not sys.platform.startswith("linux"):
        pytest.skip("glibc malloc tuning is Linux-only")
    assert keep_freed_memory() is True
    assert keep_freed_memory() is True  # idempotent
