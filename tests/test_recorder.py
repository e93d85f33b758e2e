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
    from stages.messages import Frame, Header, NDArray, encode
    rec = McapRecorder(sys.argv[1], flush_interval=0.5).open()
    img = NDArray.of(np.zeros((120, 160), np.uint8))
    i = 0
    while True:
        now = time.time_ns()
        rec.write("gflow/t/frames", encode(Frame(Header("t", i, now), img)), i, log_ns=now)
        if i == 0:
            print("started", flush=True)
        i += 1
        time.sleep(0.002)
""")


def test_sigkill_loses_at_most_the_flush_interval(tmp_path):
    path = tmp_path / "killed.mcap"
    p = subprocess.Popen([sys.executable, "-c", WRITER, str(path)], stdout=subprocess.PIPE, text=True)
    assert p.stdout.readline().strip() == "started"
    time.sleep(2.0)
    killed_at = time.time_ns()
    os.kill(p.pid, signal.SIGKILL)
    p.wait()
    notes: list[str] = []
    recs = list(iter_records(path, on_truncated=notes.append))
    assert notes and "not closed properly" in notes[0]
    seqs = [r.seq for r in recs]
    assert seqs == list(range(len(seqs))), "recovered messages must be the contiguous prefix"
    newest = max(r.log_ns for r in recs)
    lost_s = (killed_at - newest) / 1e9
    # flush every 0.5 s; allow 0.3 s for the kill and scheduling on a loaded machine
    assert lost_s < 0.8, f"lost the last {lost_s:.2f} s"
    assert len(recs) > 300
