"""``gflow learn m2``: learn a Metric Mixture model (Toyama & Blake 2002, sec. 4) from video.

Training input (sec. 4.1, 5.1, 5.2):

* contour exemplars (``--metric chamfer``): with no ``--boxes``, the paper's pipeline: a
  median background of the training frames, background subtraction, and the Canny edges
  of the foreground; with ``--boxes GT.csv``, the edges inside each ground-truth box
  (masked by the foreground unless ``--no-background-mask``), roughly aligned by the box;
* patch exemplars (``--metric shuffle`` or ``l2``): whole frames (pre-cropped video such
  as the AVLetters mouths), or the ``--boxes`` contents, resampled to ``--patch-size``.

Several sources (``gflow learn m2 SEQ1 SEQ2 ...``) are learned as one model: one exemplar set
by k-medoids over all items, kernels over all validation items, dynamics within each
sequence; with ``--boxes`` and no file each source folder's ``groundtruth.csv`` is used, and
every sequence is cut to one common reference box (the median box over all of them).
Contour models learned from boxes also get appearance exemplars (edge-orientation patches,
:mod:`gflow_core.m2.appearance_metric`) unless ``--no-appearance``.

The model file (``pipeline.io.modelfile``, kind ``m2``) also records how the features were
made (Canny thresholds, blur, crop), so ``gflow track --tracker m2`` preprocesses alike.
"""

from __future__ import annotations

ORDER = 25

import argparse
import sys
import textwrap
import time
from pathlib import Path
from typing import TYPE_CHECKING, Callable

from pipeline.cli.commands.common import (CliError, nonnegative_float, nonnegative_int, positive_float, positive_int,
                                          range_past_note, say_notes, source_frames, whole_number)

if TYPE_CHECKING:  # numpy is imported where used: the command's options and --help need none
    import numpy as np

    from pipeline.io.datasets import FrameSequence


def parse_size(text: str) -> tuple[int, int]:
    """``"WxH"`` -> (rows, cols) = (H, W)."""
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise ValueError(f"--patch-size must look like WxH (e.g. 40x30), got {text!r}") from None
    if w < 2 or h < 2:
        raise ValueError(f"--patch-size must be at least 2x2, got {text!r}")
    return h, w


def parse_pair(text: str, name: str) -> tuple[float, float]:
    try:
        a, b = (float(v) for v in text.split(","))
    except ValueError:
        raise ValueError(f"{name} must look like LOW,HIGH (e.g. 50,150), got {text!r}") from None
    if not 0 <= a <= b:
        raise ValueError(f"{name} needs 0 <= LOW <= HIGH, got {text!r}")
    return a, b


#: the options of some metrics only, with the metrics that use them (the others would ignore them)
METRIC_OPTIONS: dict[str, tuple[str, ...]] = {
    **dict.fromkeys(("--max-points", "--canny", "--blur", "--profile", "--g0", "--threshold", "--background-frames",
                     "--no-appearance", "--no-background-mask", "--kernel-floor"), ("chamfer",)),
    "--patch-size": ("shuffle", "l2"),
    "--shuffle-radius": ("shuffle",),
}


class _Given(argparse.Action):
    """An option of :data:`METRIC_OPTIONS`: its value stored as argparse's own ``store`` does (a flag,
    ``nargs=0``: its ``const``), and the option noted in ``namespace.given``, so that one typed for a metric
    that does not use it is refused (:func:`check_metric_options`), even when typed with its default value."""

    def __call__(self, parser, namespace, values, option_string=None) -> None:
        setattr(namespace, self.dest, self.const if self.nargs == 0 else values)
        namespace.given = (*getattr(namespace, "given", ()), self.option_strings[0])


def _masked(args) -> bool:
    """Contour items cut from boxes and masked by the moving foreground (``--boxes``, no ``--no-background-mask``)."""
    return args.boxes is not None and not args.no_background_mask


