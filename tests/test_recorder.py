"""The recorder flushes a chunk at least every flush_interval: a SIGKILLed recorder loses
no more than that, and its file can still be read up to the torn end."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time

from pipeline.io.mcap_io import iter_records

WRITER = textwrap.dedent("""
    import sys, time, numpy as np
    from pipeline.io.recorder import McapRecorder
    from gflow_msgs.messages import Frame, Header, NDArray, encode
    import os
    rec = McapRecorder(sys.argv[1], flush_interval=0.5).open()
    stamp = os.open(sys.argv[2], os.O_WRONLY | os.O_CREAT)  # the last message written: its log time
    img = NDArray.of(np.zeros((120, 160), np.uint8))
    i = 0
    while True:
        now = time.time_ns()
        rec.write("gflow/t/frames", encode(Frame(Header("t", i, now), img)), i, log_ns=now)
        os.pwrite(stamp, now.to_bytes(8, "little"), 0)
        if i % 100 == 0:
            print(i, flush=True)
        i += 1
        time.sleep(0.002)
""")


def test_sigkill_loses_at_most_the_flush_interval(tmp_path):
    path = tmp_path / "killed.mcap"
    stamp = tmp_path / "last-written"
    p = subprocess.Popen([sys.executable, "-c", WRITER, str(path), str(stamp)], stdout=subprocess.PIPE, text=True)
    # wait until it has written 800 messages (several flush intervals), however slow the machine
    while int(p.stdout.readline() or -1) < 800:
        assert p.poll() is None, "the writer died"
    os.kill(p.pid, signal.SIGKILL)
    p.wait()
    last_written = int.from_bytes(stamp.read_bytes(), "little")
    notes: list[str] = []
    recs = list(iter_records(path, on_truncated=notes.append))
    assert notes and "not closed properly" in notes[0]
    seqs = [r.seq for r in recs]
    assert seqs == list(range(len(seqs))), "recovered messages must be the contiguous prefix"
    newest = max(r.log_ns for r in recs)
    lost_s = (last_written - newest) / 1e9
    # flush every 0.5 s, checked at each write; allow 0.3 s for a writer starved between two writes
    assert lost_s < 0.8, f"lost the last {lost_s:.2f} s"
    assert len(recs) > 300
