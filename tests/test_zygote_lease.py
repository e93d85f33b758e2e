"""The stage zygote leased run by run (pipeline/runtime/zygote.py): one process runs many pipelines off
one zygote, a dead one or one started for another environment is replaced, and the process is a child
subreaper (reaping the orphans of a run) only while a run holds the lease.

Each test runs its own Python process (real runs through the Python API, real zygotes and stage
processes) and reads the start-up trace (``GFLOW_STARTUP_TRACE``): ``zygote forked PID`` (an early
zygote), ``zygote started PID`` (a new interpreter), and each forked stage's ``node zygote PID``.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import data_dir

ROOT = Path(__file__).resolve().parent.parent

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the zygote is Linux-only")

#: a script's preamble: two helpers, ``track_once()`` (a short real run through the Python API,
#: as processes, no recording) and ``subreaper()`` (PR_GET_CHILD_SUBREAPER)
PRELUDE = """
import ctypes, json, os, signal, sys, time
from pipeline.app import TrackRequest, plan_track, run, track
from pipeline.cli.trackers import TRACKERS
from pipeline.runtime import zygote

def request():
    return TrackRequest(source=SOURCE, init=(204.0, 150.0, 17.0, 50.0), tracker="dcf", seed=1, stop=4,
                        inline=False, quiet=True, no_record=True)

def track_once():
    r = track(plan_track(request(), TRACKERS["dcf"]))
    assert sorted(r.estimates) == [0, 1, 2, 3], r.estimates
    return r

def subreaper():
    flag = ctypes.c_int(-1)
    assert ctypes.CDLL(None).prctl(zygote.PR_GET_CHILD_SUBREAPER, ctypes.byref(flag), 0, 0, 0) == 0
    return flag.value

def wait_for(cond, what, timeout=30.0):
    end = time.monotonic() + timeout
    while not cond():
        assert time.monotonic() < end, what
        time.sleep(0.01)
