"""``gflow plot FILE.mcap [--gt GT.csv] OUT.png``: error, ESS and per-stage latency against frame."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from pipeline.cli.commands.common import CliError

if TYPE_CHECKING:  # numpy is imported where used: the command's options and --help need none
    import numpy as np

ORDER = 59


def stage_latency(path: str) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per stage: (frame, latency in ms) where latency is the time from the last input that
    reached the stage's topics before an output to that output (publish times)."""
    import numpy as np

    from pipeline.io.mcap_io import iter_records
    from pipeline.recording.rerun import recorded_plan

    plan = recorded_plan(path)
    pub: dict[str, list[tuple[int, int]]] = {}
    for r in iter_records(path):
        if r.type in ("EndOfStream", "ErrorReport", "StageStatus", "Control", "Snapshot", "unknown"):
            continue
        pub.setdefault(r.topic, []).append((r.publish_ns, r.seq))
    out: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for name, sp in plan.stages.items():
        if sp.kind == "recorder" or not sp.inputs or not sp.outputs:
            continue
        ins = sorted(t for topic in sp.inputs.values() for t, _ in pub.get(topic, []))
        first_out = next(iter(sp.outputs.values()))
        outs = sorted(pub.get(first_out, []))
        if not ins or not outs:
            continue
        ins_a = np.array(ins)
        frames, lat = [], []
        for t, seq in outs:
            i = np.searchsorted(ins_a, t, side="right") - 1
            if i >= 0:
                frames.append(seq)
                lat.append((t - ins_a[i]) / 1e6)
        if frames:  # none when no input reached the stage before its outputs (a re-run's recording): no line
            out[name] = (np.array(frames), np.array(lat))
    return out


#: the largest --dpi: the figure is 10 x 9 inches, so 1000 dpi is a picture of 10000 x 9000 pixels
MAX_DPI = 1000


def dpi(text: str) -> int:
    """A resolution in dots per inch, 1 to :data:`MAX_DPI` (argparse type): 0 was refused only after the
    recording was read, and a large one ended in an out-of-memory 'internal error'."""
    import argparse

    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number of dots per inch, got {text!r}") from None
    if not 1 <= v <= MAX_DPI:
        raise argparse.ArgumentTypeError(f"must be 1-{MAX_DPI}, got {v}")
    return v


def recorded_truth(path: str):
    """The synthetic scene's truth carried by the recording, its boxes of no size (target absent) apart."""
    from pipeline.evaluation.scored_boxes import ScoredBoxes, has_size
    from pipeline.recording.results import truth_boxes

    boxes = truth_boxes(path)
    return ScoredBoxes({f: b for f, b in boxes.items() if has_size(b)},
                       frozenset(f for f, b in boxes.items() if not has_size(b)))