#: the contour options that apply in some ways of training only: (option, whether it applies, when it does not, why)
MODE_OPTIONS: tuple[tuple[str, Callable[[argparse.Namespace], bool], str, str], ...] = (
    ("--no-appearance", lambda a: a.boxes is not None, "without --boxes",
     "appearance exemplars are learned from the boxes only, so none are learned without it"),
    ("--no-background-mask", lambda a: a.boxes is not None, "without --boxes",
     "it keeps every edge in a box, and without --boxes the training edges are those of the foreground found by "
     "background subtraction"),
    ("--threshold", lambda a: a.boxes is None or _masked(a), "with --no-background-mask",
     "it is the background subtraction's, and --no-background-mask keeps every edge in the box, the background "
     "not subtracted"),
    ("--background-frames", lambda a: a.boxes is None or _masked(a), "with --no-background-mask",
     "the background masks the edges in the boxes, which --no-background-mask leaves out"),
    ("--g0", lambda a: a.profile == "truncated", "with --profile quadratic",
     "it is the truncation level of --profile truncated, min(u^2, g0)"),
)


def check_metric_options(args) -> None:
    """Refuse an option typed that the chosen ``--metric`` does not use (``--shuffle-radius`` with chamfer,
    ``--canny`` with shuffle), or that the way of training chosen leaves unused (:data:`MODE_OPTIONS`:
    ``--no-appearance`` without ``--boxes``, ``--g0`` with the quadratic profile): the model would be learned
    without it, and nothing would say so."""
    given = getattr(args, "given", ())
    for opt in given:
        metrics = METRIC_OPTIONS[opt]
        if args.metric not in metrics:
            raise CliError(f"{opt} is an option of --metric {' / '.join(metrics)}, not of --metric {args.metric}")
    for opt, applies, when, why in MODE_OPTIONS:
        if opt in given and not applies(args):
            default = " (the default)" if opt == "--g0" and "--profile" not in given else ""
            raise CliError(f"{opt} does not apply {when}{default}: {why}")


class _Progress:
    """Prints ``learn: STAGE done/total`` on stderr, at most about twice a second per stage."""

    def __init__(self, quiet: bool) -> None:
        self.quiet = quiet
        self.t0 = time.monotonic()
        self.last: tuple[str | None, float] = (None, 0.0)

    def __call__(self, stage: str, done: int, total: int) -> None:
        if self.quiet:
            return
        now = time.monotonic()
        if stage == self.last[0] and done < total and now - self.last[1] < 0.5:
            return
        self.last = (stage, now)
        print(f"  learn: {stage:10s} {done}/{total}   ({now - self.t0:.1f} s)", file=sys.stderr, flush=True)


def _log(args, msg: str) -> None:
    if not args.quiet:
        print(msg, file=sys.stderr, flush=True)


def _box_array(path: str, index: np.ndarray) -> np.ndarray:
    """(frames, 4) boxes of the training frames ``index``, NaN where the file has none or a row of no box (the
    target absent: w or h 0, or NaN, as ``gflow eval`` reads the truth); a negative size is refused."""
    import numpy as np

    from pipeline.evaluation.scored_boxes import read_scored_boxes

    gt = read_scored_boxes(path).boxes
    boxes = np.full((index.size, 4), np.nan)
    for i, f in enumerate(index):
        if int(f) in gt:
            boxes[i] = gt[int(f)]
    if not np.isfinite(boxes[:, 0]).any():
        raise CliError(f"{path} has no box for any of the training frames {int(index[0])}..{int(index[-1])}")
    return boxes


def _sources_and_boxes(args) -> list[tuple[str, str | None]]:
    """(source, boxes CSV or None) per training sequence, from SOURCE... and --boxes [CSV...]."""
    from pipeline.cli.commands.common import refuse_same_source
    from pipeline.io.datasets import resolve_source

    sources = list(args.source)
    refuse_same_source([resolve_source(s)[1] for s in sources], sources, "source")
    boxes = args.boxes
    if boxes is None:
        return [(s, None) for s in sources]
    if not boxes:
        # --boxes as a flag: each sequence folder's groundtruth.csv
        out: list[tuple[str, str | None]] = []
        for s in sources:
            gt = Path(s) / "groundtruth.csv"
            if not gt.is_file():
                raise CliError(f"--boxes without a file needs SOURCE/groundtruth.csv; {gt} does not exist")
            out.append((s, str(gt)))
        return out
    if len(boxes) != len(sources):
        raise CliError(f"--boxes lists {len(boxes)} file(s) for {len(sources)} source(s): give one per source, or "
                       "--boxes alone to use each folder's groundtruth.csv")
    from pipeline.evaluation.scored_boxes import read_scored_boxes

    for b in boxes:  # a missing or damaged file is said before any training frame is read
        read_scored_boxes(b)
    return list(zip(sources, boxes))


