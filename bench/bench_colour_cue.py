"""Would a colour cue find the target where the edge channels do not? A measurement, not a tracker.

One command: ``python bench/bench_colour_cue.py`` (``--case occlude-60 --seed 1``).

The appearance tracker matches edge-orientation channels. After david_indoor's 60-frame
occlusion the face that comes back scores r 0.1-0.3 against every exemplar it trusted before,
no better than clutter (docs/recovery.md, "What falls short"). This benchmark asks whether the
colour of the first box would separate the target from its best look-alike there. It uses the
hue-saturation histogram of the box (16 x 8 bins, as colour-based particle filters such as
Perez et al., ECCV 2002 do) and the Bhattacharyya coefficient BC = sum_b sqrt(p_b q_b).

For every shared sequence (``../shared/data`` or ``GFLOW_DATA``) the stress case is derived
(:func:`pipeline.cli.stress_benchmark.derive`, into a temporary folder removed at the end).
On every 5th frame from the end of the window on, it prints:

* target: BC of the frame-0 box's histogram with the true box's;
* clutter: the best BC over boxes of the true size, every quarter box, that lie at least a box
  width or height away from the true box;
* the fraction of frames whose target BC beats that best clutter.

A grey sequence has every pixel at saturation 0, so every BC is 1 and colour says nothing.
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

from gflow_core.stress import CASES  # noqa: E402
from pipeline.cli.sequence_benchmark import find_sequences  # noqa: E402
from pipeline.cli.stress_benchmark import derive  # noqa: E402

DATA = Path(__file__).resolve().parent.parent.parent / "shared" / "data"
H_BINS, S_BINS = 16, 8


def bins(img: np.ndarray) -> np.ndarray:
    """(H, W) int: the hue-saturation bin of every pixel of a BGR image."""
    hsv = cv2.cvtColor(img, cv2.COLOR_BGR2HSV)
    return (hsv[..., 0].astype(np.int64) * H_BINS // 180) * S_BINS + hsv[..., 1].astype(np.int64) * S_BINS // 256


def integral(b: np.ndarray) -> np.ndarray:
    """(H + 1, W + 1, K) cumulative counts of each bin, K = H_BINS * S_BINS."""
    onehot = np.zeros(b.shape + (H_BINS * S_BINS,), dtype=np.int32)
    np.put_along_axis(onehot, b[..., None], 1, axis=2)
    out = np.zeros((b.shape[0] + 1, b.shape[1] + 1, onehot.shape[2]), dtype=np.int32)
    out[1:, 1:] = onehot.cumsum(0).cumsum(1)
    return out


def hists(ii: np.ndarray, xs: np.ndarray, ys: np.ndarray, w: int, h: int) -> np.ndarray:
    """(len(ys), len(xs), K) normalised histograms of the w x h boxes with top-left corners (xs, ys)."""
    x0, y0 = xs[None, :], ys[:, None]
    c = ii[y0 + h, x0 + w] - ii[y0, x0 + w] - ii[y0 + h, x0] + ii[y0, x0]
    return c / float(w * h)


def measure(folder: Path, window: tuple[int, int], step: int = 5) -> list[tuple[int, float, float]]:
    """(frame, target BC, best clutter BC) on every ``step``-th frame after ``window``."""
    frames = sorted((folder / "frames").glob("*"))
    truth = np.loadtxt(folder / "groundtruth.csv", delimiter=",", skiprows=1)[:, 1:]

    def box_hist(ii: np.ndarray, b: np.ndarray) -> np.ndarray:
        x, y = max(int(round(b[0])), 0), max(int(round(b[1])), 0)
        w = min(int(round(b[2])), ii.shape[1] - 1 - x)
        h = min(int(round(b[3])), ii.shape[0] - 1 - y)
        return hists(ii, np.array([x]), np.array([y]), w, h)[0, 0]

    p = box_hist(integral(bins(cv2.imread(str(frames[0])))), truth[0])
    out = []
    for t in range(window[1], len(frames), step):
        img = cv2.imread(str(frames[t]))
        ii = integral(bins(img))
        b = truth[t]
        w, h = int(round(b[2])), int(round(b[3]))
        H, W = img.shape[:2]
        if w < 4 or h < 4 or w >= W or h >= H:
            continue
        target = float(np.sqrt(p * box_hist(ii, b)).sum())
        xs = np.arange(0, W - w, max(w // 4, 1))
        ys = np.arange(0, H - h, max(h // 4, 1))
        q = hists(ii, xs, ys, w, h)
        bc = np.sqrt(p[None, None, :] * q).sum(axis=2)
        away = (np.abs(ys - b[1])[:, None] >= h) | (np.abs(xs - b[0])[None, :] >= w)
        if away.any():
            out.append((t, target, float(bc[away].max())))
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
    print(f"colour (hue-saturation histogram of the first box) after the window of {case.name}, seed {args.seed}")
    print(table(rows, ["sequence", "frames", "target BC, median (range)", "best clutter BC", "target beats clutter"]))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
