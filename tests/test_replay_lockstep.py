"""A live pipeline fed by `gflow replay --lockstep` gives the recorded outputs."""

from __future__ import annotations

import subprocess
import threading
import time

import yaml

from pipeline.runtime.build import apply_defaults
from pipeline.runtime.graph import load_graph, parse_graph
from pipeline.runtime.inline import run_inline
from pipeline.runtime.launcher import Launcher
from pipeline.runtime.running import running
from pipeline.io.mcap_io import iter_records
from pipeline.recording.rerun import recorded_plan
from pipeline.runtime.transport import ZenohSettings, free_port
import cli_fork


def _recorded_and_live(tmp_path, frames: int) -> tuple:
    """A demo run of ``frames`` frames recorded inline, and the graph of the same stages, live, with their input
    frames coming from outside it: (the recording, the live graph's YAML)."""
    original = tmp_path / "original.mcap"
    plan = apply_defaults(load_graph("demo", overrides={"source": {"frames": frames}, "filter": {"particles": 200}}))
    md = {"gflow.graph": {"yaml": plan.source_text}, "gflow.config": plan.config_metadata()}
    run_inline(plan, recording=str(original), metadata=md)
    rp = recorded_plan(original)
    doc = {"name": "live", "stream": rp.stream, "external": {"frames": "Frame"}, "stages": {}}
    for name, sp in rp.stages.items():
        if sp.is_source():
            continue
        spec = {"kind": sp.kind, "params": sp.params}
        if sp.inputs:
            spec["inputs"] = {p: t.rsplit("/", 1)[1] for p, t in sp.inputs.items()}
        doc["stages"][name] = spec
    return original, yaml.safe_dump(doc)


def test_lockstep_replay_into_live_stages_reproduces_the_recording(tmp_path, gflow_cmd):
    original, text = _recorded_and_live(tmp_path, 40)
    live = parse_graph(text, "live.yaml")
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


def test_lockstep_naming_a_stage_the_running_pipeline_lacks_is_refused_at_once(tmp_path, gflow_cmd):
    """``--lockstep filtr`` waited --ack-timeout (10 s by default) for a heartbeat that never came; with the
    pipeline running on the stream announced on this machine, the name is refused at once, with its stages."""
    original, text = _recorded_and_live(tmp_path, 5)
    (tmp_path / "live.yaml").write_text(text)
    port = free_port()
    run = subprocess.Popen([*gflow_cmd, "run", str(tmp_path / "live.yaml"), "--no-record", "--stream", "demo",
                            "--listen", f"tcp/127.0.0.1:{port}"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                           cwd=tmp_path)
    try:
        while not [i for i in running("demo") if i.get("pid") == run.pid]:  # announced: its graph is known
            assert run.poll() is None, "the live pipeline ended before it announced itself"
            time.sleep(0.05)
        for names, missing in (("filtr", "filtr"), ("preprocess,filtr", "filtr")):
            rep = cli_fork.run_command([*gflow_cmd, "replay", str(original), "--max", "--lockstep", names,
                                        "--ack-timeout", "3600", "--connect", f"tcp/127.0.0.1:{port}"],
                                       capture_output=True, text=True, timeout=120)
            lines = rep.stderr.strip().splitlines()
            assert rep.returncode == 2 and len(lines) == 1, rep.stderr
            assert f"--lockstep {missing}: no such stage" in lines[0] and "filter" in lines[0], lines
    finally:
        run.terminate()
        run.wait(60)
