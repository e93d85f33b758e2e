"""Results files: box CSVs (``frame,x,y,w,h[,confidence,state]``), visibility files and what a recording
says about tracking."""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Mapping, TypeVar

from gflow_core.params import format_value

from pipeline.io.csv_rows import FARTHEST, csv_rows
from pipeline.io.run_sessions import RunSessions

if TYPE_CHECKING:  # imported where used: reading a box file needs neither the messages, mcap nor OpenCV
    from gflow_msgs.messages import Estimate, PoseEstimate
    from pipeline.recording.edgeless import EdgelessFrames

__all__ = ["read_boxes", "read_track", "TrackRows", "write_boxes", "estimate_columns", "read_visibility",
           "write_visibility", "estimates", "run_estimates", "truth_boxes", "frame_ranges", "completeness",
           "blank_rule", "run_outcome", "RunOutcome", "renumber", "read_run", "RecordedRun"]

Box = tuple[float, float, float, float]
V = TypeVar("V")


def _box_row(p: Path, lineno: int, row: list[str], allow_nan: bool) -> tuple[int, Box]:
    try:
        frame = int(row[0])
        x, y, w, h = (float(v) for v in row[1:5])  # csv_rows gives at least five columns
    except ValueError:
        raise ValueError(f"{p}:{lineno}: not numbers: {','.join(row)}") from None
    if frame < 0:  # no source has one; in a ground truth it was scored as a frame the tracker missed
        raise ValueError(f"{p}:{lineno}: frame {frame}: frame numbers start at 0")
    box = (x, y, w, h)
    if any(math.isinf(v) for v in box):
        raise ValueError(f"{p}:{lineno}: box has inf")
    if any(abs(v) >= FARTHEST for v in box):  # its area or far corner overflowed: warnings, a wrong score, a crash
        raise ValueError(f"{p}:{lineno}: box value {max(box, key=abs):g} is beyond any image (a box's x, y, w and h "
                         f"are pixels, within +-2^31)")
    if not allow_nan and any(math.isnan(v) for v in box):
        raise ValueError(f"{p}:{lineno}: box has NaN")
    return frame, box


def box_rows(p: Path, allow_nan: bool = False):
    """(line number, row, frame, box) of every row of a boxes CSV; a frame given twice is an error
    naming both lines (the later row replaced the earlier one without a word, and was scored), and so is
    a row with more or fewer columns than the first (the first bad line named). NaN is
    an error unless ``allow_nan`` (a row of no box, :mod:`pipeline.evaluation.scored_boxes`); inf always."""
    first: dict[int, int] = {}
    for lineno, row in csv_rows(p, "frame,x,y,w,h", "box"):  # every row with the columns of the first
        frame, box = _box_row(p, lineno, row, allow_nan)
        if frame in first:
            raise ValueError(f"{p}:{lineno}: frame {frame} again (first at line {first[frame]}): one box a frame")
        first[frame] = lineno
        yield lineno, row, frame, box


def read_boxes(path: str | Path) -> dict[int, Box]:
    """Read ``frame,x,y,w,h`` rows (a header line is optional; columns after the fifth, such as
    ``confidence,state``, are not read, but every row has as many as the first). Errors name the file and line."""
    p = Path(path)
    out: dict[int, Box] = {}
    for _, _, frame, box in box_rows(p):
        out[frame] = box
    if not out:
        raise ValueError(f"{p}: no boxes")
    return out


@dataclass(frozen=True)
class TrackRows:
    """A boxes CSV with the tracker's judgement: box, confidence and target state by frame
    (confidence and state are None for a five-column file)."""

    boxes: dict[int, Box]
    confidence: dict[int, float] | None
    states: dict[int, str] | None


