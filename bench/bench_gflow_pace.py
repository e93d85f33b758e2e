"""G-flow at a camera's pace: david_indoor played at every k-th frame, the time between the frames
reaching the tracker (dt = k), scored with the landmark metric (README "Faces").

One command: ``python bench/bench_gflow_pace.py [--every 1,3] [--seeds 1] [--inline]``

A live camera faster than the tracker makes it skip frames; the stages then measure the time since
the frame they last saw in nominal periods (``gflow_core.tracker.time_step``) from the frames' host stamps.
To play a sequence that way, each k-th frame of ../shared/data/david_indoor is written to an MCAP
recording as a live source would record it: frames numbered 0, 1, 2, ... stamped k frame periods
(of 25 frames/s) apart, each with its Capture message naming the camera's frame (0, k, 2k, ...) and
the k - 1 frames skipped before it. ``gflow track REC.mcap --set source.clock=host`` replays it
with those stamps (as ``gflow rerun`` replays a live run): G-flow's proposals are made for dt = k
periods, and the CSV rows are the camera's frame numbers, so ``gflow eval --landmarks`` scores them
against the reference landmarks of frames 0, k, 2k, ... The printed commands are the ones run
(``OUT`` a temporary folder, removed at the end).

``--gflow-set NAME=VALUE`` (repeatable) passes a G-flow parameter to every run (``gflow track
--gflow-set``), to measure a setting at a camera's pace; ``--window A:B`` adds the landmark NME over
the frames A <= frame < B alone (default 351:405, where the face turns to profile in bright light
and comes back: most of the error at every 3rd frame); ``--size-window A:B`` gives the tracked face's
size over the reference's there (default 264:348, where the face shrinks before the turn).

``--rates`` prints instead how fast the pose changes on the data, for the pose walk's standard deviations:
the RMS change over T = 1, 3 and 12 frames of the log of the face's size and of its rotation (body frame,
about the model's x (pitch), y (yaw) and z (roll) axes), from the Procrustes fit of the built-in model's
mean shape to david_indoor's reference landmarks (frames 0-339, before the turn to profile), and of the
log size of the ground-truth boxes of every sequence whose boxes change size; beside them the rate per
period of a random walk with that change over 12 frames (``RMS(12) / sqrt(12)``: jitter of the reference
counts little there) and over the 9 periods from 3 to 12 (``sqrt((MS(12) - MS(3)) / 9)``: none of it).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from _util import gflow_sets, scratch, table  # noqa: E402

from gflow_core.gflow.landmark_error import landmark_score  # noqa: E402
from pipeline.io.recorder import McapRecorder  # noqa: E402
from gflow_msgs.messages import Capture, Frame, Header, NDArray, encode  # noqa: E402

DATA = Path(__file__).resolve().parent.parent.parent / "shared" / "data" / "david_indoor"
INIT = "169,76,46,60"
FPS = 25.0
T0 = 1_700_000_000_000_000_000  # a host clock stamp (ns)
GOAL = 0.10  # the landmark NME asked of G-flow at every 3rd frame


def derive(data: Path, k: int, out: Path, stream: str = "cam0") -> int:
    """Write every ``k``-th frame of ``data/frames`` to ``out`` as a live source records it; returns the
    number of frames written."""
    files = sorted(p for p in (data / "frames").iterdir() if p.suffix.lower() in (".jpg", ".png"))
    period = int(round(1e9 / FPS))
    rec = McapRecorder(out).open()
    try:
        for i, f in enumerate(files[::k]):
            img = cv2.imread(str(f))
            if img is None:
                raise SystemExit(f"{f}: cannot read the image")
            head = Header(stream, i, T0 + i * k * period)
            rec.write(f"gflow/{stream}/frames", encode(Frame(header=head, image=NDArray.of(img), source=f.name)), i,
                      log_ns=head.stamp_ns)
            rec.write(f"gflow/{stream}/captures",
                      encode(Capture(header=head, frame=i * k, skipped=0 if i == 0 else k - 1)), i, log_ns=head.stamp_ns)
    finally:
        rec.close()
    return len(files[::k])


def run(cmd: list[str], tmp: Path, show: bool) -> str:
    if show:
        print("$ " + " ".join(cmd).replace(str(DATA), "../shared/data/david_indoor").replace(str(tmp), "OUT"))
    out = subprocess.run(cmd, capture_output=True, text=True)
    if out.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed:\n{out.stderr}")
    return out.stdout


def window_nme(landmarks: Path, points: Path, lo: int, hi: int) -> float:
    """Mean per-frame landmark NME of the frames ``lo <= frame < hi`` scored in ``points`` (a ``--points-out``
    CSV: frame,landmark,x,y); NaN if none."""
    return landmark_score(np.load(landmarks)["landmarks"], read_points(points), frames=range(lo, hi)).nme


def read_points(points: Path) -> dict[int, dict[int, tuple[float, float]]]:
    """``{frame: {landmark: (x, y)}}`` of a ``--points-out`` CSV (frame,landmark,x,y)."""
    pts: dict[int, dict[int, tuple[float, float]]] = {}
    with open(points) as f:
        for line in f:
            row = line.strip().split(",")
            if len(row) >= 4 and row[0].isdigit():
                pts.setdefault(int(row[0]), {})[int(row[1])] = (float(row[2]), float(row[3]))
    return pts


def size_ratio(landmarks: Path, points: Path, lo: int, hi: int) -> float:
    """Mean over the frames ``lo <= frame < hi`` of the tracked face's size over the reference's: the RMS
    distance of the tracked points from their centroid over that of the same landmarks of the reference
    (1: the size is right); NaN if no frame has both."""
    pts = read_points(points)
    ref = np.load(landmarks)["landmarks"][..., :2]
    ratios = []
    for t in range(lo, min(hi, len(ref))):
        ids = [i for i in pts.get(t, {}) if np.isfinite(ref[t, i]).all()]
        if len(ids) < 3:
            continue
        a, b = np.array([pts[t][i] for i in ids]), ref[t, ids]
        ratios.append(np.sqrt(((a - a.mean(0)) ** 2).sum(1).mean() / ((b - b.mean(0)) ** 2).sum(1).mean()))
    return float(np.mean(ratios)) if ratios else float("nan")


def _rate_row(name: str, what: str, d: dict[int, np.ndarray]) -> list:
    """A row of ``--rates``: the RMS changes ``d[T]`` (mean squares, per axis) over T = 1, 3, 12 frames and
    the per-period rates of a random walk with those changes."""
    rms = {t: np.sqrt(v) for t, v in d.items()}
    fmt = (lambda v: " ".join(f"{x:.2f}" for x in np.atleast_1d(v)))
    return [name, what, fmt(rms[1]), fmt(rms[3]), fmt(rms[12]), fmt(rms[12] / np.sqrt(12.0)),
            fmt(np.sqrt(np.maximum(d[12] - d[3], 0.0) / 9.0))]


def rates() -> None:
    """``--rates``: how fast the face's size and rotation change per frame period (module docstring)."""
    from scipy.spatial.transform import Rotation

    from bench_gflow_turn import reference_rotation
    from pipeline.io.modelfile import load_model

    model = load_model(Path(__file__).resolve().parent.parent / "pipeline" / "models" / "face.npz")
    ref = np.load(DATA / "landmarks.npz")["landmarks"].astype(np.float64)[:340, model.landmarks]
    mean = model.bases[:, :, 0] - model.bases[:, :, 0].mean(0)
    rot, logs = [], []
    for p in ref:
        r = reference_rotation(p, model.bases[:, :, 0])
        rot.append(r)
        # log of the Procrustes scale: p - centre ~ s R mean
        logs.append(np.nan if r is None else np.log(np.sum((p - p.mean(0)) * (mean @ r.T)) / np.sum(mean * mean)))
    ls = np.array(logs)
    rows = []
    d_rot, d_size = {}, {}
    for t in (1, 3, 12):
        # body-frame increments r_s^T r_{s+t}, as the pose walk's rotation vector (degrees)
        inc = np.array([np.degrees(Rotation.from_matrix(rot[s].T @ rot[s + t]).as_rotvec())
                        for s in range(len(rot) - t) if rot[s] is not None and rot[s + t] is not None])
        d_rot[t] = (inc ** 2).mean(0)
        dl = 100.0 * (ls[t:] - ls[:-t])
        d_size[t] = np.mean(dl[np.isfinite(dl)] ** 2)
    rows.append(_rate_row("david_indoor landmarks 0-339", "rotation x y z, degrees", d_rot))
    rows.append(_rate_row("david_indoor landmarks 0-339", "log size, %", d_size))
    for seq in sorted(p for p in DATA.parent.iterdir() if (p / "groundtruth.csv").is_file()):
        gt = np.loadtxt(seq / "groundtruth.csv", delimiter=",", skiprows=1, ndmin=2)
        ok = (gt[:, 3] > 0) & (gt[:, 4] > 0)
        lb = np.full(int(gt[:, 0].max()) + 1, np.nan)
        lb[gt[ok, 0].astype(int)] = 50.0 * np.log(gt[ok, 3] * gt[ok, 4])  # 100 log sqrt(w h): %
        d = {}
        for t in (1, 3, 12):
            dl = lb[t:] - lb[:-t]
            dl = dl[np.isfinite(dl)]
            d[t] = np.mean(dl ** 2) if len(dl) else 0.0
        if min(d.values()) > 0:  # the MIL boxes keep one size (and are labelled every 5th frame): no rate
            rows.append(_rate_row(f"{seq.name} boxes", "log size, %", d))
    print("RMS change of the pose over T frames, and the rate per period of a random walk with it")
    print(table(rows, ["data", "of", "T = 1", "T = 3", "T = 12", "RMS(12) / sqrt 12", "sqrt((MS(12) - MS(3)) / 9)"]))


