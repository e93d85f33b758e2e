"""When a hidden target comes back, what does dcf's search see? A measurement, not a tracker.

One command: ``python bench/bench_dcf_redetect.py`` (``--case occlude-60 --seed 1 --sequences A,B
--set NAME=V``; ``--frames`` prints every frame after the window instead of the table; ``--variant
fast`` measures every frame of a variant of the footage, ``gflow benchmark --variant``'s, instead of
a stress case).

For every shared sequence (``../shared/data`` or ``GFLOW_DATA``) the stress case is derived as
``gflow benchmark --stress`` derives it (:func:`pipeline.evaluation.stress_benchmark.derive`, into
a temporary folder removed at the end) and ``dcf`` is stepped over it frame by frame with the
benchmark's random streams. On the frames from the window's end on where the target is in view
and the tracker searches for it (the target judged hidden or in doubt), the search's judgement of
a placement is split into its terms, natural logs of "visible" against "hidden"
(``gflow_core.dcf.tracker._log_joint``): the filter's distance (against the lower of the window
clutter's and the search's own clutter's densities), the colour score's, the place under the
motion prior against clutter's anywhere in the region searched, and the prior odds that a hidden
target is back. It prints, per sequence:

* searched: frames the target was in view and the search ran; best on: those whose best
  placement (the one judged) overlaps the true box (IoU > 0.5);
* the terms at the search's best placement, and at the true box's centre read at the held size
  and at the true box's size (medians over the searched frames);
* taken: the frame the search took a placement back (and whether it was on the target);
* lead: how far the best placement at the held size scores above the runner-up, the best placement
  half a box or more away from it (the filter's response), median over the searched frames whose best
  placement is on the target; and the same over every search made while the target is covered
  (visibility 0.5 or less: the stress case's window), with the share of those whose lead is at
  least the median lead on target. A lead seen mostly on the target would be evidence the
  filter's absolute score cannot give (a ratio test: the frame's best match is unique); one seen as
  often among clutter is none.

With ``--colour``, each searched frame also gets the colour score (the mean of Staple's beta over
the box) at the true centre and at the search's best placement, three ways: with the model's histograms
as they are (rho_B learnt about the box where it was tracked); with rho_B taken from the ring about that
placement in this frame (the placement's own surroundings, as DAT's surrounding model is); and with the
histograms as they were on the last frame before the window. A colour cue that refuses the target
because its model was learnt against other surroundings scores it higher the second way.

A case whose target is never the best placement needs another search; one whose target is the best
placement but whose terms add up to less than the prior's odds needs other evidence.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from _util import scratch, table  # noqa: E402

from gflow_core.dcf import model as tm  # noqa: E402
from gflow_core.dcf import tracker as T  # noqa: E402
from gflow_core.dcf.cues import may_fail  # noqa: E402
from gflow_core.dcf.histogram import ColourModel, box_mask, histograms  # noqa: E402
from gflow_core.dcf.params import DCFParams  # noqa: E402
from gflow_core.evaluation.stress import CASES  # noqa: E402
from gflow_core.tracker import FrameRng, stream_hash  # noqa: E402
from pipeline.evaluation.sequence_benchmark import find_sequences  # noqa: E402
from gflow_core.dcf.reacquire import peaks  # noqa: E402
from gflow_core.evaluation.variants import select_variant  # noqa: E402
from pipeline.evaluation.stress_benchmark import derive  # noqa: E402
from pipeline.evaluation.variant_benchmark import derive_variant  # noqa: E402

DATA = Path(__file__).resolve().parent.parent.parent / "shared" / "data"


def iou(a, b) -> float:
    ix = max(0.0, min(a[0] + a[2], b[0] + b[2]) - max(a[0], b[0]))
    iy = max(0.0, min(a[1] + a[3], b[1] + b[3]) - max(a[1], b[1]))
    u = a[2] * a[3] + b[2] * b[3] - ix * iy
    return ix * iy / u if u > 0 else 0.0


def terms(st, ds, cand, trials: float, place: float, p: DCFParams) -> tuple[float, float, float, float]:
    """(filter, colour, place, prior) log-odds of "visible" against "hidden" of a search candidate, as
    ``_judge`` adds them."""
    ms, rho = p.min_std, 1.0 - cand.r
    f = ds.target.log_pdf(max(rho, ds.target.mode(ms)), ms) - T._hidden_log_pdf(ds, rho, trials, p)
    c = 0.0
    if cand.r_colour is not None and st.ctarget.n and st.cclutter.n:
        rc = 1.0 - cand.r_colour
        eps = max(p.colour_outlier, p.search_colour_outlier)
        ct, cc = may_fail(st.ctarget, eps), may_fail(st.cclutter, eps)
        c = ct.log_pdf(max(rc, ct.mode(ms)), ms) - cc.log_pdf_min(rc, 1.0, ms)
    return f, c, place, math.log(p.reappear) - math.log(1.0 - p.reappear)


def at_truth(st, obs, p, centre: np.ndarray, log_f: float, like) -> tm.Candidate | None:
    """The candidate the search would score at ``centre``, size exp(log_f) the held one's."""
    r = tm.respond_region(st.model, obs.image, obs.grey, centre, (2.0, 2.0), st.log_s + log_f, st.geom, p)
    if r is None:
        return None
    col = None if r.colour is None else float(r.at(centre[None], "colour")[0])
    return tm.Candidate(float(r.at(centre[None], "cf")[0]), centre, log_f, like.area, col)


