"""Frames per second of G-flow's propose + update on synthetic 320x240 frames.

Run: ``python bench/bench_gflow_core.py [--frames N] [--experts 1,20,100]``

For each number of experts and with the background model off and on, it renders a
synthetic sequence (:mod:`gflow_core.gflow.synthetic_head`), initialises the experts from the
first frame, runs two untimed warm-up frames (the first touch of new memory is slow),
then times ``propose`` + ``update`` (via ``step``) over ``--frames`` frames (rendering
is not timed). It also prints the size of the expert state, the peak memory allocated
by numpy during one more step (``tracemalloc``, state included) and the mean tracking
error over the timed frames.
"""

from __future__ import annotations

import argparse
import time
import tracemalloc

import numpy as np

from gflow_core.gflow import paper_config, fit_head_model_to_box, init_state, step
from gflow_core.gflow.geometry import rotation_angle_deg
from gflow_core.gflow.synthetic_head import synthetic_sequence


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=20, help="frames per run (default 20)")
    ap.add_argument("--experts", default="1,20,100", help="comma-separated expert counts")
    ap.add_argument("--samples", type=int, default=paper_config().n_samples, help="samples per expert")
    args = ap.parse_args()
    rng = np.random.default_rng(2024)
    warm = 2
    seq = synthetic_sequence(rng, warm + args.frames + 2, (240, 320))
    model, pose0 = fit_head_model_to_box(seq.box, (240, 320))
    print(
        f"320x240, n={model.n_vertices} vertices, s={args.samples} samples/expert, "
        f"{paper_config().gn_iterations} Gauss-Newton iterations, {args.frames} timed frames per run"
    )
    print(
        f"{'experts':>8} {'background':>10} {'ms/frame':>9} {'frames/s':>9} {'rot err':>8} {'px err':>7} "
        f"{'state MB':>9} {'peak MB':>8}"
    )
    for E in (int(v) for v in args.experts.split(",")):
        for bg in (False, True):
            cfg = paper_config(n_experts=E, n_samples=args.samples, background=bg)
            state = init_state(model, pose0, seq.frames[0], cfg)
            for t in range(1, warm + 1):
                state, _ = step(state, seq.frames[t], model, cfg, seed=7, t=t)
            errs = []
            t0 = time.perf_counter()
            for t in range(warm + 1, warm + args.frames + 1):
                state, est = step(state, seq.frames[t], model, cfg, seed=7, t=t)
                errs.append(
                    (
                        float(rotation_angle_deg(est.pose, seq.poses[t])),
                        float(np.linalg.norm(est.pose[3:5] - seq.poses[t][3:5])),
                    )
                )
            dt = (time.perf_counter() - t0) / args.frames
            arrays = (state.poses, state.tex_mean, state.tex_var, state.bg_mean, state.bg_var)
            state_mb = sum(a.nbytes for a in arrays if a is not None) / 2**20
            t = warm + args.frames + 1
            tracemalloc.start()
            tracemalloc.reset_peak()
            base = tracemalloc.get_traced_memory()[0]
            state2, _ = step(state, seq.frames[t], model, cfg, seed=7, t=t)
            peak_mb = (tracemalloc.get_traced_memory()[1] - base) / 2**20 + state_mb
            tracemalloc.stop()
            del state2
            r, p = np.mean(errs, axis=0)
            print(
                f"{E:>8} {str(bg):>10} {dt * 1e3:>9.1f} {1.0 / dt:>9.1f} {r:>8.2f} {p:>7.2f} "
                f"{state_mb:>9.1f} {peak_mb:>8.1f}"
            )


if __name__ == "__main__":
    main()