"""


def _script(code: str, tmp_path: Path, prelude: bool = True) -> tuple[dict, list[str]]:
    """Run PRELUDE + ``code`` (``code`` only: without ``prelude``) in a new interpreter; its last
    stdout line (JSON) and its trace lines."""
    trace = tmp_path / "trace.txt"
    e = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""),
             GFLOW_STARTUP_TRACE=str(trace))
    e.pop("GFLOW_ZYGOTE", None)
    head = f"SOURCE = {str(data_dir('crossing'))!r}\n" + PRELUDE if prelude else "import json, os\n"
    r = subprocess.run([sys.executable, "-c", head + code], capture_output=True, text=True, env=e, timeout=300,
                       cwd=tmp_path)
    assert r.returncode == 0, r.stderr[-3000:]
    lines = trace.read_text().splitlines() if trace.exists() else []
    return json.loads(r.stdout.strip().splitlines()[-1]), lines


def _forked_from(lines: list[str]) -> list[int]:
    """The zygote of each forked stage process, in order."""
    return [int(ln.split()[-1]) for ln in lines if " node zygote " in ln]


def _spawned(lines: list[str]) -> list[int]:
    return [int(ln.split()[-1]) for ln in lines if " launcher spawned " in ln]


def test_two_runs_of_the_python_api_fork_every_stage_from_one_zygote(tmp_path):
    """A process that forked no zygote at start-up starts one (a new interpreter) on its first run and
    keeps it: the second run's stages fork from it too (the first run in a thread of its own, which
    ends before the second: the zygote outlives it)."""
    out, lines = _script("assert len(list(run(plan_track(request(), TRACKERS['dcf'])))) == 4\n"
                         "a = zygote.held_pid()\n"
                         "track_once(); b = zygote.held_pid()\n"
                         "print(json.dumps([a, b]))\n", tmp_path)
    a, b = out
    started = [int(ln.split()[-1]) for ln in lines if " zygote started " in ln]
    assert a is not None and a == b and started == [a], (out, started)
    assert len(_spawned(lines)) == 6 and _forked_from(lines) == [a] * 6, lines  # 3 stages a run, 2 runs


def test_a_zygote_killed_between_runs_is_replaced_and_the_next_run_forks_from_the_new_one(tmp_path):
    """A dead zygote is not leased: the next run starts a new one and succeeds."""
    out, lines = _script("track_once(); a = zygote.held_pid()\n"
                         "os.kill(a, signal.SIGKILL)\n"
                         "wait_for(lambda: open(f'/proc/{a}/stat').read().rsplit(')', 1)[1].split()[0] == 'Z',\n"
                         "         'the zygote did not die')\n"
                         "track_once(); b = zygote.held_pid()\n"
                         "print(json.dumps([a, b]))\n", tmp_path)
    a, b = out
    assert b is not None and b != a, out
    assert _forked_from(lines) == [a] * 3 + [b] * 3, lines


def test_a_lease_with_another_environment_gets_a_new_zygote(tmp_path):
    """A new-interpreter zygote forks for the very environment it was started with only; an early one
    (forked by this process) for the same start-up variables (GFLOW_*...), whatever the others."""
    out, lines = _script("track_once(); a = zygote.held_pid()\n"
                         "track_once(); b = zygote.held_pid()\n"
                         "os.environ['SOME_UNRELATED_VARIABLE'] = 'x'\n"
                         "track_once(); c = zygote.held_pid()\n"
                         "print(json.dumps([a, b, c]))\n", tmp_path)
    a, b, c = out
    assert a == b and c not in (None, a), out
    assert _forked_from(lines) == [a] * 6 + [c] * 3, lines
    # the early zygote: forked at start-up, before any thread (so no API imported), with the start-up
    # variables it had
    out, _ = _script("from pipeline.runtime import zygote as z\n"
                     "early = z.Zygote.fork(); assert early is not None\n"
                     "z._hold(early)\n"
                     "env = z.stage_environment(os.environ, 1)\n"
                     "same = z.lease(dict(env, SOME_UNRELATED_VARIABLE='y'), ()); z.release(same, False)\n"
                     "other = z.lease(dict(env, GFLOW_LOG='INFO'), ()); z.release(other, False)\n"
                     "print(json.dumps([early.pid, same.pid, other.pid, early.alive()]))\n", tmp_path, prelude=False)
    early, same, other, alive = out
    assert same == early and other != early and not alive, out


def test_the_process_is_a_subreaper_only_while_a_run_holds_the_lease(tmp_path):
    """PR_GET_CHILD_SUBREAPER: 0 before a run, 1 at each estimate it yields, 0 again after it."""
    out, _ = _script("before = subreaper()\n"
                     "during = [subreaper() for _ in run(plan_track(request(), TRACKERS['dcf']))]\n"
                     "after = subreaper()\n"
                     "print(json.dumps([before, during, after]))\n", tmp_path)
    before, during, after = out
    assert before == 0 and during == [1] * 4 and after == 0, out


def test_an_orphan_of_a_run_is_reaped_by_the_lessee_and_not_after(tmp_path):
    """A stage's child that outlives it comes to the process holding the lease, which reaps it once it
    exits; after the run it goes elsewhere (not a child of ours)."""
    code = ("import subprocess\n"
            "def orphan():\n"
            "    p = subprocess.Popen([sys.executable, '-c', 'import os, sys, time\\n'\n"
            "                          'pid = os.fork()\\n'\n"
            "                          'if pid == 0:\\n    time.sleep(60)\\n'\n"
            "                          'print(pid, flush=True)'], stdout=subprocess.PIPE, text=True,\n"
            "                         start_new_session=True)\n"
            "    child = int(p.stdout.readline()); p.wait()\n"
            "    return p.pid, child\n"
            "def ppid(pid):\n"
            "    return int(open(f'/proc/{pid}/stat').read().rsplit(')', 1)[1].split()[1])\n"
            "z = zygote.lease(zygote.stage_environment(os.environ, 1), ())\n"
            "stage, kid = orphan()\n"
            "wait_for(lambda: ppid(kid) == os.getpid(), 'the orphan did not come to us')\n"
            "os.kill(kid, signal.SIGKILL)\n"
            "reaped = []\n"
            "wait_for(lambda: reaped.extend(zygote.reap_orphans([stage], [stage])) or reaped, 'not reaped')\n"
            "gone = not os.path.exists(f'/proc/{kid}')\n"
            "zygote.release(z, False)\n"
            "stage2, kid2 = orphan()\n"
            "wait_for(lambda: ppid(kid2) != stage2, 'the second orphan was not re-parented')\n"
            "after = ppid(kid2)\n"
            "os.kill(kid2, signal.SIGKILL)\n"
            "print(json.dumps([reaped == [kid], gone, after != os.getpid()]))\n")
    out, _ = _script(code, tmp_path)
    assert out == [True, True, True], out


#: a stage process that starts a helper (as a stage may start a decoder or a plug-in's tool), says its pid and runs
#: on until it is killed
STAGE = ("import signal, subprocess, sys\n"
         "helper = subprocess.Popen([sys.executable, '-c', 'import signal; signal.pause()'],\n"
         "                          stdout=subprocess.DEVNULL)\n"
         "print(helper.pid, flush=True)\n"
         "signal.pause()\n")


def test_the_supervisor_loop_reaps_an_orphan_of_a_killed_stage_and_no_other_child(tmp_path):
    """A stage process killed (a crash, the OOM killer) leaves its helper behind: the helper comes to the
    process holding the lease, and when it exits it stays a zombie of that process unless the supervisor's
    loop (``Supervisor.check``) reaps it. A child of the process that is not the run's (another session) is
    left for its own ``wait``."""
    code = (f"STAGE = {STAGE!r}\n"
            "import subprocess\n"
            "from pathlib import Path\n"
            "from pipeline.runtime.graph import parse_graph\n"
            "from pipeline.runtime.supervision import Supervisor\n"
            "def state(pid):\n"
            "    try:\n"
            "        fields = open(f'/proc/{pid}/stat').read().rsplit(')', 1)[1].split()\n"
            "    except FileNotFoundError:\n"
            "        return None, None\n"
            "    return fields[0], int(fields[1])\n"
            "graph = Path(zygote.__file__).parents[1] / 'graphs' / 'demo.yaml'\n"
            "sup = Supervisor(parse_graph(graph.read_text(), str(graph)), say=print)\n"
            "z = zygote.lease(zygote.stage_environment(os.environ, 1), ())\n"
            "assert z is not None and subreaper() == 1\n"
            "stage = subprocess.Popen([sys.executable, '-c', STAGE], stdout=subprocess.PIPE, text=True,\n"
            "                         start_new_session=True)\n"
            "sup.pids['source'] = [stage.pid]  # as Supervisor.spawn notes the process of a stage it starts\n"
            "helper = int(stage.stdout.readline())\n"
            "stage.kill(); stage.wait()\n"
            "wait_for(lambda: state(helper)[1] == os.getpid(), 'the helper did not come to the lessee')\n"
            "mine = subprocess.Popen([sys.executable, '-c', 'pass'], start_new_session=True)\n"
            "os.kill(helper, signal.SIGTERM)\n"
            "wait_for(lambda: state(helper)[0] == 'Z' and state(mine.pid)[0] == 'Z', 'the children did not exit')\n"
            "running = sup.check([], [])\n"
            "after = [state(helper)[0], state(mine.pid)[0], mine.wait()]\n"
            "zygote.release(z, False)\n"
            "print(json.dumps([running, after]))\n")
    out, _ = _script(code, tmp_path)
    assert out == [False, [None, "Z", 0]], out  # the orphan is gone; our own child waited for its wait


def test_benchmark_forks_every_stage_of_every_run_from_one_zygote(tmp_path):
    """``gflow benchmark`` with two sequences: one zygote, forked at start-up, forks all its stages."""
    trace = tmp_path / "trace.txt"
    e = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""),
             GFLOW_STARTUP_TRACE=str(trace))
    e.pop("GFLOW_ZYGOTE", None)
    data = data_dir("crossing").parent
    r = subprocess.run([sys.executable, "-m", "pipeline.cli.main", "benchmark", str(data), "--sequences",
                        "crossing,jumping", "--trackers", "dcf", "--frames", "0:4", "--no-fps",
                        "--out-dir", str(tmp_path / "out")],
                       capture_output=True, text=True, env=e, timeout=300, cwd=tmp_path)
    assert r.returncode == 0, r.stderr[-3000:]
    lines = trace.read_text().splitlines()
    early = [int(ln.split()[-1]) for ln in lines if " zygote forked " in ln]
    assert len(early) == 1 and not any(" zygote started " in ln for ln in lines), lines
    assert len(_spawned(lines)) == 8 and _forked_from(lines) == early * 8, lines  # 4 stages a run, 2 runs
