"""What ``gflow`` imports before it can say ``--help`` or a mistake in the command: not OpenCV, zenoh, mcap, the
stages, the graph loader or the recording and run machinery (each ``gflow`` start paid ~0.3-0.5 s of CPU for them,
and the test suite starts hundreds). A module that imports one of them at its top, on the way to parsing the
options or to the first check, fails here, naming the command and the modules; ``bench/bench_command_startup.py`` measures the
time."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent

#: what no --help and no mistake found while parsing (or by a command's first check) should import
HEAVY = ("cv2", "zenoh", "mcap", "stages", "msgspec", "pipeline.runtime.graph", "pipeline.runtime.transport",
         "pipeline.recording.live_record", "pipeline.recording.edgeless", "pipeline.app.track_run",
         "pipeline.app.graph_run", "pipeline.io.frame_readers")

#: runs ``main(argv)`` as the ``gflow`` command would (its exit status), then lists the modules of ``names`` loaded
PROBE = """
import contextlib, io, json, sys
from pipeline.cli.main import main
argv, names = json.loads(sys.argv[1]), json.loads(sys.argv[2])
err = io.StringIO()
try:
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        rc = main(argv)
except SystemExit as e:
    rc = e.code
loaded = sorted(n for n in names if n in sys.modules or any(m.startswith(n + ".") for m in sys.modules))
print(json.dumps({"rc": rc, "loaded": loaded, "err": err.getvalue()}))
"""


def loaded_by(argv: list[str], names: tuple[str, ...], cwd: Path) -> dict:
    """``gflow ARGV`` run in a new interpreter: its exit status, which of ``names`` it imported, its stderr."""
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    r = subprocess.run([sys.executable, "-c", PROBE, json.dumps(argv), json.dumps(names)], cwd=cwd, env=env,
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout.strip().splitlines()[-1])


@pytest.mark.parametrize("argv,rc,words", [
    (["track", "--help"], 0, ""),
    (["eval", "--help"], 0, ""),
    (["info", "--help"], 0, ""),
    (["run", "--help"], 0, ""),  # its description lists the built-in graphs (without reading them)
    (["demo", "--help"], 0, ""),
    (["track", "--init", "1,2,3,4"], 2, "the following arguments are required: --out"),
    (["track", "frames", "--init", "1,2,3", "--out", "b.csv"], 2, "expected 4 numbers X,Y,W,H"),
    (["track", "frames", "--init", "1,2,3,4", "--out", "b.csv", "--fpss", "5"], 2, "did you mean --fps?"),
    (["track", "/nonexistent", "--init", "1,2,3,4", "--out", "b.csv", "--inline"], 2, "source not found"),
    (["eval", "--gt", "x.csv", "--pred", "y.csv"], 2, "box file not found: x.csv"),
    (["demo", "--frames", "0"], 2, "--frames: must be >= 1"),
    (["rerun", "none.mcap"], 2, "recording not found: none.mcap"),
])
def test_help_and_mistakes_import_nothing_heavy(tmp_path: Path, argv: list[str], rc: int, words: str) -> None:
    names = HEAVY if argv[0] != "run" else tuple(n for n in HEAVY if n not in (  # run --help names the graphs
        "zenoh", "stages", "msgspec", "pipeline.runtime.graph", "pipeline.runtime.transport"))
    out = loaded_by(argv, names, tmp_path)
    assert out["rc"] == rc and words in out["err"], out
    assert out["loaded"] == [], f"gflow {' '.join(argv)} imported {out['loaded']}"


def test_a_run_s_missing_source_is_said_before_the_stages_and_opencv(tmp_path: Path) -> None:
    """As processes, gflow track makes its network settings (and refuses a bad security option) before it looks at
    the source: that takes the transport's settings (zenoh's module, a few ms), not the graph, the stages or OpenCV."""
    out = loaded_by(["track", "/nonexistent", "--init", "1,2,3,4", "--out", "b.csv"], HEAVY, tmp_path)
    assert out["rc"] == 2 and "source not found: /nonexistent" in out["err"], out
    assert set(out["loaded"]) <= {"zenoh", "pipeline.runtime.transport"}, out["loaded"]


def test_an_error_of_eval_needs_no_numpy(tmp_path: Path) -> None:
    (tmp_path / "gt.csv").write_text("0,1,2,3,4\n")
    out = loaded_by(["eval", "--gt", "gt.csv", "--pred", "nosuch.csv"], ("numpy", *HEAVY), tmp_path)
    assert out["rc"] == 2 and "box file not found: nosuch.csv" in out["err"], out
    assert out["loaded"] == [], out["loaded"]


def test_the_probe_sees_what_a_command_imports(tmp_path: Path) -> None:
    """The check above can fail: a command that reads a recording imports mcap (here, before it finds none)."""
    out = loaded_by(["verify", "none.mcap"], HEAVY, tmp_path)
    assert out["rc"] == 1 and "none.mcap" in out["err"], out
    assert "mcap" in out["loaded"], out


def test_the_default_tracker_imports_no_scipy() -> None:
    """scipy costs a process about 0.4 s of CPU at import (its array-API layer), and the default tracker's stage,
    inline run or benchmark needs none of it: its transforms are numpy's (gflow_core/dcf/filter.py)."""
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    code = ("import sys, stages.box_tracker, gflow_core.dcf.tracker, gflow_core.builtin_trackers\n"
            "print(sorted(m for m in sys.modules if m == 'scipy' or m.startswith('scipy.'))[:3])")
    r = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "[]", f"the default tracker imported scipy: {r.stdout.strip()}"
