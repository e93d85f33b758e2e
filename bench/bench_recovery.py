"""Speed of the appearance tracker while it tracks and while it searches for a hidden
target: CPU time per frame and frames/s, on real frames with a long full occlusion.
One command: ``python bench/bench_recovery.py``.

Every shared sequence (``../shared/data``, or ``GFLOW_DATA``) gets the stress case
``occlude-150`` (a real image patch hides the target for 150 frames, between 30 frames before
and 60 after; :mod:`gflow_core.evaluation.stress`), and the tracker runs on it twice:

* **in one process, one frame at a time, OpenCV on one thread as in a stage process**, with the
  default cues (edges and colour) and with the edges alone (the filter's work only: grey
  levels, appearance channels, colour bins and ``gflow_core.appearance.filter.step``, with the
  proposal's random walk): CPU ms per frame, split by
  what the tracker reported on the frame -- ``tracked``, or ``occluded`` / ``lost`` (it
  searches a widening region, up to the whole frame). The channels are computed in the step
  here; as a stage process the filter computes them for the next frame on a second thread.
* **as processes over zenoh** (``gflow track``'s graph, the source reading the folder as fast as
  the filter takes it): frames/s over the whole run and over the frames reported hidden, from
  the recording's log times, and the CPU ms per frame of every stage process.

The machine is shared: the load average is printed before and after; compare the two kinds of
frame within one run rather than figures between runs.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import psutil

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from _util import pct, scratch, table  # noqa: E402
from bench_pipeline import CpuSampler  # noqa: E402

from gflow_core.appearance import filter as ap  # noqa: E402
from gflow_core.appearance.tracker import TRACKER  # noqa: E402
from gflow_core.m2.dynamics import random_walk  # noqa: E402
from gflow_core.evaluation.stress import CASES  # noqa: E402
from pipeline.evaluation.sequence_benchmark import find_sequences  # noqa: E402
from pipeline.evaluation.stress_benchmark import derive  # noqa: E402
from pipeline.cli.trackers import appearance as cli_appearance  # noqa: E402
from pipeline.io.mcap_io import iter_records  # noqa: E402
from pipeline.runtime.graph import load_graph  # noqa: E402
from pipeline.runtime.launcher import Launcher  # noqa: E402
from pipeline.runtime.transport import ZenohSettings, free_port  # noqa: E402
from gflow_msgs.messages import Estimate, decode  # noqa: E402

DATA = Path(__file__).resolve().parent.parent.parent / "shared" / "data"


def core_run(folder: Path, truth0: tuple[float, float, float, float], seed: int = 1,
             colour: bool = True) -> dict[str, list[float]]:
    """CPU seconds of each frame's observation (grey levels, channels, colour bins) + step, by the
    state the tracker reported; ``colour`` False: the edges alone (``--set tracker.colour=false``)."""
    frames = sorted((folder / "frames").glob("*"))
    cv2.setNumThreads(1)  # as in a stage process (pipeline/runtime/stage_host.py)
    p = ap.AppearanceParams(colour=colour)
    obs = TRACKER.observe(p, cv2.imread(str(frames[0]), cv2.IMREAD_COLOR))
    st = ap.initialise(obs.channels(), truth0, p, np.random.default_rng([seed, 0]), obs.bins)
    dyn = random_walk(p.walk_std(truth0), 0.0, 0.0)
    out: dict[str, list[float]] = {"tracked": [], "searching": []}
    for t in range(1, len(frames)):
        img = cv2.imread(str(frames[t]), cv2.IMREAD_COLOR)  # not timed: decoding is the source's work
        a = np.column_stack([st.particles[:, :2], np.zeros(len(st.particles)), np.exp(st.particles[:, 2])])
        a = dyn.predict(a, np.random.default_rng([seed, 1, t]))
        prop = np.column_stack([a[:, :2], np.log(a[:, 3])])
        c0 = time.process_time()
        obs = TRACKER.observe(p, img)
        res = ap.step(st, obs.channels(), prop, p, np.random.default_rng([seed, 2, t]), bins=obs.bins)
        c1 = time.process_time()
        st = res.state
        out["tracked" if res.target_state == "tracked" else "searching"].append(c1 - c0)
    return out


def _cues(colour: bool) -> str:
    return "edges + colour" if colour else "edges alone"


def pipeline_run(folder: Path, truth0: tuple[float, float, float, float], rec: str) -> dict:
    """The appearance graph as processes on the folder: fps overall and over the hidden frames,
    and the CPU ms per frame of each stage while tracking."""
    ns = argparse.Namespace(init=list(truth0), particles=None, seed=1)
    graph, ov = cli_appearance.overrides(ns)
    ov["source"] = {"kind": "folder", "path": str(folder / "frames")}
    plan = load_graph(graph, overrides=ov)
    with CpuSampler() as cs:
        res = Launcher(plan, zenoh=ZenohSettings(listen=(f"tcp/127.0.0.1:{free_port()}",)), recording=rec,
                       progress=False).run()
    if not res.ok:
        raise RuntimeError(f"pipeline failed: {res.exits}")
    est = []
    for r in iter_records(rec):
        if r.type == "Estimate":
            m = decode(r.data)
            assert isinstance(m, Estimate)
            est.append((r.log_ns, m.target_state))
    est.sort()
    t = np.array([e[0] for e in est], dtype=np.int64)
    hidden = np.array([e[1] != "tracked" for e in est])
    fps = (len(t) - 1) / ((t[-1] - t[0]) / 1e9)
    # hidden stretch: the frames from the first to the last reported hidden
    idx = np.flatnonzero(hidden)
    fps_hidden = (len(idx) - 1) / ((t[idx[-1]] - t[idx[0]]) / 1e9) if len(idx) > 1 else float("nan")
    stages = {n: 1e3 * sum(cs.cpu_between(pid, int(t[0]), int(t[-1])) for pid in pids) / (len(t) - 1)
              for n, pids in res.pids.items()}
    return {"frames": len(t), "hidden": int(hidden.sum()), "fps": fps, "fps_hidden": fps_hidden, "stages": stages}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--case", default="occlude-150", help="stress case (default occlude-150)")
    parser.add_argument("--sequences", default=None, help="comma-separated sequence names (default: every shared one)")
    parser.add_argument("--no-processes", action="store_true", help="only the in-process CPU figures")
    parser.add_argument("--out", default=None, help="keep the derived frames and recordings here")
    args = parser.parse_args()
    data = Path(os.environ.get("GFLOW_DATA", DATA))
    if not data.is_dir():
        sys.exit(f"no data at {data} (set GFLOW_DATA)")
    seqs, _ = find_sequences([str(data)])
    if args.sequences:
        want = set(args.sequences.split(","))
        seqs = [s for s in seqs if s.name in want]
    case = next(c for c in CASES if c.name == args.case)
    out = scratch("gflow-bench-recovery-", keep=args.out)
    print(f"load before: {' '.join(f'{x:.2f}' for x in psutil.getloadavg())} on {psutil.cpu_count()} cores")
    rows, prow = [], []
    all_t: dict[bool, list[float]] = {True: [], False: []}
    all_s: dict[bool, list[float]] = {True: [], False: []}
    for i, seq in enumerate(seqs):
        donor = seqs[(i + 1) % len(seqs)]
        d = derive(seq, case, donor, out / "derived", seed=1, lead=30, tail=60)
        folder = d.seq.path
        truth0 = d.seq.groundtruth[min(d.seq.groundtruth)]
        for colour in (True, False):
            cpu = core_run(folder, truth0, colour=colour)
            tr, se = 1e3 * np.array(cpu["tracked"]), 1e3 * np.array(cpu["searching"])
            all_t[colour] += list(tr)
            all_s[colour] += list(se)
            rows.append([seq.name, _cues(colour), len(tr), len(se), f"{tr.mean():.1f}", f"{pct(tr, 95):.1f}",
                         f"{se.mean():.1f}" if len(se) else "-", f"{pct(se, 95):.1f}" if len(se) else "-",
                         f"{1e3 / max(tr.mean(), 1e-9):.0f}", f"{1e3 / se.mean():.0f}" if len(se) else "-"])
        if not args.no_processes:
            r = pipeline_run(folder, truth0, str(out / f"{seq.name}.mcap"))
            prow.append([seq.name, r["frames"], r["hidden"], f"{r['fps']:.1f}", f"{r['fps_hidden']:.1f}",
                         "  ".join(f"{n} {v:.1f}" for n, v in sorted(r["stages"].items()))])
    for colour in (True, False):
        t, s = np.array(all_t[colour]), np.array(all_s[colour])
        rows.append(["all", _cues(colour), len(t), len(s), f"{t.mean():.1f}", f"{pct(t, 95):.1f}", f"{s.mean():.1f}",
                     f"{pct(s, 95):.1f}", f"{1e3 / t.mean():.0f}", f"{1e3 / s.mean():.0f}"])
    print(f"\n{case.name} ({case.describe()}): the filter's CPU per frame in one process (grey levels, channels, "
          "colour bins + step; frame decoding not counted), the default and the edges alone side by side")
    print(table(rows, ["sequence", "cues", "tracked frames", "searching frames", "tracked ms/f", "tracked p95",
                       "searching ms/f", "searching p95", "tracked frames/s (1 core)", "searching frames/s (1 core)"]))
    if prow:
        print("\nas processes (gflow track's graph): frames/s from the first to the last estimate, and over the "
              "frames reported occluded/lost; CPU ms per frame of each stage process while tracking")
        print(table(prow, ["sequence", "frames", "hidden frames", "fps", "fps while hidden", "stage CPU ms/frame"]))
    print(f"load after: {' '.join(f'{x:.2f}' for x in psutil.getloadavg())}")


if __name__ == "__main__":
    main()