def training_set(args):
    """Read the training frames and turn them into a TrainingSet; returns (set, metadata, grey frames).

    The grey frames are those of the training items, in item order (None where the items
    are not contours cut from boxes): the appearance exemplars are learned from them.
    """
    import numpy as np

    pairs = _sources_and_boxes(args)
    if len(pairs) == 1:
        return _training_set_one(args, *pairs[0], sequence=0, ref_size=None)
    from gflow_core.m2 import training

    from pipeline.io.datasets import parse_range, resolve_source

    kinds = [resolve_source(s)[0] for s, _ in pairs]
    if "avletters" in kinds:
        raise CliError("several sources: each must be a video or an image folder (AVLetters .npz files are "
                       "selected with --reps / --letters, one file at a time)")
    ref = None
    if all(b is not None for _, b in pairs):
        # one reference box for every sequence: the median box over all training frames
        start, stop = parse_range(args.frames)
        sizes = []
        for s, b in pairs:
            idx = _read_frames_of(resolve_source(s)[1], start, stop, "--frames", args.frames).frame_index
            bx = _box_array(b, idx)
            sizes.append(bx[np.isfinite(bx).all(axis=1), 2:])
        ref = np.median(np.concatenate(sizes), axis=0)
    sets, metas, greys = [], [], []
    for i, (s, b) in enumerate(pairs):
        _log(args, f"sequence {i}: {s}" + (f" (boxes {b})" if b else ""))
        ts, meta, g = _training_set_one(args, s, b, sequence=i, ref_size=ref)
        sets.append(ts)
        metas.append(meta)
        greys.append(g)
    try:
        ts = training.concat_training_sets(sets)
    except ValueError as e:
        raise CliError(f"cannot combine the training sequences: {e}") from None
    meta = dict(metas[0])
    for key in ("source", "frames"):
        meta[key] = ";".join(str(m[key]) for m in metas)
    meta["sequences"] = len(pairs)
    if any(b is not None for _, b in pairs):
        meta["boxes"] = ";".join(b or "" for _, b in pairs)
    g_all = None if any(g is None for g in greys) else [f for g in greys for f in g]
    return ts, meta, g_all


def _read_frames_of(path, start: int, stop: int | None, option: str, given: str | None, verb: str = ""):
    """:func:`pipeline.io.datasets.read_frames` of ``start:stop``; a range with no frame decoded is an error naming
    ``option`` when the user gave it (``given``), so that --frames and --background-frames are told apart. With
    ``verb`` ("learning from"), a range the user gave that runs past the source's frames is said with the frames
    read (:func:`range_past_note`): they were learned from as though the range had been there."""
    from pipeline.io.datasets import read_frames

    try:
        seq = read_frames(path, start, stop)
    except ValueError as e:
        if given:
            raise CliError(f"{option} {given}: {e}{_frames_there(path)}") from None
        raise
    n = source_frames(path) if given and verb else None
    if n:
        say_notes(range_past_note(f"{option} {given}", (start, stop), str(path), (0, n - 1),
                                  (int(seq.frame_index[0]), int(seq.frame_index[-1])), verb))
    return seq


def _frames_there(source: str | Path) -> str:
    """`` (it has 10 frames: 0..9)`` of an image folder or video whose length is known, for a range that read none
    of them ("" otherwise)."""
    n = source_frames(source)  # None for an AVLetters file: its frames are chosen by utterance, not read by range
    return f" (it has {n} frames: 0..{n - 1})" if n else ""


