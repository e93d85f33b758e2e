"""G-flow through david_indoor's head turn, frame by frame: the tracked head's angles against the
reference's, the landmark NME, the lost guard's verdict and the edge correlation it judges by, at the
estimate's box and at the ground-truth box (docs/faces.md "At a camera's pace").

One command: ``python bench/bench_gflow_turn.py [--every 3] [--seed 1] [--frames 290:420] [--set NAME=VALUE]
[--sequence david_indoor]``

G-flow is driven in one process through :class:`gflow_core.gflow.GFlowTracker` (observe, propose with
``dt = k``, update: the inline pipeline's calls, without its messages; so the figures are those of
one run of the tracker, not bit for bit the pipeline's), on every k-th frame of
../shared/data/david_indoor. For each frame in ``--frames`` it prints:

* the experts' mean yaw / pitch / roll (degrees, :func:`gflow_core.gflow.face_pose.yaw_pitch_roll`)
  and the reference's: the rotation of the orthogonal Procrustes fit of the model's mean shape to the
  frame's 3-D reference landmarks (MediaPipe's), NaN where the reference has no face;
* the landmark NME of the reported points (eye and mouth corners, :mod:`gflow_core.gflow.landmark_error`);
* the guard's ``target_state`` and confidence, and ``r``, the normalised correlation of the edge
  channels of the first frame's box with the estimate's box (what the guard judges by,
  :func:`gflow_core.m2.lost.observe`), with the same at the ground-truth box, and the best ``r`` of the
  clutter beside the estimate;
* G-flow's first look (:func:`gflow_core.gflow.guard.first_look_fit`): its fit at the estimate, its best
  fit beside it (:func:`gflow_core.gflow.guard.first_look_clutter`), and P(visible), P(present) of its
  misfit against the guard's distributions of it on found frames (what ``lost_witness`` judges by,
  :func:`gflow_core.gflow.guard.witnessed`, with the fit beside it).

With ``lost_guard=false`` there is no guard to judge by, so no frame's row is printed. Over every
frame tracked it also prints the fraction of vertices the frame explains as the face, as
the filter counts it whatever the guard makes of it (``inlier_fraction``, ``inlier_count`` of
:class:`gflow_core.gflow.filter.Estimate`): the expected fraction, which is the confidence without the
guard, and the hard count, the vertices in the image within ``outlier_sigmas`` standard deviations of
their texel; the median and the lowest of each, with the frame.

``--sequence NAME`` tracks another shared sequence from its first ground-truth box (``jumping``, say;
without ``landmarks.npz`` the NME and the reference's angles are NaN). ``--set NAME=VALUE``
(repeatable) sets a G-flow parameter (``self_occlusion=0.2``, say). Writes nothing.
"""

from __future__ import annotations

import argparse
import sys
import zlib
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from _util import table  # noqa: E402

from gflow_core.gflow import GFlowParams, GFlowTracker  # noqa: E402
from gflow_core.gflow import guard  # noqa: E402
from gflow_core.gflow.face_pose import yaw_pitch_roll  # noqa: E402
from gflow_core.gflow.geometry import rotation_matrices  # noqa: E402
from gflow_core.gflow.landmark_error import NORMALISING_PAIR, SCORED_LANDMARKS  # noqa: E402
from gflow_core.gflow.tracker import guard_params  # noqa: E402
from gflow_core.m2 import lost as lostmod  # noqa: E402
from gflow_core.tracker import FrameRng  # noqa: E402
from gflow_core.visibility import visibility  # noqa: E402
from pipeline.io.modelfile import load_model  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
SHARED = ROOT.parent / "shared" / "data"


def reference_rotation(ref: np.ndarray, mean_shape: np.ndarray) -> np.ndarray | None:
    """The rotation ``(3, 3)`` of the Procrustes fit ``ref ~ s R mean_shape + t`` (both ``(n, 3)``), or
    None when the reference has a NaN."""
    if not np.isfinite(ref).all():
        return None
    a, b = ref - ref.mean(0), mean_shape - mean_shape.mean(0)
    u, _, vt = np.linalg.svd(b.T @ a)
    d = np.sign(np.linalg.det(u @ vt))
    return (u @ np.diag([1.0, 1.0, d]) @ vt).T


def fit_summary(fits: list[tuple[int, float, float]]) -> str:
    """The expected fraction of vertices explained and the hard count over the frames ``(t, expected, hard)``:
    median and lowest of each, with the lowest's frame."""
    if not fits:
        return "fraction of vertices explained: no frame tracked"
    t, exp, hard = (np.array(v) for v in zip(*fits))
    i, j = int(np.argmin(exp)), int(np.argmin(hard))
    return (f"fraction of vertices explained over frames {t[0]}-{t[-1]} ({t.size} tracked): expected median "
            f"{np.median(exp):.3f}, lowest {exp[i]:.3f} (frame {t[i]}); hard count median {np.median(hard):.3f}, "
            f"lowest {hard[j]:.3f} (frame {t[j]}); frames below 0.95: {int((hard < 0.95).sum())}")


def read_sequence(folder: Path, every: int) -> tuple[list[Path], np.ndarray, np.ndarray]:
    """Every ``every``-th frame file, the ground-truth boxes (frames, 4) and the reference landmarks
    (frames, 468, 3; NaN where there is none, or for every frame without ``landmarks.npz``)."""
    files = sorted(p for p in (folder / "frames").iterdir() if p.suffix.lower() in (".jpg", ".png"))
    gt = np.loadtxt(folder / "groundtruth.csv", delimiter=",", skiprows=1)[:, 1:]
    lm = folder / "landmarks.npz"
    ref = np.load(lm)["landmarks"] if lm.is_file() else np.full((len(files), 468, 3), np.nan)
    return files[::every], gt, ref


