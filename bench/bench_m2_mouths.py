"""Mouth tracking with patch exemplars (Toyama & Blake 2002, sec. 5.2), on AVLetters.

One command:  python bench/bench_m2_mouths.py [--speaker anya] [-K 30] [--patch-size WxH]

1. ``gflow learn m2 avletters/SPEAKER.npz --reps 1,2 --metric shuffle -K 30`` and the same
   with ``--metric l2`` (the paper's ml2 comparison): exemplars, d_k, sigma_k, Markov matrix;
2. repetition 3 of every letter, written as a PNG folder, tracked with each model
   (``gflow track FOLDER --tracker m2 --model ...``): no alpha transform, the state is the
   exemplar index k (MAP per frame);
3. reports the distribution of the learned d_k (the paper: "the majority of clusters showed
   a dimensionality of d = 4 +/- 1", extremes 1.2 to 13.8, K = 30 from 210 frames), and how
   often each tracker's MAP exemplar comes from an utterance of the letter being spoken,
   how often the two trackers' exemplars are of the same letter, and the chance level
   (exemplars drawn from pi).

``--sweep K1 K2 ...`` also learns shuffle models with more exemplars (smaller clusters) and
prints the d_k distribution against the mean cluster size (cf. the paper's fig. 5).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from _m2cli import DATA, gflow  # noqa: E402
from _util import scratch, table  # noqa: E402


def d_summary(d: np.ndarray) -> str:
    q = np.percentile(d, [0, 25, 50, 75, 100])
    within = float(np.mean(np.abs(d - 4.0) <= 1.0))
    return (f"min {q[0]:.1f}  q25 {q[1]:.1f}  median {q[2]:.1f}  q75 {q[3]:.1f}  max {q[4]:.1f}; "
            f"in 4 +/- 1: {100 * within:.0f}%")


def d_hist(d: np.ndarray) -> str:
    edges = [0, 2, 3, 4, 5, 6, 8, 12, 16, 24, 32, 48, 64, np.inf]
    h, _ = np.histogram(d, bins=edges)
    return "  ".join(f"[{lo:g},{hi:g}): {c}" for lo, hi, c in zip(edges[:-1], edges[1:], h) if c)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=str(DATA / "avletters"))
    ap.add_argument("--speaker", default="anya")
    ap.add_argument("-K", type=int, default=30)
    ap.add_argument("--patch-size", default="", help="WxH of the patches (default: the frames' own 80x60; the "
                                                     "learned d_k depend on it, see docs/accuracy.md)")
    ap.add_argument("--particles", type=int, default=500)
    ap.add_argument("--sweep", type=int, nargs="*", default=[], help="extra K values for the d_k sweep (shuffle)")
    args = ap.parse_args()
    src = Path(args.data) / f"{args.speaker}.npz"
    if not src.is_file():
        print(f"SKIP: AVLetters speaker file not found: {src}")
        return 0
    from pipeline.io.datasets import read_avletters, write_frames
    from pipeline.io.modelfile import load_model
    from pipeline.recording.results import estimates

    tmp = scratch("m2-mouths-")
    test, av = read_avletters(src, [3])
    folder = write_frames(tmp / "rep3", test.frames)
    train, _ = read_avletters(src, [1, 2])
    print(f"{args.speaker}: training on repetitions 1-2 ({len(train)} frames), testing on repetition 3 "
          f"({len(test)} frames, {len(set(test.labels.tolist()))} letters); patches {args.patch_size or 'native'}")
    size = ["--patch-size", args.patch_size] if args.patch_size else []
    H, W = test.frames[0].shape[:2]
    models, ks = {}, {}
    for metric in ("shuffle", "l2"):
        path = tmp / f"{metric}.npz"
        _, secs = gflow("learn", "m2", str(src), "--reps", "1,2", "--metric", metric, "-K", str(args.K), *size,
                        "--out", str(path), "-q")
        print(f"  ({secs:.1f} s wall)")
        models[metric] = load_model(path)
        rec = tmp / f"track-{metric}.mcap"
        gflow("track", str(folder), "--tracker", "m2", "--model", str(path), "--init", f"0,0,{W},{H}",
              "--out", str(tmp / f"track-{metric}.csv"), "--record", str(rec), "--particles", str(args.particles), "--seed", "0", "-q")
        est = estimates(rec)
        if sorted(est) != list(range(len(test))):
            raise SystemExit(f"{metric}: expected an estimate for each of the {len(test)} frames, got {len(est)}")
        ks[metric] = np.array([est[i].k for i in range(len(test))])

    print("\nlearned kernel dimensions d_k (moments, eq. 10):")
    for metric, m in models.items():
        print(f"  {metric:8s} K={m.K}, mean cluster size {len(train) / m.K:.0f}: {d_summary(m.d)}")
        print(f"           histogram: {d_hist(m.d)}")
    for K in args.sweep:
        path = tmp / f"shuffle-K{K}.npz"
        gflow("learn", "m2", str(src), "--reps", "1,2", "--metric", "shuffle", "-K", str(K), *size,
              "--out", str(path), "-q")
        m = load_model(path)
        print(f"  shuffle  K={K}, mean cluster size {len(train) / K:.0f}: {d_summary(m.d)}")
        print(f"           histogram: {d_hist(m.d)}")

    truth = test.labels
    rows = []
    ex_letter = {}
    for metric, m in models.items():
        ex_letter[metric] = av.letter_of_frame(m.exemplar_frame)
        picked = ex_letter[metric][ks[metric]]
        # chance: an exemplar drawn from pi, independent of the frame
        chance = float(np.mean([m.pi[ex_letter[metric] == t].sum() for t in truth]))
        nk = len(np.unique(ks[metric]))
        rows.append([metric, f"{100 * np.mean(picked == truth):.1f}%", f"{100 * chance:.1f}%", nk,
                     len(set(ex_letter[metric].tolist()))])
    print("\n" + table(rows, ["tracker", "MAP exemplar of the spoken letter", "chance (k ~ pi)",
                              "exemplars used", "letters among exemplars"]))
    same = ex_letter["shuffle"][ks["shuffle"]] == ex_letter["l2"][ks["l2"]]
    print(f"\nL2 and shuffle trackers pick exemplars of the same letter on {100 * same.mean():.1f}% of the "
          f"{len(test)} frames (the same exemplar frame on "
          f"{100 * np.mean(models['shuffle'].exemplar_frame[ks['shuffle']] == models['l2'].exemplar_frame[ks['l2']]):.1f}%)")
    print(f"outputs in {tmp}, deleted at exit unless GFLOW_BENCH_KEEP=1")
    return 0


if __name__ == "__main__":
    sys.exit(main())
