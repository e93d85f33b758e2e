"""G-flow through the pipeline at 320x240: frames/s for 1, 20 and 100 experts with the
background model off and on, inline and as processes over zenoh (1 and 2 proposal shards),
the size of each message type, and the peak memory (RSS) of the proposal and filter processes.

One command: ``python bench/bench_gflow_pipeline.py [--frames 60] [--experts 1,20,100] [--source david]``

The frames are a rendered textured head (``gflow_core.gflow.synthetic_head``) written once as PNGs
(rendering is not timed), or with ``--source david`` the first frames of ../shared/data/david_indoor
from its first ground-truth box; the source reads them as fast as the pipeline takes them. The
G-flow settings are the graph's (``pipeline/graphs/gflow.yaml``: the built-in face model). Frames/s
counts the tracked frames over the time from the first to the last estimate, from the
recording's log times (start-up excluded). Message sizes are the mean encoded payloads in
the recording. Peak RSS is each process's high-water mark (``VmHWM`` in /proc/PID/status, read
every 0.1 s while it runs, so a peak between two heartbeats is not missed; a restarted
process counts its worst run); CPU is each process's user + system time per tracked frame
(from /proc/PID/stat at the last reading). Targets: every process under 250 MB
at 100 experts with the background model on; with 2 shards faster than inline.
"""

from __future__ import annotations

import argparse
import os
import sys
import threading
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from _util import gflow_plan, gflow_sets, scratch, table  # noqa: E402

from gflow_core.gflow.params import ELLIPSOID  # noqa: E402

from gflow_core.gflow.synthetic_head import synthetic_sequence  # noqa: E402
from pipeline.runtime.inline import run_inline  # noqa: E402
from pipeline.runtime.launcher import Launcher  # noqa: E402
from pipeline.io.mcap_io import iter_records  # noqa: E402
from pipeline.runtime.transport import ZenohSettings, free_port  # noqa: E402

SIZE_TYPES = ("Frame", "Features", "ExpertStates", "PoseProposals", "PoseEstimate")


def render(folder: Path, n: int) -> np.ndarray:
    seq = synthetic_sequence(np.random.default_rng(11), n, (240, 320), rot_amp_deg=(8, 15, 6), trans_amp_px=(30, 15))
    folder.mkdir(parents=True, exist_ok=True)
    for t, f in enumerate(seq.frames):
        cv2.imwrite(str(folder / f"{t:06d}.png"), np.rint(f * 255).astype(np.uint8))
    return seq.box


def david_frames(folder: Path, n: int) -> np.ndarray:
    """Copy the first ``n`` frames of david_indoor; returns its first ground-truth box."""
    data = Path(__file__).resolve().parent.parent.parent / "shared" / "data" / "david_indoor"
    if not data.is_dir():
        raise SystemExit(f"{data} not found: --source david needs ../shared/data/david_indoor")
    folder.mkdir(parents=True, exist_ok=True)
    for t in range(n):
        (folder / f"{t:06d}.jpg").write_bytes((data / "frames" / f"{t:06d}.jpg").read_bytes())
    first = (data / "groundtruth.csv").read_text().splitlines()[1].split(",")
    return np.array([float(v) for v in first[1:5]])


def plan(folder: Path, box, experts: int, background: bool, shards: int, settings: dict | None = None):
    """The graph's plan on the frames in ``folder``; ``settings`` are G-flow parameters (a model's preset
    and ``--gflow-set`` values) over the graph's."""
    shared = {**(settings or {}), "init": [float(v) for v in box], "n_experts": experts, "background": background,
              "seed": 0}
    return gflow_plan({"kind": "folder", "path": str(folder)}, shared, shards=shards)


def measure(path: str) -> tuple[int, float, dict[str, float]]:
    """(tracked frames, fps from first to last estimate, mean payload bytes per message type)."""
    t, sizes = [], {}
    for r in iter_records(path):
        if r.type == "PoseEstimate":
            t.append(r.log_ns)
        if r.type in SIZE_TYPES:
            sizes.setdefault(r.type, []).append(len(r.data))
    fps = (len(t) - 1) / ((max(t) - min(t)) / 1e9) if len(t) > 1 else float("nan")
    return len(t), fps, {k: float(np.mean(v)) for k, v in sizes.items()}


BUDGET_MB = 250


class ProcWatch:
    """Peak RSS (VmHWM) and CPU seconds of a launcher's stage processes, read from /proc."""

    def __init__(self, launcher: Launcher) -> None:
        self.la = launcher
        self.hwm: dict[str, float] = {}
        self.cpu: dict[int, tuple[str, float]] = {}
        self.stop = threading.Event()
        self.th = threading.Thread(target=self._run, daemon=True)
        self.th.start()

    def _run(self) -> None:
        tick = os.sysconf("SC_CLK_TCK")
        while not self.stop.wait(0.1):
            for name, pids in list(self.la.pids.items()):
                for pid in list(pids):
                    try:
                        with open(f"/proc/{pid}/status") as f:
                            kb = next(int(ln.split()[1]) for ln in f if ln.startswith("VmHWM:"))
                        with open(f"/proc/{pid}/stat") as f:
                            fields = f.read().rsplit(")", 1)[1].split()
                    except (OSError, StopIteration, IndexError):
                        continue
                    self.hwm[name] = max(self.hwm.get(name, 0.0), kb / 1024)
                    self.cpu[pid] = (name, (int(fields[11]) + int(fields[12])) / tick)  # utime + stime

    def finish(self) -> tuple[dict[str, float], dict[str, float]]:
        self.stop.set()
        self.th.join()
        cpu: dict[str, float] = {}
        for name, s in self.cpu.values():
            cpu[name] = cpu.get(name, 0.0) + s
        return self.hwm, cpu


