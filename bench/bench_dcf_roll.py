"""CPU cost of the correlation-filter tracker's roll search (``roll_step``, gflow_core.dcf.rotation).

The tracker on the protocol in this process (``observe`` + ``propose`` + ``update`` of every frame,
decoding the JPEG not counted) over the first 200 frames of each sequence, three ways in one run
(the machine is shared: side by side, in CPU time): the default (no roll), ``roll_step=10`` (searched
on the frames the gate opens, held by the margin), and ``roll_step=10 roll_gate=0`` (searched on every
present frame). One core: ``cv2.setNumThreads(1)``. Writes nothing.

    python bench/bench_dcf_roll.py                                   # caviar1, skating1, twinnings
    python bench/bench_dcf_roll.py --sequences jumping,surfer
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import cv2

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from bench._util import table  # noqa: E402
from gflow_core.dcf.params import DCFParams  # noqa: E402
from gflow_core.dcf.tracker import TRACKER  # noqa: E402
from gflow_core.tracker import FrameRng, step  # noqa: E402
from pipeline.recording.results import read_boxes  # noqa: E402

DATA = ROOT.parent / "shared" / "data"
WAYS = (("default", DCFParams()), ("roll_step=10", DCFParams(roll_step=10.0)),
        ("roll_step=10 roll_gate=0", DCFParams(roll_step=10.0, roll_gate=0.0)))


def cpu_ms(p: DCFParams, imgs: list, box: tuple) -> float:
    """CPU ms a frame of the tracker over ``imgs`` from ``box``."""
    t0 = time.process_time()
    st, _ = TRACKER.init(p, TRACKER.observe(p, imgs[0]), box, FrameRng(1, 7, 0), {})
    for t, im in enumerate(imgs[1:], 1):
        st, _ = step(TRACKER, p, st, TRACKER.observe(p, im), FrameRng(1, 7, t))
    return 1000.0 * (time.process_time() - t0) / len(imgs)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sequences", default="caviar1,skating1,twinnings")
    ap.add_argument("--frames", type=int, default=200)
    a = ap.parse_args()
    if a.frames < 2:
        print(f"bench_dcf_roll: --frames must be >= 2, got {a.frames}", file=sys.stderr)
        return 2
    cv2.setNumThreads(1)
    rows = []
    for name in a.sequences.split(","):
        seq = DATA / name
        if not (seq / "frames").is_dir():
            print(f"bench_dcf_roll: {seq} is not a sequence folder", file=sys.stderr)
            return 2
        files = sorted((seq / "frames").iterdir())[: a.frames]
        gt = read_boxes(seq / "groundtruth.csv")
        first = min(gt)
        imgs = [cv2.imread(str(f)) for f in files[first:]]
        ms = [cpu_ms(p, imgs, gt[first]) for _, p in WAYS]
        rows.append([name, len(imgs)] + [f"{m:.1f} ms ({1000.0 / m:.0f}/s)" for m in ms])
    print(table(rows, ["sequence", "frames"] + [w for w, _ in WAYS]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
