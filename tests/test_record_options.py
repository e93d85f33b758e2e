"""``--no-record`` and ``--record-topics`` on the real CLI (inline runs: seconds, not minutes)."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import cv2
import numpy as np

import cli_fork
from pipeline.io.mcap_io import summarize

ROOT = Path(__file__).resolve().parent.parent


def gflow(cwd: Path, *args: str) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""),
               TMPDIR=str(cwd / "tmp"))
    (cwd / "tmp").mkdir(exist_ok=True)
    return cli_fork.run(list(args), cwd=cwd, env=env, timeout=120)


def test_record_topics_keeps_only_those_and_the_diagnostics(tmp_path: Path) -> None:
    r = gflow(tmp_path, "run", "demo", "--inline", "--set", "source.frames=12", "--record", "sel.mcap",
              "--record-topics", "estimate,particles")
    assert r.returncode == 0, r.stderr
    topics = set(summarize(tmp_path / "sel.mcap").topics)
    assert {"gflow/demo/estimate", "gflow/demo/particles"} <= topics
    assert "gflow/demo/frames" not in topics and "gflow/demo/features" not in topics
    assert all(t.rsplit("/", 1)[-1] in ("estimate", "particles") or "/_" in t or t.endswith("/errors")
               for t in topics), topics
    full = gflow(tmp_path, "run", "demo", "--inline", "--set", "source.frames=12", "--record", "all.mcap")
    assert full.returncode == 0, full.stderr
    assert "gflow/demo/frames" in summarize(tmp_path / "all.mcap").topics
    assert (tmp_path / "sel.mcap").stat().st_size * 5 < (tmp_path / "all.mcap").stat().st_size


def test_no_record_writes_the_boxes_and_leaves_no_recording(tmp_path: Path) -> None:
    d = tmp_path / "frames"
    d.mkdir()
    rng = np.random.default_rng(1)
    img = rng.integers(0, 60, (96, 128), dtype=np.uint8)
    for i in range(6):
        f = img.copy()
        cv2.rectangle(f, (30 + i, 30), (60 + i, 70), 255, -1)
        cv2.imwrite(str(d / f"{i:03d}.png"), f)
    r = gflow(tmp_path, "track", str(d), "--init", "30,30,31,41", "--out", "b.csv", "--inline", "--no-record", "-q")
    assert r.returncode == 0, r.stderr
    assert "recording: none (--no-record)" in r.stdout
    assert len((tmp_path / "b.csv").read_text().splitlines()) >= 6
    assert not list(tmp_path.rglob("*.mcap")), "no recording may be left, not even a temporary one"
    assert not any((tmp_path / "tmp").iterdir())


def test_no_record_on_run_removes_the_recorder(tmp_path: Path) -> None:
    r = gflow(tmp_path, "run", "demo", "--inline", "--set", "source.frames=5", "--no-record")
    assert r.returncode == 0, r.stderr
    assert "recording: none" in r.stdout
    assert not list(tmp_path.rglob("*.mcap"))


def test_a_zstd_recording_reruns_bit_for_bit(tmp_path: Path) -> None:
    r = gflow(tmp_path, "run", "demo", "--inline", "--set", "source.frames=10", "--set", "recorder.compression=zstd",
              "--record", "z.mcap")
    assert r.returncode == 0, r.stderr
    from mcap.reader import make_reader

    with open(tmp_path / "z.mcap", "rb") as f:
        assert {c.compression for c in make_reader(f).get_summary().chunk_indexes} == {"zstd"}
    for stage in ("preprocess", "filter"):
        r = gflow(tmp_path, "rerun", "z.mcap", "--stage", stage, "--check")
        assert r.returncode == 0 and "all identical bit for bit" in r.stdout, r.stdout + r.stderr


def test_record_topics_that_choose_nothing_or_are_dropped_are_refused(tmp_path: Path) -> None:
    """`--record-topics ''` (an empty shell variable) recorded every topic, and `--no-record --record-topics estimate`
    dropped the patterns without a word; both are refused before the run, naming the option, and nothing is written."""
    for extra in (["--record", "r.mcap", "--record-topics", ""], ["--record", "r.mcap", "--record-topics", ","],
                  ["--no-record", "--record-topics", "estimate"]):
        r = gflow(tmp_path, "run", "demo", "--inline", "--set", "source.frames=3", *extra)
        lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
        assert r.returncode == 2 and len(lines) == 1 and "--record-topics" in lines[0], (extra, r.stderr)
        assert not list(tmp_path.glob("*.mcap")) and not (tmp_path / "recordings").exists(), extra
