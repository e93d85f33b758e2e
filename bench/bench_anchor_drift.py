"""Where does the first box's look fit, against the annotated box? A measurement, not a tracker.

One command: ``python bench/bench_anchor_drift.py`` (``--sequence david_indoor --every 3``).

The appearance tracker anchors its model on the region of the first annotated box (exemplar 0,
never replaced; :mod:`gflow_core.appearance.filter`). If later annotations frame the target
differently from the first one -- a larger margin, a centre placed lower on the face -- a
tracker faithful to the first box is off the annotation by that much, however well it tracks.
This benchmark runs the appearance tracker (seed 1) over a shared sequence and, on every
``--every``-th frame, searches the frame around the annotated box for the best normalised
correlation of the tracker's three exemplars (the first box's, and the running ones it has
then), exactly as the tracker measures it (:func:`gflow_core.appearance.filter._exemplar`):

* **place**: at the tracker's own scale, the offset (dx, dy) of the best match from the
  annotated centre, over +-6 px;
* **scale**: at the annotated centre (+-2 px of freedom), the log-size of the best match
  relative to the annotated box's (sqrt of its area against the first box's), over +-0.3.

Beside them it prints the tracker's own offset and log-size error. Where the first box's best
match is off the annotation by as much as the tracker is, the tracker is following its first
box, and what remains is how the annotation frames the target.
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

from _util import table  # noqa: E402

from gflow import Tracker  # noqa: E402
from gflow_core.appearance import filter as ap  # noqa: E402

DATA = Path(os.environ.get("GFLOW_DATA", Path(__file__).resolve().parent.parent.parent / "shared" / "data"))
EXEMPLARS = ("anchor", "recent", "slow")


def _ncc(a: np.ndarray, b: np.ndarray) -> float:
    """Pearson correlation of two equally shaped arrays."""
    x, y = a.ravel() - a.mean(), b.ravel() - b.mean()
    return float(x @ y / np.sqrt((x @ x) * (y @ y) + 1e-12))


def _best_place(feat: np.ndarray, st: ap.AppearanceState, centre: np.ndarray, log_s: float, ex: np.ndarray
                ) -> np.ndarray:
    """(dx, dy) px of the best match of ``ex`` at log-size ``log_s`` within +-6 px of ``centre``."""
    best, arg = -2.0, np.zeros(2)
    for dy in range(-6, 7):
        for dx in range(-6, 7):
            d = np.array([dx, dy], dtype=np.float64)
            r = _ncc(ap._exemplar(feat, centre + d, log_s, st.size0, st.res), ex)
            if r > best:
                best, arg = r, d
    return arg


def _best_scale(feat: np.ndarray, st: ap.AppearanceState, centre: np.ndarray, log_true: float, ex: np.ndarray
                ) -> float:
    """Log-size, relative to ``log_true``, of the best match of ``ex`` at ``centre`` (+-2 px)."""
    grid = np.linspace(-0.3, 0.3, 25)
    scores = []
    for d_l in grid:
        scores.append(max(_ncc(ap._exemplar(feat, centre + np.array([dx, dy], dtype=np.float64), log_true + d_l,
                                            st.size0, st.res), ex)
                          for dx in (-2, 0, 2) for dy in (-2, 0, 2)))
    return float(grid[int(np.argmax(scores))])


def measure(folder: Path, every: int, segments: list[int]) -> list[list[str]]:
    """One row per segment of frames: the tracker's and each exemplar's place and scale off the annotation."""
    frames = sorted((folder / "frames").glob("*"))
    truth = np.loadtxt(folder / "groundtruth.csv", delimiter=",", skiprows=1)
    gt = {int(r[0]): r[1:5] for r in truth}
    tracker = Tracker("appearance", seed=1)
    tracker.init(cv2.imread(str(frames[0])), tuple(float(v) for v in gt[0]))
    seen: dict[int, dict[str, np.ndarray]] = {}
    last = segments[-1]
    for t in range(1, min(len(frames), last)):
        st = tracker.state.core  # the model the tracker brings to frame t
        img = cv2.imread(str(frames[t]))
        est = tracker.update(img)
        if t % every or t not in gt:
            if t % 50 == 0:
                print(f"  frame {t} / {last}", file=sys.stderr)
            continue
        g = gt[t]
        centre = np.array([g[0] + g[2] / 2.0, g[1] + g[3] / 2.0])
        box = np.array(est.box)
        feat = ap.features(cv2.cvtColor(img, cv2.COLOR_BGR2GRAY))
        log_est = float(np.log(box[2] / st.size0[0]))
        # the annotated box's size as a log-factor on the first box's: sqrt of the area ratio
        log_true = float(0.5 * np.log(g[2] * g[3] / (st.size0[0] * st.size0[1])))
        row = {"tracker": np.array([*(box[:2] + box[2:] / 2.0 - centre), log_est - log_true])}
        for name in EXEMPLARS:
            ex = getattr(st, name)
            row[name] = np.array([*_best_place(feat, st, centre, log_est, ex),
                                  _best_scale(feat, st, centre, log_true, ex)])
        seen[t] = row
    out = []
    for a, b in zip(segments[:-1], segments[1:]):
        ts = [t for t in seen if a <= t < b]
        if not ts:
            continue
        cells = [f"{a}-{b - 1}", str(len(ts))]
        for name in ("tracker", *EXEMPLARS):
            m = np.mean([seen[t][name] for t in ts], axis=0)
            cells.append(f"{m[0]:+.2f}, {m[1]:+.2f} / {m[2]:+.3f}")
        out.append(cells)
    return out


def main() -> int:
    ap_ = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                  epilog="prints one row per segment of frames: dx, dy (px) / log-size off the annotation")
    ap_.add_argument("--sequence", default="david_indoor", help="shared sequence (default david_indoor)")
    ap_.add_argument("--every", type=int, default=3, help="measure every N-th frame (default 3)")
    ap_.add_argument("--segments", default="0,120,240,350,480,669",
                     help="frame boundaries of the rows (default 0,120,240,350,480,669)")
    args = ap_.parse_args()
    folder = DATA / args.sequence
    if not (folder / "frames").is_dir():
        print(f"bench_anchor_drift: no sequence at {folder} (set GFLOW_DATA)", file=sys.stderr)
        return 2
    if args.every < 1:
        print("bench_anchor_drift: --every must be at least 1", file=sys.stderr)
        return 2
    try:
        segments = [int(v) for v in args.segments.split(",")]
    except ValueError:
        print(f"bench_anchor_drift: --segments {args.segments!r}: not comma-separated frame numbers", file=sys.stderr)
        return 2
    if len(segments) < 2 or sorted(segments) != segments:
        print("bench_anchor_drift: --segments needs at least two increasing frame numbers", file=sys.stderr)
        return 2
    rows = measure(folder, args.every, segments)
    print(f"{args.sequence}: offset of the best match from the annotated box, dx, dy px / log-size "
          f"(one frame in {args.every})")
    print(table(rows, ["frames", "n", "tracker's estimate", "first box (anchor)", "running exemplar", "slow exemplar"]))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