def colour_scores(st, obs, centre: np.ndarray, before) -> tuple[float, float, float] | None:
    """The mean of beta = rho_O / (rho_O + rho_B) over the box at ``centre`` (held size, upright, template
    pixels in the frame): with the model's rho_B, with rho_B of the ring about the box in its own window, and
    with the histograms ``before`` (a :class:`ColourModel`); None without a colour model."""
    g, col = st.geom, st.model.colour
    win = tm.window(obs.image, obs.grey, (float(centre[0]), float(centre[1])), g.template, g.k(st.log_s), g.cell,
                    st.model.colour_mode)
    if col is None or win.bins is None or win.valid is None:
        return None
    box = (g.size0[0] * g.k0[0], g.size0[1] * g.k0[1])
    own = histograms(win.bins, win.valid, box, len(col.fg))
    inside = win.bins[box_mask(win.bins.shape, box) & win.valid]

    def mean_beta(fg: np.ndarray, bg: np.ndarray) -> float:
        # beta(b) = rho_O(b) / (rho_O(b) + rho_B(b))                                  (Staple eq. 11)
        den = fg + bg
        return float(np.divide(fg, den, out=np.zeros_like(fg), where=den > 0)[inside].mean())

    return mean_beta(col.fg, col.bg), mean_beta(col.fg, own.bg), mean_beta(before.fg, before.bg)