def whole_numbers(option: str, text: str, least: int) -> list[int]:
    """A comma-separated list of whole numbers >= ``least``, or a one-line exit naming ``option``."""
    try:
        values = [int(v) for v in text.split(",")]
    except ValueError:
        values = []
    if not values or min(values) < least:
        raise SystemExit(f"{option} must be whole numbers >= {least}, comma-separated, got {text!r}")
    return values


def every(k: int) -> str:
    """``every frame``, ``every 2nd frame``, ``every 3rd frame``, ``every 4th frame``, ..."""
    if k == 1:
        return "every frame"
    suffix = "th" if 10 <= k % 100 <= 20 else {1: "st", 2: "nd", 3: "rd"}.get(k % 10, "th")
    return f"every {k}{suffix} frame"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--every", default="1,3", help="play every k-th frame, for each k listed (default 1,3)")
    ap.add_argument("--seeds", default="1", help="seeds, comma-separated (default 1)")
    ap.add_argument("--inline", action="store_true", help="run the stages in one process (default: processes)")
    ap.add_argument("--gflow-set", action="append", default=[], metavar="NAME=VALUE",
                    help="a G-flow parameter for every run (gflow track --gflow-set), repeatable")
    ap.add_argument("--window", default="351:405", metavar="A:B",
                    help="also score frames A <= frame < B alone (default 351:405)")
    ap.add_argument("--size-window", default="264:348", metavar="A:B",
                    help="also give the tracked face's size over the reference's, frames A <= frame < B "
                         "(default 264:348, where the face shrinks by a third before the turn)")
    ap.add_argument("--rates", action="store_true", help="print how fast the face's size and rotation change per "
                                                           "frame period (the data's), and nothing else")
    args = ap.parse_args()
    if args.rates:
        if not DATA.is_dir():
            raise SystemExit(f"{DATA} not found: --rates needs ../shared/data/david_indoor")
        rates()
        return
    try:
        lo, hi = (int(v) for v in args.window.split(":"))
    except ValueError:
        raise SystemExit(f"--window must be A:B (two frame numbers), got {args.window!r}") from None
    try:
        slo, shi = (int(v) for v in args.size_window.split(":"))
    except ValueError:
        raise SystemExit(f"--size-window must be A:B (two frame numbers), got {args.size_window!r}") from None
    everies, seeds = whole_numbers("--every", args.every, 1), whole_numbers("--seeds", args.seeds, 0)
    gflow_sets(args.gflow_set)
    if not DATA.is_dir():
        raise SystemExit(f"{DATA} not found: this benchmark needs ../shared/data/david_indoor")
    tmp = scratch("gflow-pace-")
    rows = []
    raw: list[tuple[int, float]] = []  # (k, landmark NME) unrounded: the goal is judged on these
    for k in everies:
        rec = tmp / f"david-every{k}.mcap"
        n = derive(DATA, k, rec)
        for seed in seeds:
            boxes, points = tmp / f"d{k}-{seed}.csv", tmp / f"p{k}-{seed}.csv"
            show = seed == seeds[0]
            run(["gflow", "track", str(rec), "--tracker", "gflow", "--init", INIT, "--seed", str(seed),
                 "--set", "source.clock=host", "--out", str(boxes), "--points-out", str(points), "--no-record", "-q",
                 *(["--inline"] if args.inline else []), *(a for kv in args.gflow_set for a in ("--gflow-set", kv))],
                tmp, show)
            lm = json.loads(run(["gflow", "eval", "--landmarks", str(DATA / "landmarks.npz"), "--points", str(points),
                                 "--json"], tmp, show))
            bx = json.loads(run(["gflow", "eval", "--gt", str(DATA / "groundtruth.csv"), "--pred", str(boxes),
                                 "--json"], tmp, show))
            # the frames not played have no points nor boxes: scored over the frames played
            played = bx["frames"] - bx["missing_predictions"]
            success = bx["success_rate_0.5"] * bx["frames"] / max(played, 1)
            win = window_nme(DATA / "landmarks.npz", points, lo, hi)
            size = size_ratio(DATA / "landmarks.npz", points, slo, shi)
            raw.append((k, float(lm["nme"])))
            rows.append([k, n, seed, lm["frames"] - lm["missing"], f"{lm['nme']:.3f}", f"{win:.3f}", f"{size:.3f}",
                         f"{lm['px']:.2f}", f"{bx['cle_px']:.2f}", f"{success:.3f}"])
            print(f"  {every(k)}, seed {seed}: NME {lm['nme']:.3f}, CLE {bx['cle_px']:.2f} px", file=sys.stderr)
    sets = f", --gflow-set {' '.join(args.gflow_set)}" if args.gflow_set else ""
    print(f"\nG-flow on david_indoor at every k-th frame (dt = k), {'inline' if args.inline else 'processes'}{sets}")
    print(table(rows, ["k", "frames played", "seed", "with landmarks", "landmark NME", f"NME {lo}-{hi - 1}",
                       f"size {slo}-{shi - 1}", "landmark px", "box CLE px", "success"]))
    for k in dict.fromkeys(r[0] for r in rows):
        nme = [v for kk, v in raw if kk == k]
        if len(nme) > 1:
            # the turn is a matter of chance: over many seeds, how often a run stays within the goal
            # (judged on the unrounded figures: 0.1002 prints as 0.100 but is not within 0.10)
            print(f"{every(k)}, {len(nme)} seeds: mean landmark NME {np.mean(nme):.3f}, "
                  f"at most {GOAL} on {sum(v <= GOAL for v in nme)} of {len(nme)} "
                  f"(unrounded: {' / '.join(f'{v:.4f}' for v in nme)})")


if __name__ == "__main__":
    main()
