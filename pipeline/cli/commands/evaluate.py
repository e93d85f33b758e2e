"""``gflow eval``: score predicted boxes against ground truth."""

from __future__ import annotations

ORDER = 30

import argparse
import json

from pipeline.cli.commands.common import CliError, frame_range, range_past_note, say_notes


def overlap_threshold(text: str) -> float:
    """An overlap (IoU) threshold, a number in [0, 1] (argparse type)."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number in [0, 1], got {text!r}") from None
    if not 0.0 <= v <= 1.0:  # NaN fails this too
        raise argparse.ArgumentTypeError(f"an overlap is in [0, 1], got {text}")
    return v


def cmd_eval_landmarks(args) -> int:
    """``--landmarks REF.npz --points P.csv``: the landmark error of tracked face points."""
    from gflow_core.gflow.landmark_error import NORMALISING_PAIR, SCORED_LANDMARKS, landmark_score

    from pipeline.io.landmarks import read_landmarks, read_points

    if args.gt or args.pred:
        raise CliError("give either --gt/--pred (boxes) or --landmarks/--points (face points), not both")
    if not (args.landmarks and args.points):
        raise CliError("--landmarks REF.npz and --points P.csv go together")
    ref = read_landmarks(args.landmarks)
    pts = read_points(args.points)
    frames, past = _reference_frames(args, ref.shape[0])
    try:
        s = landmark_score(ref, pts, frames=frames)
    except ValueError as e:
        raise CliError(f"{args.points} against {args.landmarks}: {e}") from None
    if s.frames == 0:
        raise CliError(f"{args.landmarks} has no frame with the scored landmarks" +
                       (f" in --frames {args.frames}" if args.frames else ""))
    if s.missing == s.frames:  # as for boxes: an error of NaN px over no frame is no score
        raise CliError(f"no frame has both reference landmarks ({args.landmarks}: frames 0..{ref.shape[0] - 1}) and "
                       f"tracked points ({args.points}: frames {min(pts)}..{max(pts)})"
                       + (f" in --frames {args.frames}" if args.frames else "") + "; are the frame numbers aligned?")
    say_notes(past)
    if args.json:
        print(json.dumps(s.to_json()))
    else:
        print(f"frames with reference landmarks: {s.frames} (missing points: {s.missing})")
        print(f"landmark NME (points {', '.join(map(str, SCORED_LANDMARKS))}; over the "
              f"{NORMALISING_PAIR[0]}-{NORMALISING_PAIR[1]} distance): {s.nme:.4f}")
        print(f"landmark error: {s.px:.2f} px")
    return 0


def _reference_frames(args, n: int) -> tuple[range | None, str]:
    """The frames of the ``n`` reference landmarks that ``--frames`` chooses (None: every one), and the note of a range
    that runs past them (:func:`range_past_note`; "" when none)."""
    if not args.frames:
        return None, ""
    lo, hi = frame_range(args.frames)
    frames = range(lo, n if hi is None else min(hi, n))
    if not frames:  # said by the scoring: no frame with the scored landmarks in --frames
        return frames, ""
    return frames, range_past_note(f"--frames {args.frames}", (lo, hi), args.landmarks, (0, n - 1),
                                   (frames[0], frames[-1]), "scoring")


def _chosen_truth(args, truth):
    """The ground truth of the frames ``--frames`` chooses (all without it), and the note of a range that runs past
    the truth's frames (:func:`range_past_note`; "" when none); a range holding none of them is a CliError."""
    if not args.frames:
        return truth, ""
    lo, hi = frame_range(args.frames)
    held = truth.boxes.keys() | truth.empty
    truth = truth.frames(lo, hi)
    took = truth.boxes.keys() | truth.empty
    if not took:
        raise CliError(f"no ground-truth frame in --frames {args.frames}")
    return truth, range_past_note(f"--frames {args.frames}", (lo, hi), args.gt, (min(held), max(held)),
                                  (min(took), max(took)), "scoring")


