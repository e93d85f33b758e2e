"""The launcher hands each stage process a typed node plan; no GFLOW_* environment variable
carries the run's state from the launcher to a stage process."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

from pipeline.runtime.build import apply_defaults
from pipeline.runtime.graph import load_graph
from pipeline.runtime.launcher import Launcher
from pipeline.runtime.node_plan import NodePlan, read_node_plan
from pipeline.runtime.transport import ZenohSettings, free_port

ROOT = Path(__file__).resolve().parent.parent

#: the GFLOW_* variables the code may name: each one a user sets to configure the tool
USER_VARIABLES = {
    "GFLOW_ZYGOTE": "0 starts stage processes as new interpreters (read by the gflow command)",
    "GFLOW_STARTUP_TRACE": "a file for start-up timestamps (bench/bench_startup.py; every process)",
    "GFLOW_RUNTIME_DIR": "where running graphs announce themselves (gflow ps, topics, echo)",
    "GFLOW_ZENOH_PASSWORD": "the password of --user (read by the command line)",
    "GFLOW_LOG": "a stage process's log level",
    "GFLOW_RUN_PARENT": "where the launcher puts the run's temporary folder",
    "GFLOW_STALL_S": "seconds without progress before the launcher stops a run",
    "GFLOW_LATE_S": "seconds before a late input is given up (read by the launcher, sent in the plan)",
    "GFLOW_DRAIN_S": "seconds a finished stage waits for its messages to arrive (read by the launcher)",
    "GFLOW_RECORDINGS_WARN_MB": "the recordings folder's size above which a run says so (0 never)",
    "GFLOW_SIMD": "native leaves numpy's, OpenCV's and OpenBLAS's SIMD kernels to them (not held to x86-64-v3)",
}


def test_the_code_names_only_variables_a_user_sets():
    named: dict[str, list[str]] = {}
    for top in ("pipeline", "stages", "gflow_core"):
        for path in (ROOT / top).rglob("*.py"):
            for name in set(re.findall(r"GFLOW_[A-Z0-9_]+", path.read_text())):
                named.setdefault(name, []).append(str(path.relative_to(ROOT)))
    unknown = {n: files for n, files in named.items() if n not in USER_VARIABLES}
    assert not unknown, f"GFLOW_* variables that are not a user's settings (state goes in the node plan): {unknown}"
    assert {"GFLOW_ZYGOTE", "GFLOW_LATE_S"} <= set(named)  # the scan sees the code


def test_every_stage_process_gets_its_plan_and_no_gflow_variable_from_the_launcher(tmp_path, monkeypatch):
    """Read from /proc/PID/environ, so the stages are started as new interpreters (GFLOW_ZYGOTE=0): a stage
    forked from the zygote sets its environment in os.environ, which /proc/PID/environ does not show (it
    shows the zygote's own, its start overwritten by the process title setproctitle writes)."""
    monkeypatch.setenv("GFLOW_ZYGOTE", "0")
    plan = apply_defaults(load_graph("demo", overrides={"source": {"frames": 20, "fps": 20.0, "realtime": True},
                                                        "filter": {"particles": 100}}))
    seen: dict[str, tuple[set[str], list[str], NodePlan]] = {}

    def look(status) -> None:  # the launcher's loop, while the stage processes run
        for name, st in status.items():
            if name in seen or not st.pid:
                continue
            try:
                env = Path(f"/proc/{st.pid}/environ").read_bytes().split(b"\0")
                argv = [a for a in Path(f"/proc/{st.pid}/cmdline").read_bytes().decode().split("\0") if a]
                if len(argv) == 1:  # forked from a zygote: its title is one string (zygote.py, _set_title)
                    argv = argv[0].split()
                if argv[-1:] != [name]:  # forked, it takes its title a moment after it starts
                    continue
                node = read_node_plan(argv[-2])  # in the run folder, removed at the end of the run
            except OSError:
                continue
            keys = {e.split(b"=", 1)[0].decode() for e in env if e}
            assert "PATH" in keys, f"{name}: /proc/{st.pid}/environ is not the environment it was given: {keys}"
            seen[name] = ({k for k in keys if k.startswith("GFLOW_")}, argv, node)

    z = ZenohSettings(listen=(f"tcp/127.0.0.1:{free_port()}",))
    res = Launcher(plan, zenoh=z, recording=str(tmp_path / "run.mcap"), progress=False, on_status=look).run()
    assert res.ok, res.exits
    assert set(seen) == set(plan.stages)
    ours = {k for k in os.environ if k.startswith("GFLOW_")}
    for name, (gflow_vars, argv, node) in seen.items():
        assert gflow_vars <= ours, f"{name} got {sorted(gflow_vars - ours)} from the launcher"
        assert argv[-3] == "pipeline.runtime.node" and argv[-1] == name
        assert node.stage == name and node.launcher_pid == os.getpid() and node.restarts == 0
        assert node.recording == str(tmp_path / "run.mcap") and node.graph.stages.keys() == plan.stages.keys()


def test_the_node_plan_round_trips_and_names_its_stage(tmp_path):
    from pipeline.runtime.node_plan import write_node_plan

    plan = apply_defaults(load_graph("demo"))
    node = NodePlan(graph=plan, stage="filter", zenoh=ZenohSettings(connect=("tcp/127.0.0.1:7447",)),
                    launcher_pid=1234, run_dir=str(tmp_path), restarts=2, peers=("source", "recorder"),
                    recording="run.part2.mcap", late_s=10.0, cv_threads=2)
    back = read_node_plan(write_node_plan(node, str(tmp_path)))
    assert back.stage == "filter" and back.restarts == 2 and back.peers == ("source", "recorder")
    assert back.zenoh == node.zenoh and back.late_s == 10.0 and back.state_dir == str(tmp_path / "state")
    assert back.graph.stages["filter"].params["particles"] == plan.stages["filter"].params["particles"]


def test_a_bad_node_plan_is_one_line(tmp_path):
    bad = tmp_path / "filter.json"
    bad.write_text('{"stage": "filter", "restarts": "two"}')
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    r = subprocess.run([sys.executable, "-m", "pipeline.runtime.node", str(bad), "filter"], capture_output=True,
                       text=True, env=env, timeout=60)
    assert r.returncode == 2
    assert r.stderr.strip().count("\n") == 0 and "is not a node plan" in r.stderr and "Traceback" not in r.stderr
