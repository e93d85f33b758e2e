"""Placement and run ids, without a network: which stages a host starts, the one-line errors,
and the stream every run gets."""

from __future__ import annotations

from pathlib import Path

import pytest

from pipeline.runtime.graph import GraphError, load_graph, parse_graph
from pipeline.runtime.placement import describe_hosts, host_labels, local_stages
from pipeline.runtime.runid import choose_stream
import cli_fork


def test_host_picks_the_stages_placed_there():
    plan = load_graph("demo_hosts")
    assert host_labels(plan) == ["cam", "edge", "ops"]
    assert local_stages(plan, ("edge",)) == {"preprocess", "proposal", "filter"}
    assert local_stages(plan, ("cam", "ops")) == {"source", "render", "recorder"}
    assert local_stages(plan, ()) == set(plan.stages)  # no --host: everything here
    assert describe_hosts(plan, {"source", "recorder"}) == "cam (source); ops (recorder)"


def test_unknown_or_missing_host_labels_are_one_line_errors():
    plan = load_graph("demo_hosts")
    with pytest.raises(GraphError, match=r"no stage .* placed on 'edg' \(its hosts: cam, edge, ops\)"):
        local_stages(plan, ("edg",))
    with pytest.raises(GraphError, match="places no stage on a host"):
        local_stages(load_graph("demo"), ("edge",))
    text = load_graph("demo_hosts").source_text.replace("  render:\n    host: ops\n", "  render:\n")
    with pytest.raises(GraphError, match="stage 'render' has no host, but other stages do"):
        parse_graph(text, "g.yaml")
    with pytest.raises(GraphError, match="on_host_lost must be stop or wait"):
        parse_graph(text.replace("on_host_lost: stop", "on_host_lost: later"), "g.yaml")


def test_every_run_gets_its_own_stream_and_keeps_its_random_draws():
    a, b = load_graph("demo"), load_graph("demo")
    sa, sb = choose_stream(a, None, placed=False), choose_stream(b, None, placed=False)
    assert sa != sb and sa.startswith("demo-") and sb.startswith("demo-")
    assert all(t.startswith(f"gflow/{sa}/") for s in a.stages.values() for t in [*s.inputs.values(), *s.outputs.values()])
    assert a.seed_stream == b.seed_stream == "demo"  # the stages' random draws do not depend on the run id
    c = load_graph("demo_hosts")
    assert choose_stream(c, None, placed=True) == "demo"  # every host reads the same file
    assert choose_stream(load_graph("demo_hosts"), "site4", placed=True) == "site4"
    with pytest.raises(GraphError, match="--stream"):
        choose_stream(load_graph("demo"), "a/b", placed=False)


@pytest.mark.parametrize("tool", [["topics", "--duration", "1"], ["echo", "gflow/x/estimate", "--timeout", "1"],
                                  ["hz", "gflow/x/estimate", "--wait", "1"],
                                  ["pub", "gflow/x/_control", "Control", '{"command": "stop"}', "--wait", "1"]])