def cmd_eval(args) -> int:
    from pipeline.evaluation.scored_boxes import read_scored_boxes
    from pipeline.recording.results import read_track

    if args.landmarks or args.points:
        return cmd_eval_landmarks(args)
    if not (args.gt and args.pred):
        raise CliError("gflow eval needs --gt GT.csv --pred PRED.csv (boxes), or --landmarks REF.npz --points P.csv "
                       "(face points)")
    truth, boxes = read_scored_boxes(args.gt), read_scored_boxes(args.pred)  # damage said before any scoring
    from gflow_core.evaluation.metrics import band_text  # here: a missing or damaged file is said without numpy

    truth, past = _chosen_truth(args, truth)
    gt, pred = truth.boxes, boxes.boxes  # the rows of no box left out: absent targets, failed predictions
    absent = len(truth.empty)
    if not gt:
        raise CliError(f"{args.gt}: the target is absent (w or h <= 0, or NaN) on every ground-truth frame"
                       + (f" in --frames {args.frames}" if args.frames else "") + ": nothing to score")
    _refuse_other_frames(args, gt, boxes.boxes.keys() | boxes.empty)
    failed = len(boxes.empty & gt.keys())  # missing predictions too: overlap 0, a miss
    # the states of every row, those of no box too (NaN or w, h 0: a miss for the boxes, as read above)
    states = _state_score(args, gt, pred, read_track(args.pred, allow_nan=True)) if args.visibility else None
    s = _score(gt, pred, failed, args.threshold)
    split = _split(gt, pred)
    say_notes(past)  # once the checks are done: a mistake's error is the one line on stderr
    if args.json:
        extra: dict[str, float | int | None] = {"absent_frames": absent, "empty_predictions": failed,
                                                **{k: round(v, 4) for k, v in split.items()}}
        if s.cle != s.cle:  # no frame with both boxes: null, not JSON's missing NaN
            extra["cle_px"] = None
        print(json.dumps(dict(s.to_json(), **extra, **({"state": states.to_json()} if states else {}))))
    else:
        print(f"frames with ground truth: {s.frames} (missing predictions: {s.missing}"
              + (f", {failed} of them a box of no size" if failed else "") + ")")
        if absent:
            print(f"frames left out, the target absent: {absent} (w or h 0, or NaN, in {args.gt})")
        print(f"centre location error (CLE): {s.cle:.2f} px" if s.cle == s.cle else  # NaN: averaged over no frame
              "centre location error (CLE): none (no frame with ground truth has a predicted box)")
        print(f"mean overlap (IoU):          {s.mean_overlap:.3f}")
        print(f"success rate (IoU > {args.threshold}):   {s.success:.3f}")
        print(f"success-plot AUC:            {split['auc']:.3f} (with the true size at each centre "
              f"{split['auc_size_right']:.3f}; with the true centre, each box's size {split['auc_place_right']:.3f})")
        if states:
            print(f"state right when hidden:     {_rate(states.hidden_right, states.hidden)} (occluded or lost on "
                  f"{states.hidden_right} of {states.hidden} hidden frames, past the first 5 of each stretch)")
            print(f"state right when undisturbed: {_rate(states.shown_right, states.shown)} (tracked on "
                  f"{states.shown_right} of {states.shown} frames)")
            print(f"off the target, said tracked: {_rate(states.off_tracked, states.off)} (tracked on "
                  f"{states.off_tracked} of {states.off} frames with the target in view and IoU <= {args.threshold}; "
                  "lower is better)")
            print(f"  undisturbed, box on target:  {_rate(states.shown_on_tracked, states.shown_on)} (tracked on "
                  f"{states.shown_on_tracked} of {states.shown_on}: a miss here is a wrong state)")
            print(f"  undisturbed, box off target: {_rate(states.shown_off_hidden, states.shown_off)} (occluded or lost "
                  f"on {states.shown_off_hidden} of {states.shown_off}: the box is wrong and the state says so)")
            bands = band_text(states.to_json()["confidence_bands"])
            if bands:
                print(f"on target by confidence:     {bands} (frames with the target in view)")
    return 0


def _refuse_other_frames(args: argparse.Namespace, gt: dict, predicted: set[int]) -> None:
    """Predictions on none of the ground truth's frames (those of --frames), refused naming the frames of each file
    (as for face points): it said "no frame has both a ground-truth box and a prediction", not which frames
    either file holds, nor --frames."""
    if gt.keys() & predicted:
        return
    held = f"frames {min(predicted)}..{max(predicted)}" if predicted else "no frame"
    raise CliError(f"no frame has both a ground-truth box ({args.gt}: frames {min(gt)}..{max(gt)}) and a prediction "
                   f"({args.pred}: {held})" + (f" in --frames {args.frames}" if args.frames else "")
                   + "; are the frame numbers aligned?")


def _rate(a: int, n: int) -> str:
    return "-" if n == 0 else f"{a / n:.3f}"


