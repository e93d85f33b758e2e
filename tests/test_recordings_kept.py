"""Recordings are never overwritten, never misreported, and do not grow unseen: unique names,
files created exclusively, ``gflow info`` / ``recover`` failing on a file they cannot read,
``gflow clean``, the size warning, ``--no-record`` and CSV line endings."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from pipeline.cli.main import main
from pipeline.io.mcap_io import iter_records
from pipeline.io.recorder import McapRecorder
from pipeline.runtime.build import apply_defaults
from pipeline.runtime.graph import load_graph
from pipeline.runtime.inline import run_inline
from tests.conftest import data_dir

GFLOW = [sys.executable, "-m", "pipeline.cli.main"]


@pytest.fixture(scope="module")
def small_recording(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("rec") / "demo.mcap"
    plan = apply_defaults(load_graph("demo", overrides={"source": {"frames": 12}, "filter": {"particles": 50}}))
    md = {"gflow.graph": {"name": plan.name, "stream": plan.stream, "yaml": plan.source_text},
          "gflow.config": plan.config_metadata()}
    run_inline(plan, recording=str(path), metadata=md)
    return path


def test_default_recording_names_differ_within_one_second(tmp_path: Path) -> None:
    plan = apply_defaults(load_graph("demo", base_dir=str(tmp_path)))
    names = {plan.recording_path() for _ in range(5)}  # the same second, the same plan, no run id yet
    assert len(names) == 5, names
    from pipeline.runtime.runid import choose_stream

    choose_stream(plan, None, placed=False)  # demo-3f9c2a: the file carries the run's id
    run_id = plan.stream.rsplit("-", 1)[1]
    p = Path(str(plan.recording_path()))
    assert p.name.endswith(f"-{run_id}.mcap") and p.name.startswith("demo-"), p
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_bytes(b"x")
    again = Path(str(plan.recording_path()))  # the name is taken: a suffix
    assert again != p and again.name == f"{p.stem}-2.mcap"


def test_the_recorder_never_writes_over_a_file(tmp_path: Path) -> None:
    p = tmp_path / "taken.mcap"
    p.write_bytes(b"precious")
    with pytest.raises(FileExistsError):
        McapRecorder(p).open()
    assert p.read_bytes() == b"precious"
    assert not list(tmp_path.glob(".*.reserve"))


def test_record_to_an_existing_file_is_refused_before_the_run(tmp_path: Path, capsys) -> None:
    p = tmp_path / "run.mcap"
    p.write_bytes(b"precious")
    rc = main(["demo", "--frames", "5", "--inline", "--record", str(p)])
    err = capsys.readouterr().err
    assert rc == 2 and "exists" in err and "never overwrites" in err and len(err.strip().splitlines()) == 1, err
    assert p.read_bytes() == b"precious"


def _damaged_copy(src: Path, dest: Path) -> Path:
    """What two writers on one file leave: the start of one file, then another's bytes."""
    data = bytearray(src.read_bytes())
    mid = len(data) // 3
    data[mid:mid + 4096] = os.urandom(4096)
    dest.write_bytes(bytes(data))
    return dest


def test_info_and_recover_fail_on_a_file_they_cannot_read(small_recording: Path, tmp_path: Path, capsys) -> None:
    assert main(["info", str(small_recording)]) == 0
    capsys.readouterr()
    bad = _damaged_copy(small_recording, tmp_path / "bad.mcap")
    assert main(["info", str(bad)]) == 1
    out = capsys.readouterr()
    assert "damaged" in out.out and "damaged" in out.err
    empty = tmp_path / "cut.mcap"
    empty.write_bytes(small_recording.read_bytes()[:20])  # the header only: nothing to read
    assert main(["info", str(empty)]) == 1
    capsys.readouterr()
    assert main(["recover", str(empty), str(tmp_path / "fixed.mcap")]) == 1
    assert "nothing could be recovered" in capsys.readouterr().err


def test_concurrent_runs_keep_every_recording(tmp_path: Path) -> None:
    """Tracks and demos started in the same second: each keeps a readable recording of its own
    that re-runs bit for bit (the full 8 + 4 runs: docs/debugging.md)."""
    seq = data_dir("crossing")
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parent.parent))
    cmds = [[*GFLOW, "track", str(seq), "--init", "204,150,17,50", "--out", f"t{i}.csv", "--stop", "6", "-q"]
            for i in range(2)]
    cmds += [[*GFLOW, "demo", "--frames", "6", "--particles", "100"] for _ in range(2)]
    t0 = time.time()
    procs = [subprocess.Popen(c, cwd=tmp_path, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for c in cmds]
    outs = [p.communicate(timeout=180) for p in procs]
    assert all(p.returncode == 0 for p in procs), [o[1][-500:] for o in outs]
    recs = sorted((tmp_path / "recordings").glob("*.mcap"))
    assert len(recs) == len(cmds), recs
    for r in recs:
        assert any(x.topic.endswith("/estimate") for x in iter_records(r, strict=True)), r
        chk = subprocess.run([*GFLOW, "rerun", str(r), "--stage", "filter", "--check"], cwd=tmp_path, env=env,
                             capture_output=True, text=True, timeout=120)
        assert chk.returncode == 0 and "identical" in chk.stdout, (r, chk.stdout, chk.stderr)
    assert time.time() - t0 < 170
