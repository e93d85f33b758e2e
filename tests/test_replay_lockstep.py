"""A live pipeline fed by `gflow replay --lockstep` gives the recorded outputs."""

from __future__ import annotations

import threading

import yaml

from pipeline.runtime.build import apply_defaults
from pipeline.runtime.graph import load_graph, parse_graph
from pipeline.runtime.inline import run_inline
from pipeline.runtime.launcher import Launcher
from pipeline.io.mcap_io import iter_records
from pipeline.recording.rerun import recorded_plan
from pipeline.runtime.transport import ZenohSettings, free_port
import cli_fork


def test_lockstep_replay_into_live_stages_reproduces_the_recording(tmp_path, gflow_cmd):
    original = tmp_path / "original.mcap"
    plan = apply_defaults(load_graph("demo", overrides={"source": {"frames": 40}, "filter": {"particles": 200}}))
    md = {"gflow.graph": {"yaml": plan.source_text}, "gflow.config": plan.config_metadata()}
    run_inline(plan, recording=str(original), metadata=md)

    # the same stages, live, with their input frames coming from outside the graph
    rp = recorded_plan(original)
    doc = {"name": "live", "stream": rp.stream, "external": {"frames": "Frame"}, "stages": {}}
    for name, sp in rp.stages.items():
        if sp.is_source():
            continue
        spec = {"kind": sp.kind, "params": sp.params}
        if sp.inputs:
            spec["inputs"] = {p: t.rsplit("/", 1)[1] for p, t in sp.inputs.items()}
        doc["stages"][name] = spec
    live = parse_graph(yaml.safe_dump(doc), "live.yaml")
    port = free_port()
    new = tmp_path / "live.mcap"
    launcher = Launcher(live, zenoh=ZenohSettings(listen=(f"tcp/127.0.0.1:{port}",)), recording=str(new),
                        progress=False)
    result = {}
    th = threading.Thread(target=lambda: result.setdefault("r", launcher.run()), daemon=True)
    th.start()
    while set(launcher.status) < set(live.stages):
        th.join(0.05)
    rep = cli_fork.run_command([*gflow_cmd, "replay", str(original), "--max", "--topics", "gflow/demo/frames",
                                "--lockstep", "preprocess,filter", "--connect", f"tcp/127.0.0.1:{port}"],
                               capture_output=True, text=True, timeout=120)
    assert rep.returncode == 0, rep.stderr
    th.join(120)
    assert result["r"].ok, result["r"].exits

    def outs(p):
        return {(r.topic, r.seq): r.data for r in iter_records(p) if r.type in ("Estimate", "Particles", "Features")}

    a, b = outs(original), outs(new)
    assert len(a) == 4 * 40 and set(a) == set(b)
    assert all(a[k] == b[k] for k in a)


def test_replay_window_and_loop(tmp_path, gflow_cmd):
    import queue

    from pipeline.runtime.transport import Bus, open_session

    original = tmp_path / "original.mcap"
    plan = apply_defaults(load_graph("demo", overrides={"source": {"frames": 20}, "filter": {"particles": 100}}))
    run_inline(plan, recording=str(original))
    port = free_port()
    s = open_session(ZenohSettings(listen=(f"tcp/127.0.0.1:{port}",)))
    q: queue.SimpleQueue = queue.SimpleQueue()
    Bus(s).subscribe("gflow/demo/estimate", lambda k, p, ns, seq: q.put(seq))
    rep = cli_fork.run_command([*gflow_cmd, "replay", str(original), "--max", "--topics", "gflow/demo/estimate",
                                "--from-seq", "5", "--to-seq", "9", "--loop", "2", "--connect",
                                f"tcp/127.0.0.1:{port}"],
                               capture_output=True, text=True, timeout=60)
    assert rep.returncode == 0, rep.stderr
    got = []
    try:  # the ten sent, however long the machine takes to deliver them; then anything more already here
        while len(got) < 10:
            got.append(q.get(timeout=30))
    except queue.Empty:
        pass
    while not q.empty():
        got.append(q.get())
    s.close()
    # frames 5..8 twice, plus the end-of-stream marker (seq 20) each time
    assert got == [5, 6, 7, 8, 20, 5, 6, 7, 8, 20]