def _training_set_one(args, source: str, box_csv: str | None, *, sequence: int, ref_size):
    """One training sequence: (TrainingSet, metadata, grey frames of the items or None)."""
    import numpy as np

    from gflow_core.features import to_grey
    from gflow_core.m2 import training
    from gflow_core.m2.distances import METRICS

    from pipeline.io.datasets import parse_range, resolve_source

    kind, path = resolve_source(source)
    metric_kind = METRICS[args.metric].kind
    start, stop = parse_range(args.frames)
    meta: dict = {"source": str(Path(source).resolve()), "metric": args.metric}
    greys = None
    if kind == "avletters":
        if box_csv:
            raise CliError("--boxes does not apply to an AVLetters file (its frames are cropped mouths)")
        seq = _utterances(args, path)
        meta.update(reps=args.reps or "all", letters=args.letters or "all")
        if args.frames:
            keep = (seq.frame_index >= start) & (seq.frame_index < (stop if stop is not None else 1 << 62))
            idx = np.nonzero(keep)[0]
            if idx.size == 0:
                raise CliError(f"--frames {args.frames}: no frame of the utterances chosen lies in it (they span "
                               f"frames {int(seq.frame_index.min())}..{int(seq.frame_index.max())})")
            first, last = int(seq.frame_index.min()), int(seq.frame_index.max())
            seq = type(seq)(frames=[seq.frames[i] for i in idx], frame_index=seq.frame_index[idx],
                            sequence=seq.sequence[idx], labels=None if seq.labels is None else seq.labels[idx])
            # past the utterances chosen, as a range past a folder's frames is said (it was learned from silently)
            say_notes(range_past_note(f"--frames {args.frames}", (start, stop), f"{path} (the utterances chosen)",
                                      (first, last), (int(seq.frame_index.min()), int(seq.frame_index.max())),
                                      "learning from"))
    else:
        if args.reps or args.letters:
            raise CliError("--reps and --letters select AVLetters utterances; the source is not an .npz file")
        seq = _read_frames_of(path, start, stop, "--frames", args.frames, "learning from")
        for i, why in seq.skipped:  # damaged input is said even with -q (which silences progress)
            print(f"warning: frame {i} skipped: {why}", file=sys.stderr, flush=True)
    meta["frames"] = f"{int(seq.frame_index[0])}:{int(seq.frame_index[-1]) + 1}"
    meta["frame_size"] = f"{seq.frames[0].shape[1]}x{seq.frames[0].shape[0]}"  # checked by track (crop: frame)
    n = len(seq)
    _log(args, f"read {n} training frame(s) from {path} ({seq.frames[0].shape[1]}x{seq.frames[0].shape[0]})")
    if n < 2:
        raise CliError(f"a single training frame ({meta['frames']}): M2 needs a training sequence (at least 2 "
                       "frames, and more than K) to learn exemplars, kernel widths and dynamics")
    canny = parse_pair(args.canny, "--canny")
    meta.update(canny_low=canny[0], canny_high=canny[1], blur=args.blur)
    boxes = _box_array(box_csv, seq.frame_index) if box_csv else None
    if metric_kind == "curve":
        if args.background_frames:
            if kind == "avletters":
                raise CliError("--background-frames needs a video or an image folder")
            b0, b1 = parse_range(args.background_frames)
            bg = training.median_background(_read_frames_of(path, b0, b1, "--background-frames",
                                                            args.background_frames, "the background of").frames)
            meta["background_frames"] = args.background_frames
        else:
            bg = training.median_background(seq.frames)
        common = dict(max_points=args.max_points, canny_low=canny[0], canny_high=canny[1], blur=args.blur)
        if boxes is None:
            ts = training.curves_from_background(seq.frames, bg, threshold=args.threshold, first_frame=0,
                                                 sequence=sequence, **common)
            # frames were read with their source indices: put them back (runs break at gaps)
            ts = training.TrainingSet(items=ts.items, placement=ts.placement,
                                      frame_index=seq.frame_index[ts.frame_index], sequence=ts.sequence,
                                      ref_size=ts.ref_size, kind="curve")
            meta["training"] = "background"
        else:
            ts = training.curves_from_boxes(seq.frames, boxes, frame_index=seq.frame_index,
                                            background=None if args.no_background_mask else bg,
                                            threshold=args.threshold, ref_size=ref_size, sequence=sequence, **common)
            meta["training"] = "boxes"
            if args.appearance:
                at = {int(f): i for i, f in enumerate(seq.frame_index)}
                greys = [to_grey(seq.frames[at[int(f)]]) for f in ts.frame_index]
        meta["crop"] = "none"
    else:
        if boxes is None:
            shape = parse_size(args.patch_size) if args.patch_size else None
            sets = []
            for s in np.unique(seq.sequence):
                rows = np.nonzero(seq.sequence == s)[0]
                sets.append(training.patches_from_frames([seq.frames[i] for i in rows], shape,
                                                         frame_index=seq.frame_index[rows], sequence=int(s)))
            ts = training.concat_training_sets(sets)
            meta.update(training="frames", crop="frame")
        else:
            ok = np.isfinite(boxes).all(axis=1)
            if args.patch_size:
                shape = parse_size(args.patch_size)
            else:
                w, h = np.median(boxes[ok, 2:], axis=0) if ref_size is None else ref_size
                shape = (max(int(round(h)), 2), max(int(round(w)), 2))
            ts = training.patches_from_boxes(seq.frames, boxes, shape, frame_index=seq.frame_index,
                                             sequence=sequence)
            meta.update(training="boxes", crop="box")
    _log(args, f"training items: {len(ts)} {'curves' if ts.kind == 'curve' else 'patches'} "
               f"(reference size {ts.ref_size[0]:.1f} x {ts.ref_size[1]:.1f})")
    return ts, meta, greys


