"""Ctrl-C or SIGTERM on `gflow`: every stage stops, the recording is closed properly, and
what was tracked so far is kept."""

from __future__ import annotations

import os
import signal
import subprocess
import time

import psutil
import pytest
from mcap.reader import make_reader

from pipeline.recording.results import estimates


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_signal_stops_every_stage_and_closes_the_recording(tmp_path, gflow_cmd, sig):
    rec = tmp_path / "run.mcap"
    p = subprocess.Popen([*gflow_cmd, "run", "demo", "--set", "source.realtime=true", "--set", "source.frames=600",
                          "--set", "filter.particles=100", "--record", str(rec),
                          "--listen", "tcp/127.0.0.1:0"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    parent = psutil.Process(p.pid)
    deadline = time.monotonic() + 90
    # the recording is readable while it is written (every flushed chunk): wait for 20 estimates
    while not (rec.exists() and rec.stat().st_size > 64 and len(estimates(rec)) >= 20):
        assert time.monotonic() < deadline and p.poll() is None, "the pipeline did not get going"
        time.sleep(0.2)
    # source, preprocess, proposal, filter, render, recorder; and the zygote the run leased: all must go
    children = parent.children()
    stages = [c for c in children if "pipeline.runtime.node" in " ".join(c.cmdline())]
    assert len(stages) == 6 and len(children) <= 7, [c.cmdline() for c in children]
    p.send_signal(sig)
    out, err = p.communicate(timeout=60)
    assert p.returncode == 130, err
    assert "interrupted" in err
    gone, alive = psutil.wait_procs(children, timeout=10)
    assert not alive, f"stage processes left running: {alive}"
    with open(rec, "rb") as f:
        summary = make_reader(f).get_summary()  # only a properly closed file has one
    assert summary is not None and summary.statistics.message_count > 0
    est = estimates(rec)
    assert 20 < len(est) < 600  # it tracked for a while, and stopped early
    assert sorted(est) == list(range(len(est)))
