"""A full disk: the recorder closes its file at the last complete chunk (a valid MCAP file,
readable to there), says so in one line, and the pipeline stops cleanly, keeping the CSV."""

from __future__ import annotations

import shutil
import subprocess
import sys
import uuid

import pytest
from mcap.reader import make_reader

from pipeline.recording.results import estimates, read_boxes
import cli_fork

_CHILD = r"""
import resource, signal, sys
import numpy as np
from pipeline.io.recorder import DiskFull, McapRecorder
from gflow_msgs.messages import Frame, Header, NDArray, encode
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # writes past the limit fail with EFBIG instead
resource.setrlimit(resource.RLIMIT_FSIZE, (600_000, 600_000))
rng = np.random.default_rng(0)
rec = McapRecorder(sys.argv[1], flush_interval=0.0, compression="none", chunk_size=50_000).open()
try:
    for i in range(1000):
        img = rng.integers(0, 255, (64, 64, 3), dtype=np.uint8)
        rec.write("gflow/s/frames", encode(Frame(Header("s", i, 0), NDArray.of(img))), i)
except DiskFull as e:
    print("FULL", e.strerror)
    sys.exit(0)
sys.exit(1)
"""


def test_recorder_closes_the_file_at_its_last_chunk_when_the_disk_is_full(tmp_path):
    path = tmp_path / "full.mcap"
    out = subprocess.run([sys.executable, "-c", _CHILD, str(path)], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stdout + out.stderr
    assert out.stdout.startswith("FULL the disk is full:") and "readable to there" in out.stdout
    n = int(out.stdout.split("closed after ")[1].split(" ")[0])
    assert n > 10
    assert path.stat().st_size <= 600_000
    with open(path, "rb") as f:  # a valid MCAP file: header, complete chunks, data end, footer, magic
        f.seek(-8, 2)
        assert f.read() == b"\x89MCAP0\r\n"
        f.seek(0)
        got = [m.sequence for _, _, m in make_reader(f).iter_messages()]
    assert got == list(range(n))
    assert not (tmp_path / ".full.mcap.reserve").exists()


@pytest.fixture
def small_disk(tmp_path):
    """A 6 MiB tmpfs (needs root, or skips saying why)."""
    d = tmp_path / f"small-{uuid.uuid4().hex[:6]}"
    d.mkdir()
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=6m", "tmpfs", str(d)], capture_output=True, text=True)
    if r.returncode != 0:
        pytest.skip(f"cannot mount a small tmpfs here (needs root): {r.stderr.strip()}")
    yield d
    subprocess.run(["umount", "-l", str(d)], capture_output=True)
    shutil.rmtree(d, ignore_errors=True)


def test_a_full_disk_stops_the_pipeline_cleanly(caviar1, tmp_path, small_disk):
    rec = small_disk / "run.mcap"
    out = cli_fork.run_command([sys.executable, "-m", "pipeline.cli.main", "track", str(caviar1), "--init",
                                "129,71,30,79", "--tracker", "chamfer", "--out", str(tmp_path / "b.csv"), "--record",
                                str(rec), "--stop", "120", "--listen", "tcp/127.0.0.1:0"], capture_output=True, text=True,
                               timeout=180)
    assert out.returncode == 3, out.stdout + out.stderr
    assert "the recording's disk is full" in out.stderr and "Traceback" not in out.stderr
    with open(rec, "rb") as f:
        f.seek(-8, 2)
        assert f.read() == b"\x89MCAP0\r\n"  # closed
    est = estimates(rec)
    boxes = read_boxes(tmp_path / "b.csv")  # the CSV has what was tracked, the recording or not
    assert set(est) <= set(boxes) and len(boxes) >= 1
    assert not list(small_disk.glob("*.part*.mcap"))  # a full disk is not worth a restart