def parse_value(default, text: str):
    """``text`` read as the type of the parameter's default."""
    if isinstance(default, bool):
        return text.lower() in ("1", "true", "yes", "on")
    return type(default)(text)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--every", type=int, default=3, help="play every k-th frame (default 3)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--frames", default="290:420", metavar="A:B", help="print frames A <= frame < B (default 290:420)")
    ap.add_argument("--set", action="append", default=[], metavar="NAME=VALUE", help="a G-flow parameter")
    ap.add_argument("--sequence", default="david_indoor", help="shared sequence (default david_indoor)")
    args = ap.parse_args()
    data = SHARED / args.sequence
    if not (data / "frames").is_dir():
        raise SystemExit(f"{data} (frames, groundtruth.csv) not found: this benchmark needs "
                         f"../shared/data/{args.sequence}")
    try:
        lo, hi = (int(v) for v in args.frames.split(":"))
    except ValueError:
        raise SystemExit(f"--frames must be A:B (two frame numbers), got {args.frames!r}") from None
    base = GFlowParams()
    changes = {}
    for kv in args.set:
        name, _, value = kv.partition("=")
        if not hasattr(base, name):
            raise SystemExit(f"--set {kv}: G-flow has no parameter {name!r}")
        changes[name] = parse_value(getattr(base, name), value)
    try:
        params = GFlowParams(**changes)
    except ValueError as e:
        raise SystemExit(f"--set: {e}") from None
    model = load_model(ROOT / "pipeline" / "models" / "face.npz")
    files, gt, ref = read_sequence(data, args.every)
    order = list(model.landmarks)
    scored = [order.index(j) for j in SCORED_LANDMARKS]
    tr, sh, state = GFlowTracker(), zlib.crc32(b"cam0"), None
    gp = guard_params(params, float(args.every))
    rows, nmes, fits = [], [], []
    for i, f in enumerate(files):
        t = i * args.every
        if t >= hi:
            break
        obs = tr.observe(params, cv2.imread(str(f)))
        rng = FrameRng(args.seed, sh, i)
        if state is None:
            state, _ = tr.init(params, obs, tuple(float(v) for v in gt[0]), rng, {"model": model})
            continue
        obs = tr.with_channels(params, tr.with_pyramid(params, obs))
        state, est = tr.update(params, state, tr.propose(params, state, obs, rng, dt=float(args.every)), obs, rng)
        fits.append((t, est.extras["inlier_fraction"], est.extras["inlier_count"]))
        pts = np.asarray(est.extras["mean_points"])
        r6 = ref[t, list(SCORED_LANDMARKS), :2]
        eye = np.linalg.norm(ref[t, NORMALISING_PAIR[0], :2] - ref[t, NORMALISING_PAIR[1], :2])
        nme = float(np.linalg.norm(pts[scored] - r6, axis=1).mean() / eye) if np.isfinite(r6).all() else np.nan
        nmes.append(nme)
        if t < lo or gp is None:
            continue
        rot = reference_rotation(ref[t, model.landmarks], model.bases[:, :, 0])
        ypr_ref = np.full(3, np.nan) if rot is None else yaw_pitch_roll(rot)
        ypr = yaw_pitch_roll(rotation_matrices(state.experts.poses)).mean(0)
        seen = lostmod.observe(obs.channels, state.anchor, tuple(est.box), gp, obs.bins)
        seen_gt = lostmod.observe(obs.channels, state.anchor, tuple(float(v) for v in gt[t]), gp, obs.bins)
        pose = np.asarray(est.extras["pose"], dtype=np.float64)
        look = guard.first_look_fit(state.experts, obs.y, state.setup.model, state.setup.cfg)(pose)
        ring = guard.first_look_clutter(state.experts, obs.y, state.setup.model, state.setup.cfg, gp.ring)(
            pose, tuple(float(v) for v in est.box))
        wv = visibility(1.0 - look, state.fit_level, state.look_clutter, gp.min_std)
        rows.append([t, "%.0f / %.0f / %.0f" % tuple(ypr), "%.0f / %.0f / %.0f" % tuple(ypr_ref), f"{nme:.3f}",
                     est.target_state, f"{est.confidence:.3f}", f"{seen.r:.3f}", f"{seen_gt.r:.3f}",
                     "-" if seen.clutter is None else f"{seen.clutter[0]:.3f}", f"{look:.3f}", f"{ring:.3f}",
                     f"{wv.visible:.3f}", f"{wv.present:.3f}"])
    sets = f", {' '.join(args.set)}" if args.set else ""
    print(f"G-flow on {args.sequence} at every {args.every}th frame, seed {args.seed}, one process{sets}")
    if rows:
        print(table(rows, ["frame", "yaw/pitch/roll", "reference", "NME", "state", "confidence", "r estimate",
                           "r truth", "r clutter", "look", "look clutter", "look P(visible)", "look P(present)"]))
    with np.errstate(all="ignore"):
        print(f"landmark NME over frames 0-{hi - 1}: {np.nanmean(nmes) if np.isfinite(nmes).any() else np.nan:.3f}")
    print(fit_summary(fits))


if __name__ == "__main__":
    main()
