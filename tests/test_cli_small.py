"""Small things a user sees: numbers printed as numbers, the file actually written named, the
progress line never showing a stage ahead of the source, ``gflow frame`` with its grid."""

from __future__ import annotations

import os
import subprocess
import time
from pathlib import Path

import cv2
import numpy as np

import cli_fork
from pipeline.runtime.build import apply_defaults
from pipeline.recording.compare import field_diffs
from pipeline.runtime.graph import load_graph
from pipeline.runtime.launcher import Launcher
from gflow_msgs.messages import Header, NDArray, Particles, Snapshot, StageStatus, encode

ROOT = Path(__file__).resolve().parent.parent


def gflow(cwd: Path, *args: str) -> subprocess.CompletedProcess:
    """``gflow ARGS`` in a process of its own, forked from one that has imported the command line (:mod:`cli_fork`)."""
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    return cli_fork.run(list(args), cwd=cwd, env=env, timeout=120)


def _particles(alpha: np.ndarray) -> bytes:
    n = alpha.shape[0]
    return encode(Particles(header=Header("s", 1, 0), kind="posterior", alpha=NDArray.of(alpha),
                            k=NDArray.of(np.zeros(n, np.int32)), log_w=NDArray.of(np.zeros(n))))


def test_field_differences_print_plain_numbers() -> None:
    a = np.zeros((3, 4))
    b = a.copy()
    b[1, 2] = 0.25
    (d,) = field_diffs(_particles(a), _particles(b))
    assert d.path == "alpha[1, 2]" and "(0.0 vs 0.25)" in d.detail and "np." not in d.detail


def test_long_byte_fields_are_summarised_not_printed() -> None:
    """A stage snapshot's bytes run to megabytes: a difference names the lengths and where they part."""
    a = b"\x00" * 5000 + b"old" + b"\x01" * 5000
    b = b"\x00" * 5000 + b"new" + b"\x01" * 6000
    (d,) = field_diffs(encode(Snapshot(header=Header("s", 1, 0), stage="filter", kind="k", data=a)),
                       encode(Snapshot(header=Header("s", 1, 0), stage="filter", kind="k", data=b)))
    assert d.path == "data" and "10003 vs 11003 bytes, first different at 5000" in d.detail, d.detail
    assert len(d.detail) < 200
    (short,) = field_diffs(encode(Snapshot(header=Header("s", 1, 0), stage="filter", kind="k", data=b"ab")),
                           encode(Snapshot(header=Header("s", 1, 0), stage="filter", kind="k", data=b"ac")))
    assert short.detail == "b'ab' vs b'ac'"


def test_progress_never_shows_a_stage_ahead_of_the_source() -> None:
    plan = apply_defaults(load_graph("demo"))
    la = Launcher(plan, progress=False, total_frames=120)
    for name, steps in (("source", 5), ("preprocess", 9), ("filter", 7)):
        la.status[name] = StageStatus(header=Header("demo", steps, time.time_ns()), stage=name, pid=1,
                                      state="running", steps=steps, fps=1.0)
    line = la.monitor.line()
    assert "source: 9/120" in line and "preprocess: 9 " in line and "filter: 7 " in line, line


def test_frame_writes_a_gridded_picture_and_refuses_a_missing_frame(tmp_path: Path) -> None:
    d = tmp_path / "frames"
    d.mkdir()
    for i in range(3):
        cv2.imwrite(str(d / f"{i:03d}.png"), np.full((60, 80, 3), 40 * i, np.uint8))
    r = gflow(tmp_path, "frame", str(d), "2", "f.png")
    assert r.returncode == 0, r.stderr
    assert "80x60 pixels" in r.stdout and "--start 2" in r.stdout
    pic = cv2.imread(str(tmp_path / "f.png"))
    assert pic.shape[0] > 60 * 3 and pic.shape[1] > 80 * 3  # magnified, with a ruler margin
    r = gflow(tmp_path, "frame", str(d), "7", "g.png")
    assert r.returncode == 2 and "beyond the end" in r.stderr and "Traceback" not in r.stderr
    assert not (tmp_path / "g.png").exists()


def test_plot_names_the_file_it_wrote(tmp_path: Path) -> None:
    r = gflow(tmp_path, "run", "demo", "--inline", "--set", "source.frames=6", "--record", "r.mcap")
    assert r.returncode == 0, r.stderr
    r = gflow(tmp_path, "plot", "r.mcap", "out")
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "wrote out.png" and (tmp_path / "out.png").is_file()


def test_eval_frames_scores_only_the_tracked_frames(tmp_path: Path) -> None:
    rows = "\n".join(f"{i},10,10,20,20" for i in range(10))
    (tmp_path / "gt.csv").write_text(rows + "\n")
    (tmp_path / "p.csv").write_text("\n".join(f"{i},10,10,20,20" for i in range(4, 10)) + "\n")
    every = gflow(tmp_path, "eval", "--gt", "gt.csv", "--pred", "p.csv", "--json")
    tracked = gflow(tmp_path, "eval", "--gt", "gt.csv", "--pred", "p.csv", "--json", "--frames", "4:")
    import json

    assert json.loads(every.stdout)["success_rate_0.5"] == 0.6 and json.loads(tracked.stdout)["success_rate_0.5"] == 1.0
    bad = gflow(tmp_path, "eval", "--gt", "gt.csv", "--pred", "p.csv", "--frames", "x:y")
    assert bad.returncode == 2 and "--frames" in bad.stderr and "Traceback" not in bad.stderr


def test_inline_progress_ends_on_the_final_count(tmp_path: Path) -> None:
    """An --inline run shows no progress line before a second has passed, and a line it shows
    last is the final count (never a count the run went past, like "1/15 frames")."""
    d = tmp_path / "frames"
    d.mkdir()
    rng = np.random.default_rng(0)
    for i in range(15):
        cv2.imwrite(str(d / f"{i:04d}.png"), rng.integers(0, 255, (48, 64, 3), dtype=np.uint8))
    r = gflow(tmp_path, "track", str(d), "--init", "10,10,20,20", "--out", "b.csv", "--inline", "--no-record")
    assert r.returncode == 0, r.stderr
    counts = [ln.split()[0] for ln in r.stderr.splitlines() if ln.strip().endswith(" frames")]
    assert counts in ([], [*counts[:-1], "15/15"]), r.stderr


def test_process_progress_ends_on_the_final_count(tmp_path: Path, caviar1: Path) -> None:
    """A process run that showed a progress line ends on the final counts (every stage at the
    last frame), not on those of the last one-second tick before the stages finished."""
    # at 25 fps, 40 frames take 1.6 s: at least one tick is shown while the run goes on
    r = gflow(tmp_path, "track", str(caviar1), "--init", "129,71,30,79", "--tracker", "chamfer", "--stop", "40",
              "--realtime", "--out", "b.csv", "--no-record", "--listen", "tcp/127.0.0.1:0")
    assert r.returncode == 0, r.stderr
    lines = [ln for ln in r.stderr.splitlines() if ln.startswith("source: ")]
    assert lines, r.stderr
    assert lines[-1].startswith("source: 40/40 ") and "filter: 40 @" in lines[-1], r.stderr
