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
import cli_fork

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
    # the re-runs side by side too (each reads its own file): the same checks, not one after another
    checks = [subprocess.Popen([*GFLOW, "rerun", str(r), "--stage", "filter", "--check"], cwd=tmp_path, env=env,
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for r in recs]
    for r, chk in zip(recs, checks):
        out, err = chk.communicate(timeout=120)
        assert chk.returncode == 0 and "identical" in out, (r, out, err)
    assert time.time() - t0 < 170


def test_run_without_an_initial_box_is_refused_before_launch(tmp_path: Path, monkeypatch, capsys) -> None:
    monkeypatch.chdir(tmp_path)
    assert main(["run", "chamfer"]) == 2
    err = capsys.readouterr().err
    assert "needs an initial box" in err and "--set filter.init=" in err and len(err.strip().splitlines()) == 1, err
    assert not list(tmp_path.rglob("*.mcap"))


def test_csv_files_end_lines_with_lf(tmp_path: Path) -> None:
    from pipeline.io.landmarks import write_points
    from pipeline.recording.results import write_boxes

    write_boxes(tmp_path / "b.csv", {0: (1.0, 2.0, 3.0, 4.0), 1: (2.0, 3.0, 4.0, 5.0)}, {0: 1.0, 1: 0.5},
                {0: "tracked", 1: "occluded"})
    import numpy as np

    write_points(tmp_path / "p.csv", {0: (np.array([0, 1]), np.array([[1.0, 2.0], [3.0, 4.0]]))})
    for name in ("b.csv", "p.csv"):
        data = (tmp_path / name).read_bytes()
        assert b"\r" not in data and data.count(b"\n") >= 3, (name, data)


def test_no_record_names_no_recording(tmp_path: Path) -> None:
    seq = data_dir("crossing")
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parent.parent))
    r = cli_fork.run_command([*GFLOW, "track", str(seq), "--init", "204,150,17,50", "--out", "b.csv", "--stop", "5",
                              "--no-record"], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert "recording: none (--no-record)" in r.stdout
    assert "recording to" not in r.stderr and "gflow-norecord" not in r.stderr + r.stdout, r.stderr


#: the first bytes of every MCAP file
MAGIC = b"\x89MCAP0\r\n"


def _fake_recordings(folder: Path, n: int) -> list[Path]:
    folder.mkdir(parents=True, exist_ok=True)
    out = []
    for i in range(n):
        p = folder / f"run-{i}.mcap"
        p.write_bytes(MAGIC + b"x" * 992)  # an MCAP file's beginning: clean removes only those
        os.utime(p, (1_000_000 + i * 10, 1_000_000 + i * 10))
        out.append(p)
    seg = folder / "run-0.part1.mcap"  # the oldest one has a segment of a restarted recorder
    seg.write_bytes(MAGIC + b"y" * 492)
    os.utime(seg, (1_000_000, 1_000_000))
    return out


def test_clean_keeps_the_newest_and_says_what_it_removed(tmp_path: Path, capsys) -> None:
    recs = _fake_recordings(tmp_path / "recordings", 4)
    assert main(["clean", str(tmp_path / "recordings"), "--keep", "2", "--dry-run"]) == 0
    out = capsys.readouterr().out.strip()
    assert out.startswith("would remove 2 recording(s) (0.0 MB)") and "kept the newest 2" in out, out
    assert all(p.exists() for p in recs)
    assert main(["clean", str(tmp_path / "recordings"), "--keep", "2"]) == 0
    out = capsys.readouterr().out.strip()
    assert out.startswith("removed 2 recording(s)") and len(out.splitlines()) == 1, out
    assert [p.exists() for p in recs] == [False, False, True, True]
    assert not (tmp_path / "recordings" / "run-0.part1.mcap").exists()
    with pytest.raises(SystemExit):
        main(["clean", "--help"])
    assert "--keep" in capsys.readouterr().out


def test_clean_of_a_folder_with_no_recordings_says_so_and_where_they_are(tmp_path: Path, capsys) -> None:
    """A folder of no recordings was 'removed 0 recording(s) ...; kept the newest 0', the same answer as a folder
    whose recordings are all kept: it now says the folder holds none, and how many its subfolders hold (the
    folder of `gflow benchmark --out-dir` keeps one per sequence)."""
    (tmp_path / "empty").mkdir()
    assert main(["clean", str(tmp_path / "empty"), "--keep", "1"]) == 0
    assert capsys.readouterr().out.strip() == f"{tmp_path / 'empty'} holds no recordings (.mcap files); nothing removed"
    _fake_recordings(tmp_path / "bench" / "caviar1", 2)
    assert main(["clean", str(tmp_path / "bench"), "--keep", "0"]) == 0
    out = capsys.readouterr().out.strip()
    assert out.endswith("nothing removed (its subfolders hold 3: clean one of them)"), out
    assert len(list((tmp_path / "bench").rglob("*.mcap"))) == 3


def test_a_run_warns_when_its_recordings_folder_grows(tmp_path: Path, monkeypatch, capsys) -> None:
    monkeypatch.chdir(tmp_path)
    _fake_recordings(tmp_path / "recordings", 3)
    monkeypatch.setenv("GFLOW_RECORDINGS_WARN_MB", "0.001")
    assert main(["demo", "--frames", "3", "--particles", "50", "--inline"]) == 0
    err = capsys.readouterr().err
    assert "recordings holds" in err and "GFLOW_RECORDINGS_WARN_MB" in err and "gflow clean" in err, err
    monkeypatch.setenv("GFLOW_RECORDINGS_WARN_MB", "0")
    assert main(["demo", "--frames", "3", "--particles", "50", "--inline"]) == 0
    assert "GFLOW_RECORDINGS_WARN_MB" not in capsys.readouterr().err


@pytest.mark.skipif(not hasattr(os, "geteuid") or os.geteuid() != 0, reason="giving a file to another user needs root")
def test_ps_lists_only_the_users_own_pipelines(tmp_path: Path, monkeypatch, capsys) -> None:
    import json

    monkeypatch.setenv("GFLOW_RUNTIME_DIR", str(tmp_path))
    theirs = tmp_path / "cam9-1.json"
    theirs.write_text(json.dumps({"kind": "pipeline", "name": "theirs", "stream": "cam9", "pid": os.getpid(),
                                  "endpoints": ["tcp/127.0.0.1:9"], "stages": [], "started": time.time()}))
    os.chown(theirs, 4242, 4242)  # another user's pipeline, alive
    assert main(["ps", "--listen-for", "0.1"]) == 1
    err = capsys.readouterr().err
    assert "no running gflow pipeline" in err and "other users" in err
    assert main(["ps", "--all", "--listen-for", "0.1"]) == 0
    assert "stream cam9" in capsys.readouterr().out


def test_a_run_whose_default_port_is_taken_at_the_last_moment_still_runs(tmp_path: Path, monkeypatch, capsys) -> None:
    """Runs started together all find 7447 free; the ones that lose the race for it listen elsewhere."""
    import socket

    from pipeline.cli.commands import common

    held = socket.socket()
    try:
        held.bind(("127.0.0.1", 7447))
        held.listen()
    except OSError:
        pass  # another pipeline holds it: taken all the same
    real = common.launcher_zenoh

    def found_free(args):  # what the check saw a moment before another run took the port
        return common.dataclasses.replace(real(args), listen=(common.DEFAULT_ENDPOINT,))

    monkeypatch.setattr(common, "launcher_zenoh", found_free)
    monkeypatch.chdir(tmp_path)
    try:
        assert main(["demo", "--frames", "3", "--particles", "50"]) == 0
    finally:
        held.close()
    err = capsys.readouterr().err
    assert "listening on tcp/127.0.0.1:7447" in err and "in use" not in err, err
    assert len(list((tmp_path / "recordings").glob("*.mcap"))) == 1


def test_a_file_written_beside_never_takes_a_name_that_is_there(tmp_path: Path) -> None:
    """What ``gflow recover`` writes under a temporary name (``create_beside``) takes FIXED's name only while
    nothing has it (``move_new``): a file that appeared there meanwhile is kept, the new one removed."""
    from pipeline.io.recording_files import RecordingExists, create_beside, move_new

    out, tmp = create_beside(tmp_path / "fixed.mcap")
    with out:
        out.write(b"new")
    assert tmp.parent == tmp_path and tmp.name.startswith(".fixed.mcap.") and tmp.suffix == ".tmp"
    assert oct(tmp.stat().st_mode & 0o777) == oct(0o666 & ~_umask())  # as open(path, "wb") makes it
    (tmp_path / "fixed.mcap").write_bytes(b"there first")
    with pytest.raises(RecordingExists, match="fixed.mcap appeared while it was being written"):
        move_new(tmp, tmp_path / "fixed.mcap")
    assert (tmp_path / "fixed.mcap").read_bytes() == b"there first" and not tmp.exists()
    out, tmp = create_beside(tmp_path / "other.mcap")
    with out:
        out.write(b"new")
    move_new(tmp, tmp_path / "other.mcap")
    assert (tmp_path / "other.mcap").read_bytes() == b"new" and not tmp.exists()


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def test_points_written_new_leave_nothing_on_a_failed_write_and_never_replace_a_file(tmp_path: Path) -> None:
    """``gflow track --points-out`` wrote its CSV directly: a write that failed midway (a full disk) left part of
    it, which a retry then refused as an existing file. Written new, a failure leaves nothing and names the file;
    a file that appeared meanwhile is not replaced."""
    import errno

    import numpy as np

    from pipeline.io.landmarks import read_points, write_points
    from pipeline.io.recording_files import RecordingExists

    class FullDisk(dict):
        def __getitem__(self, frame: int):
            if frame == 2:
                raise OSError(errno.ENOSPC, "No space left on device")
            return super().__getitem__(frame)

    pts = FullDisk({k: (np.arange(3), np.full((3, 2), float(k))) for k in range(4)})
    with pytest.raises(OSError, match="points.csv"):
        write_points(tmp_path / "points.csv", pts, new=True)
    assert not list(tmp_path.iterdir()), "neither the file nor its temporary one may be left"
    write_points(tmp_path / "points.csv", dict(pts), new=True)
    assert sorted(read_points(tmp_path / "points.csv")) == [0, 1, 2, 3]
    with pytest.raises(RecordingExists):
        write_points(tmp_path / "points.csv", dict(pts), new=True)
    assert [p.name for p in tmp_path.iterdir()] == ["points.csv"]