def _mb(v: float) -> str:
    return f"{v:.0f}" + ("*" if v > BUDGET_MB else "")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=60, help="frames per run (default 60)")
    ap.add_argument("--experts", default="1,20,100", help="comma-separated expert counts")
    ap.add_argument("--modes", default="inline,processes,processes-2", help="inline, processes, processes-K (K shards)")
    ap.add_argument("--out", default=None, help="folder for frames and recordings (default: a temporary one)")
    ap.add_argument("--source", choices=("synthetic", "david"), default="synthetic",
                    help="a rendered head (default) or the first frames of ../shared/data/david_indoor")
    ap.add_argument("--model", choices=("face", "ellipsoid"), default="face",
                    help="the built-in face model with the graph's settings (default) or the generic ellipsoid "
                         "head with its own (gflow_core.gflow.params.ELLIPSOID), as `gflow track --model`")
    ap.add_argument("--gflow-set", action="append", default=[], metavar="NAME=VALUE",
                    help="a G-flow parameter over the model's settings (repeatable), as `gflow track --gflow-set`")
    ap.add_argument("--background", default="off,on", help="background model: off, on or off,on (default)")
    args = ap.parse_args()
    settings = {**(ELLIPSOID if args.model == "ellipsoid" else {}), **gflow_sets(args.gflow_set)}
    tmp = scratch("gflow-bench-", keep=args.out)
    if args.source == "david":
        box = david_frames(tmp / "frames", args.frames)
    else:
        box = render(tmp / "frames", args.frames)
    print(f"G-flow pipeline, 320x240, {args.source} frames, {args.frames} frames, the {args.model} model with the graph's "
          f"settings{''.join(' ' + v for v in args.gflow_set)}; load "
          f"average {os.getloadavg()[0]:.1f} at the start; {tmp}")
    rows, size_rows, mem_rows = [], [], []
    for E in (int(v) for v in args.experts.split(",")):
        for bg in (v == "on" for v in args.background.split(",")):
            for mode in args.modes.split(","):
                shards = int(mode.split("-")[1]) if "-" in mode else 1
                if shards > E:
                    continue
                rec = str(tmp / f"E{E}-bg{int(bg)}-{mode}.mcap")
                p = plan(tmp / "frames", box, E, bg, shards, settings)
                if mode == "inline":
                    c0 = os.times()
                    run_inline(p, recording=rec)
                    c1 = os.times()
                    rss, cpu = {}, {"inline": (c1.user + c1.system) - (c0.user + c0.system)}
                else:
                    la = Launcher(p, zenoh=ZenohSettings(listen=(f"tcp/127.0.0.1:{free_port()}",)), recording=rec,
                                  progress=False, startup_timeout=120)
                    watch = ProcWatch(la)
                    res = la.run()
                    rss, cpu = watch.finish()
                    if not res.ok:
                        raise SystemExit(f"run failed: {res.exits}")
                n, fps, sizes = measure(rec)
                cpu_ms = 1e3 * sum(cpu.values()) / max(n, 1)
                rows.append([E, "on" if bg else "off", mode, n, f"{fps:.1f}", f"{cpu_ms:.0f}",
                             " ".join(f"{k} {1e3 * v / max(n, 1):.0f}" for k, v in sorted(cpu.items()))])
                if mode == "inline":
                    size_rows.append([E, "on" if bg else "off"] + [f"{sizes.get(k, 0) / 1024:.1f}" for k in SIZE_TYPES])
                if rss:
                    prop = max(v for k, v in rss.items() if k.startswith("proposal"))
                    mem_rows.append([E, "on" if bg else "off", mode, *(_mb(v) for v in (
                        prop, rss.get('filter', 0), rss.get('preprocess', 0), rss.get('source', 0),
                        rss.get('recorder', 0))), BUDGET_MB, "yes" if max(rss.values()) <= BUDGET_MB else "NO"])
                print(f"  E={E} background={'on' if bg else 'off'} {mode}: {fps:.1f} fps", file=sys.stderr)
    print(f"\nframes/s (first to last estimate; load average {os.getloadavg()[0]:.1f} at the end)")
    print(table(rows, ["experts", "background", "mode", "frames", "fps", "CPU ms/frame", "by process"]))
    print("\nmean message size (KiB, encoded payload)")
    print(table(size_rows, ["experts", "background", *SIZE_TYPES]))
    print(f"\npeak RSS per process (MB, VmHWM; budget {BUDGET_MB} MB each, * = over it)")
    print(table(mem_rows, ["experts", "background", "mode", "proposal (max over shards)", "filter", "preprocess",
                           "source", "recorder", "budget", "all within"]))


if __name__ == "__main__":
    main()
