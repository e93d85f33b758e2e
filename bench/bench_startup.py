"""Start-up of ``gflow track`` (the default tracker, or ``--tracker NAME``, processes) on caviar1 (or
``--sequence NAME`` of ../shared/data, from its first labelled box): N cold starts of a new
``python -m pipeline.cli track ... --stop 5`` process, each timed from just before the process is
started to the first estimate in its recording (the recorder's receive time).

The breakdown comes from ``GFLOW_STARTUP_TRACE`` (``pipeline/runtime/trace.py``): the CLI, the
launcher and every stage process write a timestamp at each step of the start-up. Printed: the
median time of each step since the start (ms) and, per stage process, how long each of its
own steps took; then the CPU seconds of each whole run (every process, start-up to exit).

``--compare DIR`` alternates the runs with the code in DIR (another worktree, e.g. the base):
there only the total to the first estimate and the CPU are known (no trace marks there).

    python bench/bench_startup.py --runs 5
    python bench/bench_startup.py --runs 5 --compare /path/to/base/worktree
    python bench/bench_startup.py --runs 5 --tracker gflow --sequence david_indoor
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import subprocess
import sys
import time
from collections import defaultdict
from pathlib import Path

import psutil

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from _util import checkout, scratch, table  # noqa: E402

from pipeline.cli.commands.track import DEFAULT_TRACKER  # noqa: E402
from pipeline.cli.trackers import TRACKERS  # noqa: E402
from pipeline.io.mcap_io import iter_records  # noqa: E402
from pipeline.recording.results import read_boxes  # noqa: E402

DATA = Path(os.environ.get("GFLOW_DATA", ROOT.parent / "shared" / "data"))

#: the CLI's and the launcher's steps, in order: (trace label, what the step since the previous one was)
MAIN_STEPS = [("cli start", "interpreter start"), ("cli imported", "CLI imports"), ("cli parsed", "argument parsing"),
              ("cli plan checked", "graph + preflight (first frame read)"),
              ("launcher run", "launcher set-up (run id, announce)"), ("launcher session", "launcher zenoh session"),
              ("spawned all", "spawning the stage processes"), ("launcher heard all", "handshake: every heartbeat"),
              ("launcher start sent", "start sent"), ("first estimate", "first frame through to the recorder")]
#: a stage process's steps (after "launcher spawned NAME PID")
NODE_STEPS = [("node begin", "interpreter"), ("imported", "imports"), ("opening session", "plan + node set-up"),
              ("session", "zenoh session"), ("stage built", "stage built"), ("declared", "subscribers declared"),
              ("heard all", "heard every peer")]


def first_estimate_ns(path: str) -> int | None:
    t = [r.log_ns for r in iter_records(path) if r.type in ("Estimate", "PoseEstimate")]
    return min(t) if t else None


def one_run(code: str, out: Path, k: int, init: str, seq: Path, tracker: str) -> dict | None:
    """One cold start of ``gflow track`` with the code in ``code``; the trace, the total and the CPU."""
    rec, trace = out / f"run-{k}.mcap", out / f"trace-{k}.txt"
    env = dict(os.environ, PYTHONPATH=code, GFLOW_STARTUP_TRACE=str(trace))
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.time_ns()
    r = subprocess.run([sys.executable, "-m", "pipeline.cli", "track", str(seq), "--init", init, "--stop", "5",
                        "--tracker", tracker, "--record", str(rec), "--out", str(out / f"run-{k}.csv"), "-q"],
                       capture_output=True, text=True, env=env, cwd=out)
    wall = (time.time_ns() - t0) / 1e9
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    if r.returncode != 0:
        print(f"gflow track failed ({code}): {r.stderr.strip()[-400:]}", file=sys.stderr)
        return None
    first = first_estimate_ns(str(rec))
    marks: dict[str, int] = {}
    nodes: dict[str, dict[str, int]] = defaultdict(dict)
    pid_name: dict[str, str] = {}
    lines = [ln.split(" ", 2) for ln in trace.read_text().splitlines()] if trace.exists() else []
    for t, pid, label in lines:
        if label.startswith("launcher spawned "):
            _, _, name, child = label.split(" ")
            pid_name[child] = name
            nodes[name]["spawned"] = int(t)
    for t, pid, label in lines:
        if label == "node begin" and pid in pid_name:
            nodes[pid_name[pid]]["node begin"] = int(t)
        elif label.startswith("node "):
            name, _, what = label[5:].partition(" ")
            if name in nodes:
                nodes[name].setdefault(what, int(t))
        else:
            marks.setdefault(label, int(t))
    if nodes:
        marks["spawned all"] = max(n["spawned"] for n in nodes.values())
    if first is not None:
        marks["first estimate"] = first
    cpu = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
    return {"t0": t0, "marks": marks, "nodes": dict(nodes), "first": (first - t0) / 1e9 if first else float("nan"),
            "wall": wall, "cpu": cpu}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--compare", metavar="DIR", help="another checkout to alternate with (e.g. the base)")
    ap.add_argument("--out", default=None, help="keep recordings and traces here (default: a temporary folder)")
    ap.add_argument("--tracker", default=DEFAULT_TRACKER, help=f"the tracker to start (default: {DEFAULT_TRACKER})")
    ap.add_argument("--sequence", default="caviar1", help="a sequence of the shared data (default: caviar1)")
    args = ap.parse_args()
    if args.tracker not in TRACKERS:
        ap.error(f"--tracker {args.tracker}: not a tracker; choose from {', '.join(sorted(TRACKERS))}")
    codes = {"this": str(ROOT)} | ({"compare": str(checkout(ap, args.compare))} if args.compare else {})
    seq = DATA / args.sequence
    if not seq.is_dir():
        sys.exit(f"bench_startup: {seq} not found (set GFLOW_DATA)")
    init = ",".join(f"{v:g}" for v in read_boxes(seq / "groundtruth.csv")[0])
    out = scratch("gflow-bench-startup-", keep=args.out)
    print(f"load before: {' '.join(f'{x:.2f}' for x in psutil.getloadavg())} on {psutil.cpu_count()} cores")
    runs: dict[str, list[dict]] = {c: [] for c in codes}
    k = 0
    for _ in range(args.runs):
        for c, code in codes.items():
            r = one_run(code, out, k, init, seq, args.tracker)
            k += 1
            if r is not None:
                runs[c].append(r)
    rows = []
    for c, rs in runs.items():
        firsts = [r["first"] for r in rs]
        rows.append([c, codes[c], len(rs), ", ".join(f"{x:.2f}" for x in firsts),
                     f"{statistics.median(firsts):.2f}" if firsts else "-",
                     f"{statistics.median(r['wall'] for r in rs):.2f}" if rs else "-",
                     f"{statistics.median(r['cpu'] for r in rs):.2f}" if rs else "-"])
    what = "the default tracker" if args.tracker == DEFAULT_TRACKER else "not the default"
    print(f"`gflow track {args.sequence} --stop 5` ({args.tracker}, {what}, processes): new process to the first "
          "estimate recorded")
    print(table(rows, ["code", "path", "runs", "to first estimate s", "median s", "median wall s (to exit)",
                       "median CPU s (all processes)"]))
    rs = runs["this"]
    if not rs or not rs[0]["marks"]:
        return
    print("\nbreakdown (this code), median over the runs: ms since the process was started, and the step's own ms")
    rows, prev = [], 0.0
    for label, what in MAIN_STEPS:
        at = [(r["marks"][label] - r["t0"]) / 1e6 for r in rs if label in r["marks"]]
        if not at:
            continue
        m = statistics.median(at)
        rows.append([label, what, f"{m:.0f}", f"{m - prev:.0f}"])
        prev = m
    print(table(rows, ["mark", "step", "at ms", "step ms"]))
    names = sorted({n for r in rs for n in r["nodes"]})
    rows = []
    for n in names:
        row = [n]
        prev_label = "spawned"
        for label, _ in NODE_STEPS:
            d = [(r["nodes"][n][label] - r["nodes"][n][prev_label]) / 1e6 for r in rs
                 if n in r["nodes"] and label in r["nodes"][n] and prev_label in r["nodes"][n]]
            row.append(f"{statistics.median(d):.0f}" if d else "-")
            prev_label = label
        at = [(r["nodes"][n]["heard all"] - r["t0"]) / 1e6 for r in rs if "heard all" in r["nodes"].get(n, {})]
        sp = [(r["nodes"][n]["spawned"] - r["t0"]) / 1e6 for r in rs if "spawned" in r["nodes"].get(n, {})]
        row += [f"{statistics.median(sp):.0f}" if sp else "-", f"{statistics.median(at):.0f}" if at else "-"]
        rows.append(row)
    print("\nper stage process, median ms of each of its steps (from its spawn), and when it was spawned / heard all")
    print(table(rows, ["stage"] + [w for _, w in NODE_STEPS] + ["spawned at ms", "heard all at ms"]))
    print(f"load after: {' '.join(f'{x:.2f}' for x in psutil.getloadavg())}")


if __name__ == "__main__":
    main()