def _split(gt: dict, pred: dict) -> dict[str, float]:
    """The success plot's AUC, and what it would be with each box's size right (the truth's size at its centre)
    and with its place right (its size at the truth's centre): which of the two errors costs the overlap."""
    from gflow_core.evaluation.metrics import auc, place_and_size

    place, size = place_and_size(gt, pred)
    return {"auc": auc(gt, pred), "auc_size_right": auc(gt, place), "auc_place_right": auc(gt, size)}


def _score(gt: dict, pred: dict, failed: int, threshold: float):
    """The boxes' score; a tracker that gave no box on any frame with a box of truth (each a failure) scores
    overlap 0 and success 0, its centre error undefined (NaN: averaged over no frame)."""
    from gflow_core.evaluation.metrics import TrackScore, score

    if failed and not gt.keys() & pred.keys():
        return TrackScore(frames=len(gt), cle=float("nan"), mean_overlap=0.0, success=0.0, missing=len(gt))
    return score(gt, pred, threshold=threshold)


def _state_score(args, gt: dict, pred: dict, track):
    """How often the predicted state was right, given the truth's visibility file."""
    from gflow_core.evaluation.metrics import overlaps, state_score

    from pipeline.recording.results import read_visibility

    vis, pert = read_visibility(args.visibility)  # first: a missing or damaged file is named as itself
    if track.states is None:
        raise CliError(f"{args.pred} has no state column (frame,x,y,w,h,confidence,state), so --visibility "
                       "has nothing to score")
    frames = sorted(gt)
    missing = [f for f in frames if f not in vis]
    if missing:
        raise CliError(f"{args.visibility} has no row for frame {missing[0]} of the ground truth")
    return state_score([track.states.get(f) for f in frames], [vis[f] for f in frames],
                       None if pert is None else [pert[f] for f in frames],
                       overlap=overlaps(gt, pred), threshold=args.threshold,
                       confidence=None if track.confidence is None else
                       [track.confidence.get(f, float("nan")) for f in frames], frames=frames)


def register(sub) -> None:
    from pipeline.evaluation.scored_boxes import CONVENTION

    p = sub.add_parser("eval", help="score predicted boxes (or face points) against ground truth",
                       description="Boxes (--gt, --pred): centre location error (px), mean overlap (IoU), "
                                   "success rate (IoU > 0.5) and the success plot's AUC, beside the AUC with each box's "
                                   "size made the truth's and with its centre made the truth's (which of the two errors "
                                   "costs the overlap); with --visibility, how often the reported state was "
                                   "right, how often a box off the target was still reported tracked, and how often "
                                   "the box was on the target at each level of confidence. Face points (--landmarks, "
                                   "--points): the mean distance of the eye corners "
                                   "33, 133, 362, 263 and mouth corners 61, 291 from the reference, in pixels and over "
                                   "the reference 33-263 distance (NME), over the frames with a reference. "
                                   "Boxes of no size, as OTB scores them: " + CONVENTION + ".")
    p.add_argument("--gt", help="ground truth CSV (frame,x,y,w,h; w or h 0, or NaN: the target is absent, the frame "
                                "left out)")
    p.add_argument("--pred", help="predicted CSV (frame,x,y,w,h, optionally confidence,state; w or h 0, or NaN: no "
                                  "box, a failure)")
    p.add_argument("--visibility", metavar="CSV",
                   help="frame,visible[,perturbed] of the truth (a stress sequence's visibility.csv): also report how "
                        "often the predicted state was right (occluded or lost when less than 10%% of the target is "
                        "in view, past the first 5 frames of it; tracked on undisturbed frames), how often a box off "
                        "the target was said tracked, and the share on target per band of confidence")
    p.add_argument("--landmarks", metavar="REF.npz",
                   help="reference landmarks (npz, key 'landmarks', (frames, 468, 2 or 3), NaN where none; or a "
                        "dataset folder holding landmarks.npz)")
    p.add_argument("--points", metavar="P.csv",
                   help="tracked points CSV (frame,landmark,x,y), e.g. from gflow track --points-out")
    p.add_argument("--frames", metavar="A:B",
                   help="score only frames A <= frame < B ('150:' after a run with --start 150; A alone: frame A); "
                        "by default every ground-truth frame counts and a frame with no prediction is a failure")
    p.add_argument("--threshold", type=overlap_threshold, default=0.5, help="overlap (IoU) threshold of the success rate (default 0.5)")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(func=cmd_eval)
