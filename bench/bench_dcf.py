"""Speed of the correlation-filter tracker (``--tracker dcf``) beside the appearance tracker.

Two measurements, both in CPU time (the machine is shared: wall time says more about the other
users than about the tracker):

1. **The tracker itself**, on the protocol in this process (``observe`` + ``propose`` + ``update`` of
   every frame, decoding the JPEG not counted), per shared sequence: CPU ms per frame (mean, median,
   90th percentile) and the frames/s that CPU allows one core. One core: numpy's FFTs and the
   tracker's OpenCV calls are single-threaded here (``cv2.setNumThreads(1)``, as a stage process on a
   loaded machine).
2. **The pipeline**, ``gflow track --tracker dcf`` as processes (``--no-record``) on one sequence: the
   CPU of every process of the run (user + system, from ``getrusage`` of the children) per frame,
   and the frames/s that leaves two cores.

    python bench/bench_dcf.py                       # every shared sequence, both trackers, and the pipeline on caviar1
    python bench/bench_dcf.py --sequences jumping   # one sequence
    python bench/bench_dcf.py --no-pipeline         # the tracker only
"""

from __future__ import annotations

import argparse
import resource
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from bench._util import pct, table  # noqa: E402
from gflow_core.tracker import FrameRng, stream_hash  # noqa: E402
from pipeline.recording.results import read_boxes  # noqa: E402

DATA = ROOT.parent / "shared" / "data"
SEQUENCES = ("caviar1", "crossing", "david_indoor", "dollar", "jumping", "skating1", "surfer", "tiger1", "twinnings")


def _tracker(name: str):
    if name == "dcf":
        from gflow_core.dcf.params import DCFParams
        from gflow_core.dcf.tracker import TRACKER

        return TRACKER, DCFParams()
    from gflow_core.appearance.params import AppearanceParams
    from gflow_core.appearance.tracker import TRACKER as APP

    return APP, AppearanceParams()


def cpu_per_frame(seq: Path, name: str) -> np.ndarray:
    """CPU seconds of observe + propose + update of every frame after the first."""
    impl, params = _tracker(name)
    gt = read_boxes(seq / "groundtruth.csv")
    files = sorted((seq / "frames").iterdir())
    f0 = min(gt)
    h = stream_hash("cam0")
    st, _ = impl.init(params, impl.observe(params, cv2.imread(str(files[f0]))), gt[f0], FrameRng(1, h, f0), {})
    out = []
    for t in range(f0 + 1, len(files)):
        img = cv2.imread(str(files[t]))
        c0 = time.process_time()
        obs = impl.observe(params, img)
        rng = FrameRng(1, h, t)
        st, _ = impl.update(params, st, impl.propose(params, st, obs, rng), obs, rng)
        out.append(time.process_time() - c0)
    return np.array(out)


def pipeline(seq: Path) -> tuple[int, float, float]:
    """(frames, CPU s of every process, wall s) of ``gflow track --tracker dcf`` as processes."""
    gt = read_boxes(seq / "groundtruth.csv")
    box = ",".join(str(v) for v in gt[min(gt)])
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    w0 = time.perf_counter()
    out = ROOT / ".bench-dcf-boxes.csv"
    try:
        r = subprocess.run([sys.executable, "-m", "pipeline.cli.main", "track", str(seq), "--tracker", "dcf", "--init",
                            box, "--seed", "1", "--out", str(out), "--no-record", "-q"], capture_output=True, text=True,
                           timeout=1800)
        n = len(read_boxes(out)) if r.returncode == 0 else 0
    finally:
        out.unlink(missing_ok=True)
    wall = time.perf_counter() - w0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if r.returncode != 0:
        raise SystemExit(f"gflow track failed: {r.stderr.strip()}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return n, cpu, wall


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sequences", default=",".join(SEQUENCES), help="shared sequences to time (default all nine)")
    ap.add_argument("--trackers", default="dcf,appearance", help="trackers to time in this process")
    ap.add_argument("--pipeline", default="caviar1", help="sequence of the processes run")
    ap.add_argument("--no-pipeline", action="store_true", help="skip the processes run")
    a = ap.parse_args()
    if not DATA.is_dir():
        raise SystemExit(f"the shared sequences are not at {DATA}")
    cv2.setNumThreads(1)
    rows = []
    for name in a.sequences.split(","):
        for trk in a.trackers.split(","):
            ms = 1000.0 * cpu_per_frame(DATA / name, trk)
            rows.append([name, trk, len(ms), f"{ms.mean():.1f}", f"{pct(ms, 50):.1f}", f"{pct(ms, 90):.1f}",
                         f"{1000.0 / ms.mean():.0f}"])
            print(f"  {name} / {trk}: {ms.mean():.1f} ms CPU a frame", file=sys.stderr, flush=True)
    print("The tracker in this process, one core (CPU time of observe + propose + update):")
    print(table(rows, ["sequence", "tracker", "frames", "CPU ms/frame", "median", "p90", "frames/s one core"]))
    if not a.no_pipeline:
        n, cpu, wall = pipeline(DATA / a.pipeline)
        print(f"\ngflow track {a.pipeline} --tracker dcf as processes: {n} frames, {1000.0 * cpu / n:.1f} ms CPU a "
              f"frame over every process (start-up included), {2.0 * n / cpu:.0f} frames/s on two cores at that "
              f"CPU; wall {wall:.1f} s ({n / wall:.1f} frames/s on this machine now)")


if __name__ == "__main__":
    main()