def run(folder: Path, window: tuple[int, int], p: DCFParams, seed: int, every: bool, colour: bool = False) -> dict:
    """Step dcf over the derived sequence in ``folder``; the search's terms after ``window``."""
    frames = sorted((folder / "frames").glob("*"))
    gt = {int(r[0]): tuple(r[1:]) for r in np.loadtxt(folder / "groundtruth.csv", delimiter=",", skiprows=1)}
    # a variant of the footage has no visibility file: the target is in view on every frame
    vis = {} if not (folder / "visibility.csv").exists() else {
        int(r[0]): float(r[1]) for r in np.loadtxt(folder / "visibility.csv", delimiter=",", skiprows=1, usecols=(0, 1))}
    judged: list = []
    orig = T._log_joint

    def spy(st, ds, cand, trials, place, pp, negs=()):
        # every judgement of a search candidate goes through _log_joint (_judge's, and the search's own
        # with search_clutter): P(visible) from its two log joints
        lv, lh = orig(st, ds, cand, trials, place, pp, negs)
        judged.append((cand, ds, trials, place, T._p_visible(lv, lh)))
        return lv, lh

    leads: list[float] = []
    search = tm.search

    def spy_search(model, image, grey, hold, margin, log_s, geom, pp, log_sizes=(0.0,)):
        # the lead of the best placement at the held size over the runner-up half a box or more away
        r = tm.respond_region(model, image, grey, hold, margin, log_s, geom, pp)
        if r is not None and r.cf is not None:
            s = float(np.exp(log_s))
            pk = peaks(r.cf, (int(0.5 * geom.size0[1] * s * r.q[1]), int(0.5 * geom.size0[0] * s * r.q[0])), 2)
            if len(pk) == 2:
                leads.append(pk[0][2] - pk[1][2])
        return search(model, image, grey, hold, margin, log_s, geom, pp, log_sizes)

    T._log_joint, tm.search = spy, spy_search
    out = {"searched": 0, "best_on": 0, "best": [], "held": [], "true": [], "taken": None, "lead_on": [],
           "lead_hidden": [], "colour": []}
    try:
        st = None
        before: ColourModel | None = None
        h = stream_hash("cam0")
        for t, f in enumerate(frames):
            obs = T.TRACKER.observe(p, cv2.imread(str(f)))
            rng = FrameRng(seed, h, t)
            if st is None:
                st, _ = T.TRACKER.init(p, obs, gt[0], rng, {})
                continue
            judged.clear()
            leads.clear()
            prev = st
            if t == window[0] - 1:
                before = st.model.colour  # the colour model of the last frame before the window
            prop = T.TRACKER.propose(p, st, obs, rng)
            res = T.step(st, obs, prop.particles, p, rng.stream(T.PURPOSE_STEP), 1.0)
            st = res.state
            g = gt.get(t)
            if vis.get(t, 1.0) <= 0.5 and leads:
                out["lead_hidden"].append(leads[0])
            if t < window[1] or g is None or vis.get(t, 1.0) <= 0.5 or not judged:
                continue
            acc = [j for j in judged if j[4] >= 0.5]
            cand, ds, trials, place, v = acc[0] if acc else judged[0]
            s = float(np.exp(prev.log_s + cand.log_f))
            w, hh = prev.geom.size0[0] * s, prev.geom.size0[1] * s
            on = iou((cand.centre[0] - (w - 1) / 2, cand.centre[1] - (hh - 1) / 2, w, hh), g) > 0.5
            out["searched"] += 1
            out["best_on"] += on
            if on and leads:
                out["lead_on"].append(leads[0])
            out["best"].append(terms(prev, ds, cand, trials, place, p))
            gc = np.array([g[0] + (g[2] - 1) / 2.0, g[1] + (g[3] - 1) / 2.0])
            size = prev.geom.size0[0] * prev.geom.size0[1] * float(np.exp(2 * prev.log_s))
            row = {}
            for key, lf in (("held", 0.0), ("true", 0.5 * math.log(g[2] * g[3] / size))):
                c = at_truth(prev, obs, p, gc, lf, cand)
                if c is not None:
                    out[key].append(terms(prev, ds, c, trials, place, p)[:2])
                    row[key] = (lf, 1.0 - c.r, out[key][-1])
            if res.redetected and out["taken"] is None:
                out["taken"] = (t, on)
            cs = [colour_scores(prev, obs, c, before) for c in (gc, cand.centre)] if colour and before is not None else []
            if cs and None not in cs:
                out["colour"].append(cs)
            if every:
                fs = lambda x: " ".join(f"{y:+.1f}" for y in x)  # noqa: E731
                print(f"  {t:4d} best IoU>0.5 {on!s:5s} rho {1 - cand.r:.3f} [{fs(out['best'][-1])}] "
                      f"P {v:.3f}" + "".join(f" | {k} lf {r[0]:+.2f} rho {r[1]:.3f} [{fs(r[2])}]"
                                              for k, r in row.items()))
                if cs and None not in cs:
                    print("        colour at truth: model {:.3f} own {:.3f} before {:.3f}; at best: model {:.3f} "
                          "own {:.3f} before {:.3f}; the target's mean {:.3f}".format(
                              *cs[0], *cs[1], 1.0 - prev.ctarget.mean()))
    finally:
        T._log_joint, tm.search = orig, search
    return out


