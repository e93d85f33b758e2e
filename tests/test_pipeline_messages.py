"""What the process pipeline sends per frame besides the data: the source announces its
position every few frames, not every frame (each announcement wakes every process)."""

from __future__ import annotations

from pipeline.io.mcap_io import iter_records
from gflow_msgs.messages import decode
from pipeline.runtime.build import apply_defaults
from pipeline.runtime.graph import load_graph
from pipeline.runtime.launcher import Launcher
from pipeline.runtime.transport import ZenohSettings, free_port

FRAMES = 60
HEARTBEAT_S = 0.5  # pipeline/runtime/node_base.py


def test_the_source_announces_every_few_frames_not_every_frame(tmp_path):
    plan = apply_defaults(load_graph("demo", overrides={"source": {"frames": FRAMES}, "filter": {"particles": 100}}))
    path = tmp_path / "run.mcap"
    res = Launcher(plan, zenoh=ZenohSettings(listen=(f"tcp/127.0.0.1:{free_port()}",)), recording=str(path),
                   progress=False, startup_timeout=60).run()
    assert res.ok, res.exits
    recs = list(iter_records(path))
    assert sum(r.type == "Estimate" for r in recs) == FRAMES
    status = [decode(r.data) for r in recs if r.topic.endswith("/_status/source")]
    # an announcement is a new position every 4 frames; a heartbeat (every 0.5 s) repeats the
    # last frame sent, so each heartbeat while frames were being sent may add a position. The
    # load of the machine is in the allowance (how long sending took); with an announcement per
    # frame there would be FRAMES positions.
    announced = {s.last_seq for s in status if s.last_seq >= 0}
    sent = [r.publish_ns for r in recs if r.type == "Frame"]
    beats = (max(sent) - min(sent)) / 1e9 / HEARTBEAT_S + 1
    assert len(announced) <= FRAMES / 4 + 3 + beats, (sorted(announced), beats)
