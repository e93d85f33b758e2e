"""Recordings that end early or come in segments: `rerun --check` compares only what the
recording has and says where it ends; `gflow boxes` rebuilds the CSV from any of them."""

from __future__ import annotations

import signal
import subprocess
import sys
import time

import pytest

import cli_fork
from pipeline.runtime.build import apply_defaults
from pipeline.runtime.graph import load_graph
from pipeline.runtime.inline import run_inline
from pipeline.io.mcap_io import iter_records, read_metadata, segment_path, segments
from pipeline.io.recorder import McapRecorder
from pipeline.recording.results import estimates, read_boxes

GFLOW = [sys.executable, "-m", "pipeline.cli.main"]


@pytest.fixture(scope="module")
def demo_recording(tmp_path_factory):
    path = tmp_path_factory.mktemp("rec") / "demo.mcap"
    plan = apply_defaults(load_graph("demo", overrides={"source": {"frames": 40}, "filter": {"particles": 100}}))
    md = {"gflow.graph": {"name": plan.name, "stream": plan.stream, "yaml": plan.source_text},
          "gflow.config": plan.config_metadata()}
    run_inline(plan, recording=str(path), metadata=md)
    return path


def test_rerun_check_on_a_torn_recording_compares_what_it_has(demo_recording, tmp_path):
    torn = tmp_path / "torn.mcap"
    data = demo_recording.read_bytes()
    torn.write_bytes(data[: int(len(data) * 0.6)])
    n = len(estimates(torn))
    assert 5 < n < 40
    out = cli_fork.run_command([*GFLOW, "rerun", str(torn), "--stage", "filter", "--check"], capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0, out.stdout + out.stderr
    assert "ends early" in out.stdout and f"{n - 1} on estimate" in out.stdout, out.stdout
    # and a real difference is still found in what the recording has
    out = cli_fork.run_command([*GFLOW, "rerun", str(torn), "--stage", "filter", "--set", "seed=7", "--check"],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 1 and "differ" in out.stdout


def test_rerun_check_on_an_interrupted_run(tmp_path):
    rec = tmp_path / "run.mcap"
    p = subprocess.Popen([*GFLOW, "run", "demo", "--set", "source.realtime=true", "--set", "source.frames=600",
                          "--set", "filter.particles=100", "--record", str(rec), "--listen", "tcp/127.0.0.1:0"],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 90
    while not (rec.exists() and rec.stat().st_size > 64 and len(estimates(rec)) >= 15):
        assert time.monotonic() < deadline and p.poll() is None, "the pipeline did not get going"
        time.sleep(0.1)
    p.send_signal(signal.SIGINT)
    p.communicate(timeout=60)
    for args in (["--stage", "filter"], ["--stage", "preprocess"], ["--graph", "--out", str(tmp_path / "g.mcap")]):
        out = cli_fork.run_command([*GFLOW, "rerun", str(rec), *args, "--check"], capture_output=True, text=True,
                             timeout=180)
        assert out.returncode == 0, (args, out.stdout + out.stderr)
        assert "all identical" in out.stdout


def _split(src, dest, at: float) -> int:
    """Write ``src`` as a recording in two segments (as a restarted recorder does); return the split."""
    recs = list(iter_records(src))
    cut = int(len(recs) * at)
    meta = read_metadata(src)
    for i, part in enumerate((recs[:cut], recs[cut:])):
        with McapRecorder(segment_path(dest, i), metadata=meta if i == 0 else {}) as w:
            for r in part:
                w.write(r.topic, r.data, r.seq, publish_ns=r.publish_ns, log_ns=r.log_ns, type_name=r.type)
    return cut


def test_segments_read_as_one_recording(demo_recording, tmp_path):
    dest = tmp_path / "seg.mcap"
    _split(demo_recording, dest, 0.5)
    assert segments(dest) == [dest, tmp_path / "seg.part1.mcap"]
    assert sorted(estimates(dest)) == sorted(estimates(demo_recording)) == list(range(40))
    out = cli_fork.run_command([*GFLOW, "boxes", str(dest), "--out", str(tmp_path / "b.csv")], capture_output=True,
                         text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert "from 2 segments" in out.stdout
    boxes = read_boxes(tmp_path / "b.csv")
    assert boxes == {k: tuple(round(v, 2) for v in e.box) for k, e in estimates(demo_recording).items()}
    info = cli_fork.run_command([*GFLOW, "info", str(dest)], capture_output=True, text=True, timeout=60)
    assert info.returncode == 0 and "seg.part1.mcap" in info.stdout
    out = cli_fork.run_command([*GFLOW, "rerun", str(dest), "--stage", "filter", "--check"], capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0 and "all identical" in out.stdout, out.stdout + out.stderr


def test_boxes_from_a_torn_recording_names_what_is_missing(demo_recording, tmp_path):
    torn = tmp_path / "torn.mcap"
    data = demo_recording.read_bytes()
    torn.write_bytes(data[: int(len(data) * 0.5)])
    out = cli_fork.run_command([*GFLOW, "boxes", str(torn), "--out", str(tmp_path / "b.csv")], capture_output=True,
                         text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert "ends early" in out.stdout
    assert sorted(read_boxes(tmp_path / "b.csv")) == sorted(estimates(torn))
    bad = cli_fork.run_command([*GFLOW, "boxes", str(tmp_path / "nothing.mcap"), "--out", str(tmp_path / "c.csv")],
                         capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "not found" in bad.stderr and "Traceback" not in bad.stderr


def test_a_recording_cut_anywhere_reads_to_its_cut_and_info_says_so(demo_recording, tmp_path):
    """Cut inside the header, inside a record's opcode and length, inside a chunk, or before the
    footer: the messages before the cut are read, the cut is reported, and never an internal error."""
    data = demo_recording.read_bytes()
    whole = sum(1 for _ in iter_records(demo_recording))
    cuts = sorted({9, 10, 12, 16, 17, 30, len(data) // 3, len(data) // 2, len(data) - 40, len(data) - 1})
    seen = []
    for cut in cuts:
        torn = tmp_path / f"cut{cut}.mcap"
        torn.write_bytes(data[:cut])
        notes: list[str] = []
        n = sum(1 for _ in iter_records(torn, on_truncated=notes.append))
        assert n <= whole and notes and "not closed properly" in notes[0], (cut, notes)
        r = cli_fork.run_command([*GFLOW, "info", str(torn)], capture_output=True, text=True, timeout=60)
        # a cut before the first message leaves nothing readable: exit 1; after it, a warning
        assert r.returncode == (1 if n == 0 else 0), (cut, n, r.returncode, r.stderr)
        assert "internal error" not in r.stderr and "Traceback" not in r.stderr, (cut, r.stderr)
        assert "recording ends early" in r.stdout, (cut, r.stdout)
        seen.append(n)
    assert seen == sorted(seen) and seen[0] == 0 and seen[-1] > 0  # the later the cut, the more is read