def read_track(path: str | Path, allow_nan: bool = False) -> TrackRows:
    """Read ``frame,x,y,w,h[,confidence,state]`` rows. A file has the two extra columns on every
    row or on none (:func:`box_rows`); a confidence outside [0, 1] or an unknown state is an error naming the line and
    column. ``allow_nan``: a row with NaN in its box is read (a row of no box, as
    :mod:`pipeline.evaluation.scored_boxes` reads it: a miss), its confidence and state too. A row of no box
    (NaN, or w or h 0) may have NaN for its confidence; a row with a box may not."""
    p = Path(path)
    boxes: dict[int, Box] = {}
    conf: dict[int, float] = {}
    states: dict[int, str] = {}
    for lineno, row, frame, box in box_rows(p, allow_nan=allow_nan):
        boxes[frame] = box
        if len(row) < 7:  # every row has the columns of the first (box_rows)
            continue
        conf[frame], states[frame] = _confidence(p, lineno, row, box), _state(p, lineno, row)
    if not boxes:
        raise ValueError(f"{p}: no boxes")
    return TrackRows(boxes, conf or None, states or None)


def _confidence(p: Path, lineno: int, row: list[str], box: Box) -> float:
    """The confidence (column 6) of a row, in [0, 1]; NaN only on a row that holds no box (NaN in x, y, w or h,
    or w or h 0: the tracker gave no box, so no confidence in one either)."""
    try:
        c = float(row[5])
    except ValueError:
        raise ValueError(f"{p}:{lineno}: confidence is not a number (column 6): {row[5]!r}") from None
    if math.isnan(c) and (any(math.isnan(v) for v in box) or box[2] == 0 or box[3] == 0):
        return c
    if not 0.0 <= c <= 1.0:  # NaN fails this too: a box with no confidence in it
        raise ValueError(f"{p}:{lineno}: confidence {row[5].strip()} is outside [0, 1] (column 6"
                         + ("; NaN only on a row of no box, NaN or w or h 0)" if math.isnan(c) else ")"))
    return c


def _state(p: Path, lineno: int, row: list[str]) -> str:
    """The target state (column 7) of a row, one of :data:`TARGET_STATES`."""
    from gflow_core.evaluation.metrics import TARGET_STATES

    s = row[6].strip()
    if s not in TARGET_STATES:
        raise ValueError(f"{p}:{lineno}: unknown state {s!r} (column 7; known: {', '.join(TARGET_STATES)})")
    return s