def error_series(seqs: list[int], truth, boxes: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The centre error to plot: (frames, error in px, miss), each (F,), over the frames from the first to the last
    estimate (``seqs``, sorted) that have a row of truth (``truth``, :class:`ScoredBoxes`; a frame of the estimates
    without one is not in the series). The error is NaN, a gap in the line rather than a line drawn straight across,
    where the target is absent (a truth row of no size, left out as ``gflow eval`` leaves it out) and where there is
    no estimate or one of no size (``boxes``: box by frame; ``miss`` True there: a miss, out of the mean)."""
    import numpy as np

    from gflow_core.evaluation.metrics import centre_error

    from pipeline.evaluation.scored_boxes import has_size

    lo, hi = (seqs[0], seqs[-1]) if seqs else (0, -1)
    frames = np.array(sorted(f for f in truth.boxes.keys() | truth.empty if lo <= f <= hi), dtype=np.int64)
    shown = np.array([f in truth.boxes for f in frames], dtype=bool)
    hit = np.array([f in truth.boxes and f in boxes and has_size(boxes[f]) for f in frames], dtype=bool)
    err = np.full(len(frames), np.nan)
    if hit.any():
        err[hit] = centre_error(np.array([truth.boxes[f] for f in frames[hit]]),
                                np.array([boxes[f] for f in frames[hit]]))
    return frames, err, shown & ~hit


def _error_panel(ax, seqs: list[int], truth, est: dict) -> str:
    """Plot the centre error (:func:`error_series`): a gap in the line where the target is absent or the estimate
    missing or of no size (w or h <= 0, or NaN: a miss, out of the mean). Returns the panel's title."""
    import numpy as np

    frames, err, miss = error_series(seqs, truth, {s: e.box for s, e in est.items()})
    ax.plot(frames, err, lw=1.2, color="C3")
    ok = np.isfinite(err)
    alone = ok & ~np.r_[False, ok[:-1]] & ~np.r_[ok[1:], False]  # a frame between two gaps: no line, so a dot
    if alone.any():
        ax.plot(frames[alone], err[alone], ".", ms=3, color="C3")
    absent = int((~ok & ~miss).sum())
    said = [f"no box (a miss) on {int(miss.sum())}"] if miss.any() else []
    said += [f"target absent on {absent}, left out"] if absent else []
    mean = f"mean {np.nanmean(err):.2f} px over {int(ok.sum())} frames" if ok.any() else "no box on any frame"
    return f"centre location error ({mean}" + "".join(f"; {t}" for t in said) + ")"


def cmd_plot(args) -> int:
    from pipeline.cli.commands.common import check_new_picture, check_outputs

    # the output is checked before matplotlib is imported (a second of CPU), so a mistyped --out fails at once
    if Path(args.out).is_dir():
        check_outputs(OUT=args.out)  # says it is a folder
    out = args.out if Path(args.out).suffix else args.out + ".png"
    check_new_picture(out)

    import numpy as np

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from pipeline.evaluation.scored_boxes import read_scored_boxes
    from pipeline.recording.results import estimates

    if Path(out).suffix.lower().lstrip(".") not in plt.gcf().canvas.get_supported_filetypes():
        raise CliError(f"{args.out}: matplotlib cannot write {Path(out).suffix!r} files (use .png, .svg or .pdf)")
    plt.close("all")
    from pipeline.cli.commands.common import warn_if_torn

    warn_if_torn(args.file)
    est = estimates(args.file)
    if not est:  # a damaged or torn file says where it ends, so the cut is not taken for what the run recorded
        from pipeline.io.mcap_io import damage_cause, torn_cause

        why = damage_cause(args.file) or torn_cause(args.file)
        raise CliError(f"{args.file} has no estimates to plot" + (f": {why}" if why else ""))
    truth = read_scored_boxes(args.gt) if args.gt else recorded_truth(args.file)  # damage said before plotting
    gt = truth.boxes
    seqs = sorted(est)
    fig, axes = plt.subplots(3, 1, figsize=(10, 9), sharex=True)
    ax = axes[0]
    both = [s for s in seqs if s in gt]
    absent = [s for s in seqs if s in truth.empty]  # frames with the target absent: left out
    if args.gt and not (both or absent):  # a plot of no error at all would pass for one of a run without ground truth
        given = gt.keys() | truth.empty
        raise CliError(f"--gt {args.gt}: none of its frames ({min(given)}..{max(given)}) is a frame of the estimates "
                       f"of {args.file} ({seqs[0]}..{seqs[-1]}); are the frame numbers aligned?")
    if both:
        ax.set_title(_error_panel(ax, seqs, truth, est))
    elif absent:
        ax.set_title(f"centre location error: the target is absent on every frame with ground truth ({len(absent)})")
    else:
        ax.set_title("centre location error: no ground truth (give --gt GT.csv)")
    ax.set_ylabel("CLE (px)")
    ax.grid(alpha=0.3)
    ax = axes[1]
    ess = np.array([est[s].ess for s in seqs])
    n = np.array([e.n if hasattr(e, "n") else e.log_credibility.array().size for e in (est[s] for s in seqs)], float)
    ax.plot(seqs, ess / n, lw=1.2, color="C0")
    coast = [s for s in seqs if est[s].state == "coast"]
    if coast:
        ax.plot(coast, [0.02] * len(coast), "|", color="k", label="coasting (no usable image)")
        ax.legend(loc="upper right")
    ax.set_ylabel("ESS / N")
    ax.set_ylim(0, 1.05)
    ax.set_title("effective sample size before resampling")
    ax.grid(alpha=0.3)
    _latency_panel(axes[2], args.file)
    fig.suptitle(Path(args.file).name)
    fig.tight_layout()
    from pipeline.io.recording_files import save_figure_new

    save_figure_new(fig, out, args.dpi)  # beside its name, moved there whole (an SVG cut short was left as OUT)
    print(f"wrote {out}")
    from pipeline.cli.commands.common import partial_if_damaged

    return partial_if_damaged(args.file, "plot", out)


def _latency_panel(ax, path: str) -> None:
    """The per-stage latency panel: a line per stage whose input and output topics are both in the recording,
    or a title saying there is none (a recording kept with --record-topics: matplotlib's "No artists with
    labels found to put in legend" warning, file and line, was printed under the command's answer)."""
    import numpy as np

    lines = stage_latency(path)
    for name, (f, lat) in lines.items():
        ax.plot(f, lat, lw=1.0, label=f"{name} (median {np.median(lat):.1f} ms)")
    ax.set_ylabel("latency (ms)")
    ax.set_xlabel("frame")
    ax.grid(alpha=0.3)
    if not lines:
        ax.set_title("per-stage latency: none to show (no stage has both its input and output topics recorded)")
        return
    ax.set_yscale("log")
    ax.set_title("per-stage latency: last input to output (publish times)")
    ax.legend(loc="upper right", fontsize=8)


def register(sub) -> None:
    p = sub.add_parser("plot", help="plot error, ESS and per-stage latency of a recording against frame",
                       description="Three panels against the frame index: the centre location error against ground "
                                   "truth, the effective sample size (with the frames where the filter coasted), and "
                                   "each stage's latency from its last input to its output.",
                       epilog="example: gflow plot run.mcap --gt ../shared/data/caviar1/groundtruth.csv plot.png")
    p.add_argument("file", help="MCAP recording")
    p.add_argument("out", help="output image: .png, .svg or .pdf (no suffix: .png is added)")
    p.add_argument("--gt", help="ground truth CSV (default: the synthetic scene's truth, if recorded). A row with w or "
                                "h 0, or NaN, marks the target absent: that frame is left out; an estimate of no "
                                "size is a miss (a gap in the line); a negative width or height is an error naming "
                                "the line")
    p.add_argument("--dpi", type=dpi, default=100, help=f"resolution of a PNG in dots per inch, 1-{MAX_DPI} "
                                                         "(default 100)")
    p.set_defaults(func=cmd_plot)
