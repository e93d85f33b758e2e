"""Drops are not silent: a live stage that misses frames reports how many, per input, on its
heartbeat (and so in the recording and in the launcher's progress line)."""

from __future__ import annotations

import queue
import threading
import time

import numpy as np

from pipeline.runtime.graph import parse_graph
from pipeline.runtime.launcher import Launcher
from pipeline.io.mcap_io import iter_records
from pipeline.runtime.transport import Bus, ZenohSettings, free_port, open_session
from gflow_msgs.messages import EndOfStream, Frame, Header, NDArray, StageStatus, decode, encode

GRAPH = """
name: drops
stream: cam0
external: {frames: Frame}
stages:
  preprocess:
    kind: preprocess
    inputs: {frames: frames}
    qos: {features: drop}
  recorder:
    kind: recorder
"""


def test_missing_frames_are_counted_on_the_heartbeat(tmp_path):
    plan = parse_graph(GRAPH, "drops.yaml")
    assert plan.drop_topics() == {"gflow/cam0/features"}
    port = free_port()
    rec = tmp_path / "drops.mcap"
    launcher = Launcher(plan, zenoh=ZenohSettings(listen=(f"tcp/127.0.0.1:{port}",)), recording=str(rec),
                        progress=False)
    result = {}
    th = threading.Thread(target=lambda: result.setdefault("r", launcher.run()), daemon=True)
    th.start()
    while set(launcher.status) < set(plan.stages):
        th.join(0.05)
    s = open_session(ZenohSettings(connect=(f"tcp/127.0.0.1:{port}",)))
    bus = Bus(s)
    pub = bus.publisher("gflow/cam0/frames")
    deadline = time.monotonic() + 30
    while not pub.matching_status.matching:  # the stage's subscription has reached this session
        assert time.monotonic() < deadline, "no subscriber to gflow/cam0/frames within 30 s"
        time.sleep(0.02)
    heard: queue.Queue[int] = queue.Queue()
    bus.subscribe("gflow/cam0/features", lambda k, p, ns, seq: heard.put(seq))
    img = NDArray.of(np.random.default_rng(0).integers(0, 255, (60, 80), dtype=np.uint8))
    for seq in (0, 1, 2, 5, 6, 9):  # frames 3, 4, 7 and 8 never arrive
        # one frame at a time: `features` is a drop topic, and a burst may be dropped by design; a frame
        # is sent again every 2 s until its features come (a publisher may match the recorder before its
        # route to the stage has settled; the stage takes a second copy as a repeat, not a frame)
        deadline = time.monotonic() + 30
        got = -1
        while got != seq:
            assert time.monotonic() < deadline, f"no features of frame {seq} within 30 s"
            bus.publish("gflow/cam0/frames", encode(Frame(Header("cam0", seq, seq), img)), seq, "Frame")
            try:
                while (got := heard.get(timeout=2.0)) != seq:
                    pass
            except queue.Empty:
                pass
    # the end of the stream, again every 2 s until the pipeline has ended (a second EndOfStream only
    # ends an input already ended)
    deadline = time.monotonic() + 60
    while th.is_alive() and time.monotonic() < deadline:
        bus.publish("gflow/cam0/frames", encode(EndOfStream(Header("cam0", 10, 0))), 10, "EndOfStream")
        th.join(2.0)
    s.close()
    if th.is_alive():  # fail cleanly: stop the pipeline rather than leave it running at exit
        launcher.request_stop()
        th.join(30)
        raise AssertionError("the pipeline did not end within 60 s of the end of the stream")
    assert result["r"].ok, result["r"].exits
    last = [decode(r.data) for r in iter_records(rec, topics=["gflow/cam0/_status/preprocess"])][-1]
    assert isinstance(last, StageStatus) and last.dropped == {"frames": 4}
    assert result["r"].status["preprocess"].dropped == {"frames": 4}
    feats = [r.seq for r in iter_records(rec, topics=["gflow/cam0/features"]) if r.type == "Features"]
    assert feats == [0, 1, 2, 5, 6, 9]