def write_boxes(path: str | Path, boxes: dict[int, Box], confidence: dict[int, float] | None = None,
                states: dict[int, str] | None = None, inputs: dict[int, str] | None = None,
                new: bool = False) -> None:
    """Write ``frame,x,y,w,h`` rows, and ``confidence,state`` after them when given (for every frame),
    and ``input`` after those when given (a live source: ``ok``, or ``damaged`` for a frame decoded
    from damaged data). ``new``: written under a hidden temporary name beside ``path`` and moved there once
    complete, never over a file (:func:`pipeline.io.recording_files.move_new`), so a write that fails midway
    (a full disk: an OSError naming ``path``) leaves no part of the file behind."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    if not new:
        with open(p, "w", newline="") as f:
            _write_box_rows(f, boxes, confidence, states, inputs)
        return
    from pipeline.io.recording_files import write_text_new

    write_text_new(p, lambda f: _write_box_rows(f, boxes, confidence, states, inputs))


def _write_box_rows(f, boxes: dict[int, Box], confidence: dict[int, float] | None, states: dict[int, str] | None,
                    inputs: dict[int, str] | None) -> None:
    """The rows of :func:`write_boxes` into the text file ``f``."""
    full = confidence is not None and states is not None
    w = csv.writer(f, lineterminator="\n")  # LF: a CSV reads the same on every platform and in diff
    w.writerow(["frame", "x", "y", "w", "h"] + (["confidence", "state"] if full else [])
               + (["input"] if full and inputs is not None else []))
    for k in sorted(boxes):
        extra = [f"{confidence[k]:.3f}", states[k]] if confidence is not None and states is not None else []
        if extra and inputs is not None:
            extra.append(inputs.get(k, "ok"))
        w.writerow([k, *(f"{v:.2f}" for v in boxes[k]), *extra])


def estimate_columns(est: dict[int, Any]) -> tuple[dict[int, Box], dict[int, float], dict[int, str]]:
    """Boxes, confidences and target states of estimates by frame (the CSV's columns)."""
    return ({k: v.box for k, v in est.items()}, {k: float(v.confidence) for k, v in est.items()},
            {k: v.target_state for k, v in est.items()})


def read_visibility(path: str | Path) -> tuple[dict[int, float], dict[int, bool] | None]:
    """Read ``frame,visible[,perturbed,...]`` rows: the fraction of the target in view on each
    frame and, when the file has the column, whether the frame was perturbed (0 or 1)."""
    p = Path(path)
    vis: dict[int, float] = {}
    pert: dict[int, bool] = {}
    first: dict[int, int] = {}
    for lineno, row in csv_rows(p, "frame,visible", "visibility"):  # every row with the columns of the first
        try:
            frame, v = int(row[0]), float(row[1])
            if len(row) >= 3:
                pert[frame] = bool(int(row[2]))
        except ValueError:
            raise ValueError(f"{p}:{lineno}: not numbers: {','.join(row)}") from None
        if len(row) >= 3 and row[2].strip() not in ("0", "1"):  # 2 or -1 was read as perturbed
            raise ValueError(f"{p}:{lineno}: perturbed {row[2].strip()} is not 0 or 1 (column 3)")
        if frame < 0:
            raise ValueError(f"{p}:{lineno}: frame {frame}: frame numbers start at 0")
        if not 0.0 <= v <= 1.0:
            raise ValueError(f"{p}:{lineno}: visible {row[1]} is outside [0, 1]")
        if frame in first:  # the later row would replace the earlier one without a word
            raise ValueError(f"{p}:{lineno}: frame {frame} again (first at line {first[frame]}): one row a frame")
        first[frame] = lineno
        vis[frame] = v
    if not vis:
        raise ValueError(f"{p}: no rows")
    return vis, pert or None


def write_visibility(path: str | Path, visible: dict[int, float], perturbed: dict[int, bool],
                     source: dict[int, int] | None = None) -> None:
    """Write ``frame,visible,perturbed[,source_frame]`` rows."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    with open(p, "w", newline="") as f:
        w = csv.writer(f, lineterminator="\n")  # LF: a CSV reads the same on every platform and in diff
        w.writerow(["frame", "visible", "perturbed"] + (["source_frame"] if source is not None else []))
        for k in sorted(visible):
            w.writerow([k, f"{visible[k]:.4f}", int(perturbed[k])] + ([source[k]] if source is not None else []))


def renumber(col: dict[int, V], frame_of: Mapping[int, int]) -> dict[int, V]:
    """A column by frame with each frame renamed by ``frame_of`` (a live run's camera frames), else kept."""
    return {frame_of.get(k, k): v for k, v in col.items()}


def estimates(recording: str | Path, stream: str | None = None) -> dict[int, Estimate | PoseEstimate]:
    """Every Estimate of the run's own stages in a recording, by frame (the last one wins if a
    frame repeats); those from outside the run are left out (:func:`run_estimates`)."""
    return run_estimates(recording, stream)[0]


def run_estimates(recording: str | Path, stream: str | None = None
                  ) -> tuple[dict[int, Estimate | PoseEstimate], RunSessions]:
    """:func:`estimates`, and what the recording says of the run's sessions: the messages from
    outside the run (another zenoh session on the run's estimate topic) that were left out."""
    run = read_run(recording, stream)
    return run.estimates, run.sessions


@dataclass
class RecordedRun:
    """What one reading of a finished run's recording says (:func:`read_run`)."""

    estimates: dict[int, Estimate | PoseEstimate]  # the run's own (:func:`run_estimates`)
    sessions: RunSessions
    sent: set[int]  # the frames of Frame messages on ``frames_topic``
    reported: set[int]  # the frames of ErrorReports (:func:`reported_frames` of ``errors_stream``)
    first_frame_ns: int | None  # the publish time of the first Frame message (any topic)
    last_estimate_ns: int | None  # the latest publish time of an estimate (any topic, any session)

    @property
    def tracking_seconds(self) -> float | None:
        """Wall time from the first Frame published to the last estimate (None when not both, or none
        after it): :func:`pipeline.evaluation.sequence_benchmark.tracking_seconds`."""
        first, last = self.first_frame_ns, self.last_estimate_ns
        return None if first is None or last is None or last <= first else (last - first) / 1e9


def read_run(recording: str | Path, stream: str | None = None, frames_topic: str = "",
             errors_stream: str | None = None) -> RecordedRun:
    """Everything :func:`run_outcome` and the benchmark's timing want of a recording, read in one
    pass: the file is decompressed and its CRCs checked once, not once per question (a run's
    recording holds every frame, and reading it back cost as much as a tenth of a short run).

    stream : only the estimates of this stream (:func:`run_estimates`).
    frames_topic : the topic whose Frame messages are the frames sent.
    errors_stream : the stream whose errors topic :func:`reported_frames` reads (None: any ``*/errors``).
    """
    from gflow_msgs.messages import ErrorReport, Estimate, MessageError, PoseEstimate, decode
    from pipeline.io.mcap_io import iter_records

    sessions = RunSessions()
    found: list[tuple[str, str, Estimate | PoseEstimate]] = []
    sent: set[int] = set()
    reported: set[int] = set()
    first: int | None = None
    last: int | None = None
    errors = f"gflow/{errors_stream}/errors" if errors_stream else None
    for r in iter_records(recording):
        sessions.add(r)
        if r.type == "Frame":
            first = r.publish_ns if first is None else first
            if r.topic == frames_topic:
                sent.add(r.seq)
        if r.topic.endswith("/errors") and (errors is None or r.topic == errors):
            try:
                m = decode(r.data)
            except MessageError:
                m = None
            if isinstance(m, ErrorReport):
                reported.add(m.header.seq)
        if r.type not in ("Estimate", "PoseEstimate"):
            continue
        last = r.publish_ns if last is None else max(last, r.publish_ns)
        if stream and not r.topic.startswith(f"gflow/{stream}/"):
            continue
        try:
            est = decode(r.data)
        except MessageError:
            continue
        if isinstance(est, (Estimate, PoseEstimate)):
            found.append((r.topic, r.source, est))
    out: dict[int, Estimate | PoseEstimate] = {}
    for topic, source, est in found:  # whose they are is known once the whole recording was read
        if sessions.is_own(topic, source):
            out[est.header.seq] = est
    return RecordedRun(out, sessions, sent, reported, first, last)


def truth_boxes(recording: str | Path) -> dict[int, Box]:
    """Ground-truth boxes carried by Frame messages (synthetic scenes)."""
    from gflow_msgs.messages import Frame, MessageError, decode
    from pipeline.io.mcap_io import iter_records

    out: dict[int, Box] = {}
    for r in iter_records(recording):
        if r.type != "Frame":
            continue
        try:
            m = decode(r.data)
        except MessageError:
            continue
        if isinstance(m, Frame) and m.truth is not None:
            out[m.header.seq] = m.truth  # decoded as a tuple (Box)
    return out


def frame_ranges(frames) -> str:
    """Frame numbers as compact ranges: ``3, 7-9, 12``."""
    out: list[str] = []
    fs = sorted(set(frames))
    i = 0
    while i < len(fs):
        j = i
        while j + 1 < len(fs) and fs[j + 1] == fs[j] + 1:
            j += 1
        out.append(str(fs[i]) if i == j else f"{fs[i]}-{fs[j]}")
        i = j + 1
    return ", ".join(out)


def reported_frames(recording: str | None, stream: str | None = None) -> set[int]:
    """The frames a stage reported a problem with (an ``ErrorReport`` on ``gflow/<stream>/errors``)."""
    from gflow_msgs.messages import ErrorReport, MessageError, decode
    from pipeline.io.mcap_io import iter_records

    if not recording or not Path(recording).is_file():
        return set()
    out: set[int] = set()
    for r in iter_records(recording, topics=[f"gflow/{stream}/errors"] if stream else None):
        if not r.topic.endswith("/errors"):
            continue
        try:
            m = decode(r.data)
        except MessageError:
            continue
        if isinstance(m, ErrorReport):
            out.add(m.header.seq)
    return out


def blank_rule(plan: Any) -> str:
    """Why a frame that was read held no evidence for the tracker of ``plan`` (a
    :class:`pipeline.runtime.graph.Plan`, None: not known), as :func:`completeness` says it: the rule
    of the stage that decides, read from its parameters (defaults filled in, as a plan holds them).

    * M2 with a patch model (``patch.filter``): the grey levels' standard deviation below
      ``blank_std`` (:mod:`gflow_core.m2.patch_protocol`);
    * the contour trackers (``particle.filter``, ``m2.filter``, ``chamfer.filter``): fewer edge pixels
      than ``min_edges`` (M2 sec. 5.1.2).
    """
    for name in plan.stages if plan is not None else ():
        params = plan.stage_params(name)
        if params.get("blank_std") is not None:
            std = format_value(params["blank_std"])
            return f"a grey-level standard deviation below the tracker's blank_std {std}: a blank frame"
        if params.get("min_edges") is not None:
            return f"fewer edge pixels than the tracker's min_edges {params['min_edges']}: a blank frame, M2 sec. 5.1.2"
    return "a blank frame"


def completeness(est: dict, expected: range | None, reported: set[int] | None = None,
                 edgeless: EdgelessFrames | None = None, blank: str = "a blank frame") -> list[str]:
    """Lines saying which frames have no estimate and which coasted (empty: every frame tracked).

    expected : the frames the source was to send (None: from the first to the last estimate).
    reported : the frames a stage reported a problem with (:func:`reported_frames`): a coasted frame
        among them had no usable input; one not among them was read, but held no evidence for the
        tracker: a blank frame, by the tracker's own rule (``blank``, :func:`blank_rule`).
    edgeless : of those, the frames that are not blank but have no edges at the fixed Canny
        thresholds (:func:`pipeline.recording.edgeless.edgeless_frames`), said apart with the thresholds.
    blank : what made those frames blank for the run's tracker (:func:`blank_rule` of its plan).
    """
    if expected is None:
        expected = range(min(est), max(est) + 1) if est else range(0)
    missing = [f for f in expected if f not in est]
    coasted = [f for f, e in est.items() if getattr(e, "state", "") == "coast"]
    reported = reported or set()
    bad = [f for f in coasted if f in reported]
    blanks = [f for f in coasted if f not in reported and (edgeless is None or f not in edgeless.frames)]
    dim = [f for f in coasted if f not in reported and edgeless is not None and f in edgeless.frames]
    lines = []
    if missing:
        lines.append(f"{len(missing)} frame(s) have no estimate: {frame_ranges(missing)}")
    if bad:
        lines.append(f"{len(bad)} frame(s) coasted on the dynamics (no usable input, reported in the errors): "
                     f"{frame_ranges(bad)}")
    if blanks:
        lines.append(f"{len(blanks)} frame(s) coasted on the dynamics: the frame was read but held no evidence "
                     f"({blank}): {frame_ranges(blanks)}")
    if dim and edgeless is not None:
        lines.append(f"{len(dim)} frame(s) coasted on the dynamics: the frame was read and is not blank, but has "
                     f"no edges at {edgeless.whose} Canny thresholds {edgeless.low:g}/{edgeless.high:g} (fewer edge "
                     f"pixels than the tracker's min_edges {edgeless.min_edges}: too dim or low in contrast for "
                     f"them): {frame_ranges(dim)}; set others with --set preprocess.canny_low=LOW --set "
                     f"preprocess.canny_high=HIGH (null for both: chosen from each frame's gradients)")
    return lines


@dataclass
class RunOutcome:
    """What a run tracked, whatever happened to it: the estimates by frame (from the recording
    and its segments, plus those the launcher heard that the recording lost), report lines,
    and whether the run was incomplete (and why)."""

    estimates: dict[int, Any]
    expected: range
    lines: list[str] = field(default_factory=list)
    incomplete: bool = False
    why: str = ""
    tracking_seconds: float | None = None  # from the first frame published to the last estimate (RecordedRun)


def run_outcome(recording: str | None, plan, info: dict, start: int = 0, heard: Mapping[int, Any] | None = None,
                reported: set[int] | frozenset[int] = frozenset()) -> RunOutcome:
    """Gather a finished run's estimates and say what is missing.

    ``info`` is what ``run_plan`` returns (``ok``, ``estimates`` heard live, ``restarts``, and
    ``last_sent``, the last frame the source sent). The frames expected are those the source sent
    (a truncated video sends fewer than its header says), from ``start`` to the last frame seen,
    whether or not a recording holds them. ``heard`` are the estimates taken from the run
    itself ({frame: message}; default: those of ``info["estimates"]``), kept before the
    recording's; ``reported`` the frames a stage reported a problem with, beside those the
    recording holds."""
    from gflow_msgs.messages import Estimate, MessageError, PoseEstimate, decode
    from pipeline.io.mcap_io import iter_records
    from pipeline.recording.edgeless import edgeless_frames

    src = next((s for s in plan.stages.values() if s.is_source()), None)
    topic = src.outputs.get("frames", "") if src is not None else ""
    read = read_run(recording, frames_topic=topic, errors_stream=plan.stream) if recording and Path(
        recording).is_file() else None
    est, sessions = (read.estimates, read.sessions) if read is not None else ({}, RunSessions())
    if heard is None:
        heard = {}
        for seq, payload in info.get("estimates", {}).items():
            try:
                m = decode(payload)
            except MessageError:
                continue
            if isinstance(m, (Estimate, PoseEstimate)) and m.header.seq == seq:
                heard[seq] = m
    lost = [seq for seq in heard if seq not in est]  # what the recording lost
    est.update(heard)
    if read is not None:  # the frames sent and the frames reported, from the same reading
        sent = read.sent if topic else set()
        reported = read.reported | set(reported)
    else:
        sent = ({r.seq for r in iter_records(recording, topics=[topic]) if r.type == "Frame"}
                if topic and recording else set())
        reported = reported_frames(recording, plan.stream) | set(reported)
    # the frames sent are expected even when no estimate came at all (a run whose filter failed on every frame
    # was 'tracked 0 frames' and complete, exit 0), and without a recording of them (--no-record: the last frame
    # the source said it sent; a stage that failed midway left those after its last estimate uncounted); not
    # those reported (a live stream's end is a report past it), unless nothing else says a frame was sent
    if info.get("last_sent", -1) >= start:
        sent = sent | {info["last_sent"]}
    expected = range(start, max(sent | set(est) or set(reported), default=start - 1) + 1)
    coasted = [f for f, e in est.items() if getattr(e, "state", "") == "coast" and f not in reported]
    lines = completeness(est, expected, reported, edgeless_frames(plan, coasted), blank_rule(plan)) + sessions.lines()
    if lost and recording:
        lines.append(f"{len(lost)} frame(s) missing from the recording were kept from the live stream: "
                     f"{frame_ranges(lost)}")
    for n, k in info.get("restarts", {}).items():
        kind = plan.stages[n].kind if n in plan.stages else ""
        lines.append(f"stage {n} was restarted {k} time(s)" + (
            " (the recording continues in segment files NAME.partN.mcap)" if kind == "recorder"
            else ", and resumed from its checkpoint"))
    missing = [f for f in expected if f not in est]
    incomplete = not info.get("ok", True) or bool(missing)
    why = (f"{len(missing)} frame(s) have no estimate: {frame_ranges(missing)}" if missing
           else "the pipeline did not finish cleanly" if incomplete else "")
    return RunOutcome(est, expected, lines, incomplete, why,
                      tracking_seconds=read.tracking_seconds if read is not None else None)