def parse_reps(text: str) -> list[int]:
    """``--reps 1,2`` -> [1, 2]: repetition numbers (whole, >= 1), each once. A CliError naming the option for
    anything else: ``1,x`` said Python's "invalid literal for int() with base 10: 'x'", ``1,1`` was read as 1."""
    from pipeline.app.names import comma_names

    try:
        parts = comma_names(text, "--reps")
    except ValueError as e:
        raise CliError(str(e)) from None
    bad = next((r for r in parts if not r.isdigit() or int(r) < 1), None)
    if bad is not None or not parts:
        raise CliError(f"--reps {text!r}: {bad!r} is not a repetition number (1, 2, ...)" if bad is not None
                       else f"--reps {text!r} names no repetition")
    return [int(r) for r in parts]


def _utterances(args: argparse.Namespace, path: Path) -> FrameSequence:
    """The AVLetters utterances ``--reps`` and ``--letters`` choose in the file ``path``, each repetition and letter
    (or range of letters) named checked to be in it: ``--reps 1,5`` of a file with repetitions 1 and 2 learned from
    repetition 1 without a word of 5, and ``--letters X`` said the file's repetitions, not its letters."""
    from pipeline.io.datasets import AVLetters, select_utterances

    av = AVLetters.load(path)
    reps = None if not args.reps else parse_reps(args.reps)
    held = sorted(set(av.repetitions.tolist()))
    missing = [r for r in reps or () if r not in held]
    if missing:
        raise CliError(f"--reps {args.reps}: {path} has no repetition {', '.join(map(str, missing))} (its "
                       f"repetitions: {', '.join(map(str, held))})")
    letters = sorted(set(av.letters.tolist()))
    for part, span in check_letters(args.letters) if args.letters else ():
        if not set(span) & set(letters):
            raise CliError(f"--letters {args.letters}: {path} has no utterance of {part} (its letters: "
                           f"{', '.join(letters)})")
    try:
        return select_utterances(av, reps, args.letters, where=str(path))
    except ValueError:
        there = sorted({str(a) for a, r in zip(av.letters, av.repetitions) if int(r) in (reps or held)})
        raise CliError(f"--reps {args.reps} --letters {args.letters}: {path} has no utterance of those letters in "
                       f"those repetitions (they hold letters {', '.join(there)})") from None


def check_letters(text: str) -> list[tuple[str, list[str]]]:
    """``--letters``: each letter once, a range from an earlier letter to a later one. ``A-C,B`` was read as A-C
    without a word (B in it twice), and ``Z-A`` as no letter at all ("no utterance with ... letters Z-A").
    Returns each part as typed (upper case) with the letters it names."""
    from pipeline.app.names import comma_names

    try:
        parts = comma_names(text.upper().replace(" ", ""), "--letters")
    except ValueError as e:
        raise CliError(str(e)) from None
    seen: set[str] = set()
    spans = []
    for part in parts:
        a, _, b = part.partition("-")
        if b and len(a) == len(b) == 1 and a.isalpha() and b.isalpha() and a > b:
            raise CliError(f"--letters {text!r}: {part} runs backwards; write {b}-{a}")
        span = [chr(c) for c in range(ord(a), ord(b) + 1)] if b and len(a) == len(b) == 1 else [part]
        twice = next((c for c in span if c in seen), None)
        if twice is not None:
            raise CliError(f"--letters {text!r}: {twice} is named twice; give each letter once")
        seen.update(span)
        spans.append((part, span))
    return spans


