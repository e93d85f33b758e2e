"""Would a colour cue find the target where the edge channels do not? A measurement, not a tracker.

One command: ``python bench/bench_colour_cue.py`` (``--case occlude-60 --seed 1``).

The appearance tracker matches edge-orientation channels. After david_indoor's 60-frame
occlusion the face that comes back scores r 0.1-0.3 against every exemplar it trusted before,
no better than clutter (docs/recovery.md). This benchmark asks whether the colour of the first
box alone separates the target from its best look-alike there, measured as the tracker's colour
cue measures it (:mod:`gflow_core.colour`: Perez et al.'s HSV bins, the Bhattacharyya
coefficient BC, about 12 x 12 samples a box).

For every shared sequence (``../shared/data`` or ``GFLOW_DATA``) the stress case is derived
(:func:`pipeline.evaluation.stress_benchmark.derive`, into a temporary folder removed at the end).
On every 5th frame from the end of the window on, it prints:

* target: BC of the frame-0 box's histogram with the true box's;
* clutter: the best BC over boxes of the true size, anywhere in the frame, that lie at least a
  box width or height away from the true box;
* the fraction of frames whose target BC beats that best clutter.

A grey sequence puts every pixel in the value bins: its BC compares grey-level histograms.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from _util import scratch, table  # noqa: E402

from gflow_core import colour  # noqa: E402
from gflow_core.evaluation.stress import CASES  # noqa: E402
from pipeline.evaluation.sequence_benchmark import find_sequences  # noqa: E402
from pipeline.evaluation.stress_benchmark import derive  # noqa: E402

DATA = Path(__file__).resolve().parent.parent.parent / "shared" / "data"


def measure(folder: Path, window: tuple[int, int], step: int = 5) -> list[tuple[int, float, float]]:
    """(frame, target BC, best clutter BC) on every ``step``-th frame after ``window``."""
    frames = sorted((folder / "frames").glob("*"))
    truth = np.loadtxt(folder / "groundtruth.csv", delimiter=",", skiprows=1)[:, 1:]

    def centre(b: np.ndarray) -> np.ndarray:
        return np.array([b[0] + (b[2] - 1) / 2.0, b[1] + (b[3] - 1) / 2.0])

    size0 = (float(truth[0][2]), float(truth[0][3]))
    first = colour.histogram(colour.bins(cv2.imread(str(frames[0]))), centre(truth[0]), size0,
                             colour.stride_for(size0))
    assert first is not None
    out = []
    for t in range(window[1], len(frames), step):
        img = cv2.imread(str(frames[t]))
        bins = colour.bins(img)
        b = truth[t]
        size = (float(b[2]), float(b[3]))
        stride = colour.stride_for(size)
        h = colour.histogram(bins, centre(b), size, stride)
        H, W = img.shape[:2]
        sc = colour.scan(bins, np.array([(W - 1) / 2.0, (H - 1) / 2.0]), (W / 2.0, H / 2.0), size, [first], stride)
        if h is None or sc is None:
            continue
        best = sc.best(sc.away(centre(b), size))
        if best is not None:
            out.append((t, colour.bhattacharyya(h, [first]), best[0]))
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--case", default="occlude-60", help="stress case whose frames after the window are measured")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    data = Path(os.environ.get("GFLOW_DATA", DATA))
    case = next((c for c in CASES if c.name == args.case), None)
    if case is None:
        print(f"bench_colour_cue: unknown case {args.case!r} (known: {', '.join(c.name for c in CASES)})")
        return 2
    if not data.is_dir():
        print(f"bench_colour_cue: no data at {data} (set GFLOW_DATA)")
        return 2
    seqs, _ = find_sequences([str(data)])
    tmp = scratch("gflow-colour-cue-")
    rows = []
    for i, seq in enumerate(seqs):
        d = derive(seq, case, seqs[(i + 1) % len(seqs)], tmp, args.seed, 30, 60)
        m = measure(d.seq.path, d.plan.window)
        if not m:
            continue
        tgt = np.array([v[1] for v in m])
        clu = np.array([v[2] for v in m])
        rows.append([seq.name, len(m), f"{np.median(tgt):.2f} ({tgt.min():.2f}-{tgt.max():.2f})",
                     f"{np.median(clu):.2f} ({clu.min():.2f}-{clu.max():.2f})", f"{np.mean(tgt > clu):.2f}"])
    print(f"colour histogram of the first box (gflow_core.colour) after the window of {case.name}, seed {args.seed}")
    print(table(rows, ["sequence", "frames", "target BC, median (range)", "best clutter BC", "target beats clutter"]))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
