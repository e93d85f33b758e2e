"""M2 likelihood throughput and tracking frame rate on caviar1 (Toyama & Blake 2002, eq. 7, sec. 5.1.2).

Learns K exemplars from caviar1's ground-truth boxes (Canny edges inside each box, masked
by background subtraction; :func:`gflow_core.m2.learn.learn`), then runs the M2 particle
filter of :mod:`gflow_core.m2.tracking` (propose + weigh + posterior) on the frames and
reports:

* the time to learn the model;
* the per-frame chamfer image (Canny + distance transform), which the runtime computes
  once per frame in its preprocessing stage and which is not part of the filter step;
* likelihood evaluations per second, counted as particles x contour points sampled;
* tracking frames per second for the filter step at each particle count;
* the centre location error of the MAP box against the ground truth, for orientation.

Usage:  python bench/bench_m2_likelihood.py [--frames 120] [--K 100] [--points 150]
"""

from __future__ import annotations

import argparse
import glob
import os
import sys
import time

import numpy as np

DATA = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "shared", "data", "caviar1")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=os.environ.get("GFLOW_CAVIAR1", DATA))
    ap.add_argument("--frames", type=int, default=150, help="frames to track")
    ap.add_argument("--K", type=int, default=100, help="number of exemplars")
    ap.add_argument("--points", type=int, default=150, help="max contour points per exemplar")
    ap.add_argument("--particles", type=int, nargs="+", default=[500, 2000])
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()

    files = sorted(glob.glob(os.path.join(args.data, "frames", "*.jpg")))
    gt_path = os.path.join(args.data, "groundtruth.csv")
    if not files or not os.path.exists(gt_path):
        print(f"SKIP: caviar1 data not found under {os.path.abspath(args.data)} "
              "(expected frames/*.jpg and groundtruth.csv)")
        return 0

    import cv2

    from gflow_core.features import chamfer_image, edge_map, to_grey
    from gflow_core.m2 import tracking, training
    from gflow_core.m2.learn import learn

    frames = [cv2.imread(f) for f in files]
    gt = np.loadtxt(gt_path, delimiter=",", skiprows=1)
    boxes = np.full((len(frames), 4), np.nan)
    boxes[gt[:, 0].astype(int)] = gt[:, 1:5]
    print(f"caviar1: {len(frames)} frames {frames[0].shape[1]}x{frames[0].shape[0]}, "
          f"{int(np.isfinite(boxes[:, 0]).sum())} ground-truth boxes; numpy {np.__version__}, cv2 {cv2.__version__}, "
          f"{os.cpu_count()} CPUs")

    # ---- learning -------------------------------------------------------------------
    t0 = time.perf_counter()
    bg = training.median_background(frames)
    ts = training.curves_from_boxes(frames, boxes, background=bg, max_points=args.points)
    t1 = time.perf_counter()
    model = learn(ts, "chamfer", K=args.K, kernel="moments")
    t2 = time.perf_counter()
    ex = model.to_contour_exemplars()
    P_mean = float(ex.n_points.mean())
    print(f"training curves: {len(ts)} items in {t1 - t0:.2f} s; learn K={model.K}: {t2 - t1:.2f} s; "
          f"exemplar points: mean {P_mean:.0f}, max {ex.curves.shape[1]}")
    print(f"kernel d_k: median {np.median(model.d):.1f} (range {model.d.min():.1f}-{model.d.max():.1f}); "
          f"sigma_k median {np.median(model.sigma):.3f} px")

    # ---- per-frame features (preprocessing, not the filter step) ----------------------
    n_frames = min(args.frames, len(frames))
    t0 = time.perf_counter()
    gammas = [chamfer_image(edge_map(to_grey(f)), model.profile, model.g0) for f in frames[:n_frames]]
    t_feat = (time.perf_counter() - t0) / n_frames
    print(f"chamfer image (Canny + distance transform, {model.profile}): {t_feat * 1e3:.2f} ms/frame")

    # ---- likelihood throughput and tracking fps --------------------------------------
    print(f"\n{'particles':>9} {'weigh ms':>9} {'Mpts/s':>8} {'propose':>8} {'posterior':>9} {'step ms':>8} "
          f"{'fps':>6} {'CLE px':>7}")
    for n in args.particles:
        rng = np.random.default_rng([args.seed, n])
        first = int(np.nonzero(np.isfinite(boxes[:, 0]))[0][0])
        alpha0 = model.alpha_from_box(tuple(boxes[first]))
        cloud = tracking.init_particles(alpha0, int(np.argmax(model.pi)), n, np.array([2.0, 2.0, 0.02, 0.03]), rng)
        cloud = tracking.ParticleCloud(cloud.alpha, rng.integers(0, model.K, n), cloud.log_w)
        t_prop = t_weigh = t_post = 0.0
        n_pts = 0
        errs = []
        for t in range(first + 1, n_frames):
            a = time.perf_counter()
            prop = tracking.propose(cloud, ex, rng)
            b = time.perf_counter()
            ll, _ = tracking.weigh(prop, ex, gammas[t])
            c = time.perf_counter()
            post = tracking.posterior(prop, ll, ex.K, rng)
            d = time.perf_counter()
            t_prop += b - a
            t_weigh += c - b
            t_post += d - c
            n_pts += int(ex.n_points[prop.k].sum())
            cloud = post.resampled
            if np.isfinite(boxes[t, 0]):
                x, y, w, h = boxes[t]
                errs.append(np.hypot(post.map_alpha[0] - (x + (w - 1) / 2), post.map_alpha[1] - (y + (h - 1) / 2)))
        steps = n_frames - first - 1
        step = (t_prop + t_weigh + t_post) / steps
        print(f"{n:9d} {t_weigh / steps * 1e3:9.2f} {n_pts / t_weigh / 1e6:8.2f} {t_prop / steps * 1e3:8.2f} "
              f"{t_post / steps * 1e3:9.2f} {step * 1e3:8.2f} {1.0 / step:6.1f} {np.mean(errs):7.1f}")
        # the same weighing in one block (weigh(chunk=0)) instead of blocks of WEIGH_CHUNK particles
        reps = 20
        a = time.perf_counter()
        for t in range(reps):
            tracking.weigh(prop, ex, gammas[first + 1 + t % steps], chunk=0)
        one = (time.perf_counter() - a) / reps
        print(f"{'':9} weigh in one block: {one * 1e3:.2f} ms (blocks of {tracking.WEIGH_CHUNK}: "
              f"{t_weigh / steps * 1e3:.2f} ms)")
    print(f"\n(step = propose + weigh + posterior over {n_frames - 1} frames; Mpts/s = particles x exemplar points "
          "sampled per second in weigh; CLE = mean distance of the MAP box centre from the ground-truth centre)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