def check_values(args) -> None:
    """The frame ranges, Canny thresholds, patch size, repetitions and letters, each refused by its option's name
    before any frame is read (they were read where used, after the training video, and a range's error named
    none)."""
    from pipeline.cli.commands.common import frame_range

    for opt in ("frames", "background_frames"):
        frame_range(getattr(args, opt), f"--{opt.replace('_', '-')}")
    parse_pair(args.canny, "--canny")
    if args.patch_size:
        parse_size(args.patch_size)
    if args.reps:
        parse_reps(args.reps)
    if args.letters:
        check_letters(args.letters)


def cmd_learn(args) -> int:
    import numpy as np

    from pipeline.cli.commands.common import check_model_out, start_work

    check_metric_options(args)
    check_model_out(args.out)
    from gflow_core.m2.learn import learn

    from pipeline.io.modelfile import save_model

    if args.K < 1:
        raise CliError(f"-K must be a positive number of exemplars, got {args.K}")
    check_values(args)
    ts, meta, greys = training_set(args)
    n = len(ts)
    if args.K >= n:
        raise CliError(f"-K {args.K} exemplars but only {n} training item(s): K must be smaller than the number of "
                       "items (the items that are not exemplars are the validation set of sec. 4.2); use a smaller "
                       "-K or more frames")
    start_work()  # the options and training frames checked: a value the learning refuses is its failure (exit 1)
    if args.metric == "chamfer":
        metric_params = {"profile": args.profile, "g0": args.g0}
    elif args.metric == "shuffle":
        metric_params = {"radius": args.shuffle_radius}
    else:
        metric_params = {}
    t0 = time.monotonic()
    floor = {"kernel_floor": args.kernel_floor} if args.metric == "chamfer" else {}
    model = learn(ts, args.metric, K=args.K, kernel=args.kernel, metric_params=metric_params, frames=greys,
                  progress=_Progress(args.quiet), **floor)
    out = save_model(args.out, model, meta=meta, new=True)
    d = model.d
    print(f"learned M2 model: K={model.K} {model.metric} exemplars from {n} items in {time.monotonic() - t0:.1f} s; "
          f"d_k median {np.median(d):.1f} (range {d.min():.1f}-{d.max():.1f}), sigma_k median "
          f"{np.median(model.sigma):.3g}" + ("" if model.appearance is None else
          f"; appearance d'_k median {np.median(model.appearance.d):.1f}, sigma'_k median "
          f"{np.median(model.appearance.sigma):.3g}") + f"; written to {out}")
    return 0