def _med(xs: list, i: int) -> str:
    return f"{np.median([x[i] for x in xs]):+.1f}" if xs else "-"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--case", default="occlude-60", help="stress case whose frames after the window are measured")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--sequences", default="", help="only these sequences (comma-separated)")
    ap.add_argument("--set", action="append", default=[], metavar="NAME=V", help="a dcf parameter")
    ap.add_argument("--frames", action="store_true", help="print every searched frame after the window")
    ap.add_argument("--colour", action="store_true", help="also the colour score at the truth and "
                                                              "at the best placement, against the model's surroundings, "
                                                              "the placement's own, and the model before the window")
    ap.add_argument("--variant", default="", help="measure every frame of this variant of the footage (fast, "
                                                  "blur, fast+blur, ...: gflow benchmark --variant) instead of --case")
    args = ap.parse_args()
    data = Path(os.environ.get("GFLOW_DATA", DATA))
    case = next((c for c in CASES if c.name == args.case), None)
    if case is None:
        print(f"bench_dcf_redetect: unknown case {args.case!r} (known: {', '.join(c.name for c in CASES)})")
        return 2
    try:
        variant = select_variant(args.variant) if args.variant else None
    except ValueError as e:
        print(f"bench_dcf_redetect: {e}")
        return 2
    if not data.is_dir():
        print(f"bench_dcf_redetect: no data at {data} (set GFLOW_DATA)")
        return 2
    p = DCFParams()
    for s in args.set:
        k, _, v = s.partition("=")
        if not hasattr(p, k):
            print(f"bench_dcf_redetect: dcf has no parameter {k!r}")
            return 2
        old = getattr(p, k)
        try:
            if isinstance(old, bool) and v not in ("true", "false"):
                raise ValueError(f"{k} is true or false, got {v!r}")
            p = replace(p, **{k: v == "true" if isinstance(old, bool) else type(old)(v)})
        except (TypeError, ValueError) as e:
            print(f"bench_dcf_redetect: --set {s}: {e}")
            return 2
    seqs, _ = find_sequences([str(data)])
    want = {s for s in args.sequences.split(",") if s}
    if want - {s.name for s in seqs}:
        print(f"bench_dcf_redetect: no sequence {', '.join(sorted(want - {s.name for s in seqs}))} in {data}")
        return 2
    tmp = scratch("gflow-dcf-redetect-")
    rows = []
    for i, seq in enumerate(seqs):
        if want and seq.name not in want:
            continue
        if variant is not None:
            folder, window = derive_variant(seq, variant, tmp / variant.name, min(seq.groundtruth), None).path, (0, 0)
        else:
            d = derive(seq, case, seqs[(i + 1) % len(seqs)], tmp, args.seed, 30, 60)
            folder, window = d.seq.path, d.plan.window
        if args.frames:
            print(seq.name)
        m = run(folder, window, p, args.seed, args.frames, args.colour)
        if m["colour"]:
            med = np.median(np.array(m["colour"]), axis=0)
            print(f"  {seq.name}: colour, medians over {len(m['colour'])} frames: at truth model {med[0][0]:.3f} own "
                  f"{med[0][1]:.3f} before {med[0][2]:.3f}; at best model {med[1][0]:.3f} own {med[1][1]:.3f} "
                  f"before {med[1][2]:.3f}")
        on = float(np.median(m["lead_on"])) if m["lead_on"] else None
        hid = m["lead_hidden"]
        taken = "-" if m["taken"] is None else f"{m['taken'][0]} ({'on' if m['taken'][1] else 'off'} target)"
        rows.append([seq.name, m["searched"], m["best_on"],
                     " ".join(_med(m["best"], k) for k in range(4)),
                     " ".join(_med(m["held"], k) for k in range(2)),
                     " ".join(_med(m["true"], k) for k in range(2)), taken,
                     "-" if on is None else f"{on:.3f}",
                     "-" if not hid else f"{np.median(hid):.3f}" + ("" if on is None else
                                                                   f" ({np.mean(np.array(hid) >= on):.2f} >= on)")])
    what = f"every frame of the {variant.name} variant" if variant is not None else \
        f"the frames after the window of {case.name}"
    print(f"dcf's search on {what} with the target in view, seed {args.seed}; "
          "medians of the log-odds terms (filter, colour[, place, prior])")
    print(table(rows, ["sequence", "searched", "best on", "at best: f c place prior", "truth, held size: f c",
                       "truth, true size: f c", "taken at", "lead on target", "lead while covered"]))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