def test_live_tools_that_reach_nothing_say_so(tool, tmp_path):
    """Each in the same words, exit 2 (pub said it with exit 1, as if a wait for a subscriber had run out)."""
    import sys

    from pipeline.runtime.transport import free_port

    r = cli_fork.run_command([sys.executable, "-m", "pipeline.cli.main", *tool, "--connect", f"tcp/127.0.0.1:{free_port()}"],
                             cwd=tmp_path, capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and "reached nothing at tcp/127.0.0.1:" in r.stderr, r.stderr
    assert r.stderr.startswith(f"gflow {tool[0]}: error: ") and "within 3 s (is a gflow pipeline" in r.stderr, r.stderr


def test_a_recorder_only_graph_records_until_the_end_of_stream(tmp_path):
    """A graph fed from outside (external topics, a recorder and nothing else) records every
    message until the end of each stream, then exits 0 by itself."""
    import os
    import subprocess
    import sys
    import time

    from pipeline.io.mcap_io import iter_records

    gflow = [sys.executable, "-m", "pipeline.cli.main"]
    env = dict(os.environ, GFLOW_RUNTIME_DIR=str(tmp_path / "rt"))
    base = tmp_path / "base.mcap"
    r = cli_fork.run_command([*gflow, "run", "demo", "--inline", "--set", "source.frames=10", "--set", "filter.particles=50",
                              "--record", str(base)], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    (tmp_path / "rec.yaml").write_text("name: rec\nstream: demo\nexternal: {frames: Frame, estimate: Estimate}\n"
                                       "stages:\n  recorder:\n    kind: recorder\n")
    out = tmp_path / "out.mcap"
    p = subprocess.Popen([*gflow, "run", "rec.yaml", "--stream", "demo", "--record", str(out)], cwd=tmp_path, env=env,
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 60
        while not out.exists():  # the recorder opens its file after declaring its subscriber
            assert p.poll() is None and time.monotonic() < deadline, p.stderr.read() if p.poll() is not None else ""
            time.sleep(0.05)
        rp = cli_fork.run_command([*gflow, "replay", str(base), "--max", "--topics", "gflow/demo/frames",
                                   "gflow/demo/estimate"], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120)
        assert rp.returncode == 0, rp.stderr
        _, err = p.communicate(timeout=60)
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == 0 and "Traceback" not in err, err
    want = [(r.topic, r.type, r.seq) for r in iter_records(base) if r.topic in ("gflow/demo/frames", "gflow/demo/estimate")]
    got = [(r.topic, r.type, r.seq) for r in iter_records(out) if r.topic in ("gflow/demo/frames", "gflow/demo/estimate")]
    assert sorted(got) == sorted(want) and len(want) == 22  # 10 frames, 10 estimates, 2 ends of stream


def test_a_tool_given_the_graphs_stream_finds_the_one_run_of_it(tmp_path):
    """Every run has its own stream (demo-3f9c2a); `gflow echo gflow/demo/estimate` still finds it
    while it is the only run of that graph, and says which run it took."""
    import json
    import os
    import subprocess
    import sys
    import time

    gflow = [sys.executable, "-m", "pipeline.cli.main"]
    rt = tmp_path / "rt"
    env = dict(os.environ, GFLOW_RUNTIME_DIR=str(rt))
    p = subprocess.Popen([*gflow, "run", "demo", "--set", "source.realtime=true", "--set", "source.fps=20",
                          "--set", "source.frames=3000", "--set", "filter.particles=100", "--no-record",
                          "--listen", "tcp/127.0.0.1:0"], env=env, cwd=tmp_path,
                         stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 60
        while not (rt.is_dir() and list(rt.glob("*.json"))):
            assert time.monotonic() < deadline and p.poll() is None, "the pipeline did not announce itself"
            time.sleep(0.05)
        info = json.loads(next(rt.glob("*.json")).read_text())
        assert info["stream"].startswith("demo-") and info["camera"] == "demo"
        r = cli_fork.run_command([*gflow, "echo", "gflow/demo/estimate", "-n", "1", "--timeout", "60"], env=env,
                                 capture_output=True, text=True, timeout=120)
        assert r.returncode == 0, r.stderr
        assert f"(stream demo: the running run {info['stream']})" in r.stderr
        assert r.stdout.startswith(f"gflow/{info['stream']}/estimate: Estimate seq=")
    finally:
        p.terminate()
        p.wait(60)


def test_record_on_a_host_without_the_recorder_is_refused_before_anything_starts(tmp_path):
    """`--record` on a host whose stages do not include the recorder used to be ignored
    without a word; now it is a one-line error naming the recorder's host."""
    import sys

    root = Path(__file__).resolve().parent.parent
    r = cli_fork.run_command([sys.executable, "-m", "pipeline.cli", "run", "demo_hosts", "--host", "cam",
                              "--record", str(tmp_path / "x.mcap")], cwd=root, capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert "recorder runs on host ops" in r.stderr and r.stderr.count("\n") == 1, r.stderr
    assert not (tmp_path / "x.mcap").exists()


class _NoNetwork:
    """The one call HostWatch makes on a session: a liveliness subscriber (fed by hand here)."""

    def liveliness(self):
        return self

    def declare_subscriber(self, *args, **kwargs):
        return None


def test_a_lost_host_is_named_with_every_stage_it_ran_even_when_their_tokens_go_one_by_one():
    from pipeline.runtime.multihost import HostWatch

    plan = load_graph("demo_hosts")
    said: list[str] = []
    watch = HostWatch(_NoNetwork(), plan, local={"source"}, say=said.append, settle_s=60.0)
    watch.ever = watch.alive = set(watch.remote)
    running = {n: "running" for n in plan.stages}
    assert not watch.check(running) and not said
    watch.alive = set(watch.remote) - {"proposal"}  # the first of edge's tokens is gone
    assert not watch.check(running) and not said     # the others are still there: not yet
    watch.alive = {"render", "recorder"}             # edge's last tokens follow
    assert watch.check(running)
    assert said == ["host lost: edge (preprocess, proposal, filter) stopped answering (liveliness token gone); "
                    "stopping this host's stages (on_host_lost: stop)"]
    # a single stage that dies while the rest of its host lives is named once the wait is over
    said.clear()
    watch = HostWatch(_NoNetwork(), plan, local={"source"}, say=said.append, settle_s=0.0)
    watch.ever, watch.alive = set(watch.remote), set(watch.remote) - {"render"}
    assert watch.check(running) and said[0].startswith("host lost: ops (render) stopped answering")


def test_a_draining_stage_of_another_host_whose_token_is_gone_has_finished():
    """Its final 'done' heartbeat can be lost on a lossy link: the run must not wait for it for ever."""
    from pipeline.runtime.multihost import HostWatch

    plan = load_graph("demo_hosts")
    watch = HostWatch(_NoNetwork(), plan, local={"render", "recorder"}, say=lambda s: None)
    remote = ["source", "preprocess", "proposal", "filter"]
    watch.ever = watch.alive = set(remote)
    states = {"source": "done", "preprocess": "done", "proposal": "draining", "filter": "running"}
    assert watch.unfinished(remote, states) == ["proposal", "filter"]
    watch.alive = set(remote) - {"proposal"}  # proposal exited; its "done" never arrived
    assert watch.unfinished(remote, states) == ["filter"]
    watch.alive = set(remote) - {"proposal", "filter"}  # a running stage whose token went is lost, not finished
    assert watch.unfinished(remote, states) == ["filter"]
    assert watch.check(states)


def test_a_stage_heartbeat_overtaken_by_its_final_one_does_not_undo_it():
    import io

    from pipeline.runtime.progress import Console, ProgressMonitor
    from gflow_msgs.messages import Header, StageStatus, encode

    plan = load_graph("demo_hosts")
    mon = ProgressMonitor(plan, Console(io.StringIO(), enabled=False))

    def hb(pid: int, stamp: int, state: str) -> None:
        st = StageStatus(header=Header(plan.stream, 40, stamp), stage="filter", pid=pid, state=state, steps=40, fps=0.0)
        mon._on_status("k", encode(st), stamp, 40)

    hb(7, 200, "done")
    hb(7, 100, "draining")  # sent earlier by the heartbeat thread, arrived later
    assert mon.states()["filter"] == "done"
    hb(8, 50, "running")  # a new process of the stage (a restart): its own clock
    assert mon.states()["filter"] == "running"