def register(sub) -> None:
    p = sub.add_parser("learn", help="learn a model from training video (m2: Metric Mixture exemplars; gflow: a "
                                     "morphable face from landmarks)",
                       description="Learn a model from training data and write it to a model file (.npz).")
    ms = p.add_subparsers(dest="model_kind", metavar="MODEL", required=True)
    from pipeline.cli.commands._learn_gflow import add_parser as add_learn_gflow

    add_learn_gflow(ms)
    q = ms.add_parser(
        "m2", help="Metric Mixture exemplars, kernels and dynamics (Toyama & Blake 2002)",
        description=textwrap.fill(
            "Learn an M2 model (Toyama & Blake, IJCV 2002, sec. 4): exemplars by k-medoids under the chosen "
            "distance, the kernel parameters d_k, sigma_k of each exemplar (eq. 10 or 11), mixture weights, a "
            "Markov matrix over exemplars and an AR(1) process on the similarity transform. Progress is printed "
            "on stderr. Inspect the result with `gflow info MODEL.npz`; track with `gflow track SOURCE --tracker "
            "m2 --model MODEL.npz --init X,Y,W,H`.", 90),
        epilog="examples:\n"
               "  gflow learn m2 ../shared/data/caviar1 --boxes ../shared/data/caviar1/groundtruth.csv "
               "--frames 0:150 -K 20 --out caviar1-m2.npz\n"
               "  gflow learn m2 ../shared/data/caviar1 ../shared/data/other --boxes --frames 0:150 -K 30 "
               "--out people.npz   # two sequences, each folder's groundtruth.csv\n"
               "  gflow learn m2 walk.mp4 -K 30 --out walk.npz            # background subtraction (fixed camera)\n"
               "  gflow learn m2 ../shared/data/avletters/anya.npz --reps 1,2 --metric shuffle -K 30 "
               "--patch-size 40x30 --out mouth.npz",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    q.add_argument("source", nargs="+", help="image folder (or dataset folder with frames/), video file, or "
                   "AVLetters .npz; several sources are learned as one model (one exemplar set, dynamics within "
                   "each sequence)")
    q.add_argument("--out", required=True, metavar="MODEL.npz", help="model file to write")
    q.add_argument("--boxes", metavar="GT.csv", nargs="*",
                   help="ground-truth boxes (frame,x,y,w,h), one file per source, or no file: each source folder's "
                        "groundtruth.csv; supervised training items cut from the boxes instead of background "
                        "subtraction")
    q.add_argument("--frames", metavar="A:B", help="train on frames A <= index < B (default: all)")
    q.add_argument("--metric", choices=["chamfer", "shuffle", "l2"], default="chamfer",
                   help="distance: chamfer on edge curves (default), shuffle or l2 on grey patches")
    q.add_argument("-K", type=whole_number, default=20, help="number of exemplars (default 20)")
    q.add_argument("--kernel", choices=["moments", "mle"], default="moments",
                   help="estimator of d_k, sigma_k: moments (eq. 10, default) or MLE with integer d (eq. 11)")
    q.add_argument("--patch-size", action=_Given, metavar="WxH",
                   help="patch metrics: resample items to W x H pixels (default: frame size, or the median box size)")
    from gflow_core.m2 import edge_settings as edge
    from gflow_core.m2.kernel import CURVE_KERNEL_FLOOR

    g = q.add_argument_group("contour exemplars (chamfer)")
    g.add_argument("--max-points", action=_Given, type=positive_int, default=150,
                   help="points kept per training curve (default 150)")
    canny = f"{edge.CANNY_LOW:g},{edge.CANNY_HIGH:g}"
    g.add_argument("--canny", action=_Given, default=canny, metavar="LOW,HIGH",
                   help=f"Canny thresholds (default {canny}); gflow track --tracker m2 uses the same")
    g.add_argument("--blur", action=_Given, type=nonnegative_float, default=edge.BLUR,
                   help=f"Gaussian blur before Canny, pixels (default {edge.BLUR:g})")
    g.add_argument("--profile", action=_Given, choices=["quadratic", "truncated"], default=edge.PROFILE,
                   help=f"chamfer profile g(u): u^2 (quadratic) or min(u^2, g0) (truncated; eq. 4; default "
                        f"{edge.PROFILE})")
    g.add_argument("--g0", action=_Given, type=positive_float, default=edge.G0,
                   help=f"truncation level of the truncated profile, px^2 (default {edge.G0:g})")
    g.add_argument("--kernel-floor", action=_Given, type=nonnegative_float, default=CURVE_KERNEL_FLOOR, metavar="RHO",
                   help="a cluster whose mean validation distance is at most RHO px^2 gets the pooled kernel, as one "
                        "with too few samples does: distances that small are the pixel grid's (a small training "
                        "target), and their kernel would win every frame on another target (default "
                        f"{CURVE_KERNEL_FLOOR:g}: twice the distance between two renderings of one 16x42 px outline; "
                        "0: none, as models learned before it)")
    g.add_argument("--threshold", action=_Given, type=nonnegative_float, default=30.0,
                   help="background subtraction threshold, grey levels (default 30)")
    g.add_argument("--background-frames", action=_Given, metavar="A:B",
                   help="frames whose per-pixel median is the background (default: the training frames; a target "
                        "that barely moves in them is part of that median)")
    g.add_argument("--no-appearance", dest="appearance", action=_Given, nargs=0, const=False, default=True,
                   help="with --boxes: do not learn appearance exemplars (edge-orientation patches) beside chamfer")
    g.add_argument("--no-background-mask", action=_Given, nargs=0, const=True, default=False,
                   help="with --boxes: keep every edge in the box (default: only the moving foreground's)")
    g = q.add_argument_group("patch exemplars (shuffle, l2)")
    g.add_argument("--shuffle-radius", action=_Given, type=nonnegative_int, default=1,
                   help="shuffle neighbourhood radius r (default 1: 3x3)")
    g = q.add_argument_group("AVLetters (.npz source)")
    g.add_argument("--reps", metavar="1,2", help="repetitions to train on (default: all)")
    g.add_argument("--letters", metavar="A-Z", help="letters to train on, e.g. A-E or A,B,C (default: all)")
    q.add_argument("-q", "--quiet", action="store_true", help="no progress output")
    q.set_defaults(func=cmd_learn)
