"""``gflow benchmark DATA --stress``: trackers on sequences derived from real ones by perturbing a window.

For every sequence folder and every stress case (:data:`gflow_core.evaluation.stress.CASES`), a derived
sequence folder is written: ``frames/`` (the original frames of the run, copied byte for byte
where the case leaves them alone), ``groundtruth.csv`` (the original truth, moved where the
image moves), ``visibility.csv`` (``frame,visible,perturbed,source_frame``: the fraction of the
target in view, whether the case changed the frame, and the original frame shown) and
``stress.json`` (the case, its window and where its image patch was cut). Where the original
truth is sparse (a box every 5th frame), the derived ``groundtruth.csv`` and ``visibility.csv``
hold the frames that show a labelled one, and only those are scored. Each derived
sequence then runs through :func:`pipeline.evaluation.sequence_benchmark.tracker_row`, the very
path of ``gflow benchmark`` and ``gflow track``, and OpenCV's CSRT and a box that never moves
are scored beside it.

Derived sequences are kept between runs under ``--stress-cache DIR``, in
``DIR/SEQUENCE/CASE-KEY`` (KEY a digest of everything they are made from, so runs that differ
in seed, lead or tail keep their own; each is written under a name of its own and renamed when
complete, so runs at the same time share it safely); without it they are written to a
temporary folder and removed.
"""

from __future__ import annotations

import hashlib
import json
import math
import shutil
import tempfile
import time
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import cv2
import numpy as np

from gflow_core.evaluation.metrics import (CONFIDENCE_BANDS, HIDDEN_BELOW, StateScore, band_json, band_text, frames_to_recover,
                                 overlaps, state_score)
from gflow_core.evaluation.stress import (CASES, COPY_KINDS, PATCH_KINDS, StressCase, StressPlan, fill_truth, occluder_size,
                               plan_case, render_frame, target_copy)

from pipeline.app import TrackPlan
from pipeline.app.names import comma_names
from pipeline.evaluation.scored_boxes import read_scored_boxes
from pipeline.io.frame_readers import folder_frames
from pipeline.recording.results import read_boxes, read_track, write_boxes, write_visibility
from pipeline.evaluation.sequence_benchmark import Row, Sequence, note

__all__ = ["StressRow", "Derived", "CaseNotBuilt", "select_cases", "derive", "check_sequences", "stress_scores", "untouched",
           "format_stress", "stress_json", "run_stress", "AFTER_GAP", "BACK_AT", "VERSION"]

#: the "after" score starts this many frames after the window ends
AFTER_GAP = 10
#: a tracker got the target back when its success after the window is at least this
BACK_AT = 0.8
#: bumped whenever a derived sequence would come out differently (invalidates caches)
VERSION = 3
#: (derived sequence, tracker name, folder for its boxes and recording) -> what
#: :func:`pipeline.evaluation.sequence_benchmark.tracker_row` runs (its boxes CSV and its plan), or why the
#: tracker is skipped on it
PlanOf = Callable[[Sequence, str, Path], "tuple[str, TrackPlan] | str"]


class CaseNotBuilt(ValueError):
    """A case that cannot be made on a sequence (``distract`` with nothing of the target in the image at the
    window's start, so no look of it to copy): :func:`run_stress` skips that case of that sequence, says so in
    one line and in the tables, and goes on with the others."""


def select_cases(text: str | None) -> list[StressCase]:
    """The cases named in ``text`` (comma-separated names or name prefixes: ``occlude`` is every
    ``occlude-*``), in the order of :data:`CASES`; None: every case. ValueError for a case named twice
    (also by a name and a prefix)."""
    if text is None:
        return list(CASES)
    want = comma_names(text, "--cases")  # a name given twice or an empty one is refused
    if not want:
        raise ValueError(f"--cases needs at least one name (known: {', '.join(c.name for c in CASES)})")
    chosen: dict[str, str] = {}  # case -> the name that chose it
    for w in want:
        hit = [c.name for c in CASES if c.name == w or c.name.startswith(w + "-") or c.kind == w]
        if not hit:
            raise ValueError(f"unknown stress case {w!r} in --cases (known: {', '.join(c.name for c in CASES)})")
        again = next((h for h in hit if h in chosen), None)
        if again is not None:  # a case and its kind (occlude-20,occlude): it was run once without a word
            raise ValueError(f"--cases {text!r}: {again} is named twice (by {chosen[again]} and by {w}); give each "
                             "case once")
        chosen.update(dict.fromkeys(hit, w))
    return [c for c in CASES if c.name in chosen]


@dataclass(frozen=True)
class Derived:
    """A derived sequence written to disk: its folder (as a :class:`Sequence`), its plan, and
    where its image patch came from."""

    seq: Sequence
    plan: StressPlan
    origin: str
    case: StressCase
    patch_from: str
    cached: bool


def _digest(*parts) -> str:
    return hashlib.sha256(json.dumps(parts, sort_keys=True, default=str).encode()).hexdigest()[:16]


def _files(seq: Sequence) -> dict[int, Path]:
    """The original image file of every frame of ``seq``."""
    return {i: f for i, f in folder_frames(seq.path / "frames") if f is not None}


@dataclass(frozen=True)
class Truth:
    """A sequence's truth for planning: ``boxes`` (N, 4) of frames ``first`` .. ``first + N - 1``,
    interpolated between labelled frames, and ``labelled`` (N,) bool."""

    first: int
    boxes: np.ndarray
    labelled: np.ndarray


def _truth(seq: Sequence, files: dict[int, Path]) -> Truth:
    """The truth from the first labelled frame to the last; every frame between needs an image."""
    gt = seq.groundtruth
    if len(gt) < 2:
        raise ValueError(f"{seq.path}: the stress benchmark needs ground-truth boxes on at least two frames")
    boxes, labelled = fill_truth(gt)
    first = min(gt)
    missing = [f for f in range(first, first + boxes.shape[0]) if f not in files]
    if missing:
        raise ValueError(f"{seq.path}: the stress benchmark needs an image for every frame from the first "
                         f"ground-truth box ({first}) to the last ({first + boxes.shape[0] - 1}); frame {missing[0]} "
                         "has none")
    return Truth(first, boxes, labelled)


def _source_key(seq: Sequence, files: dict[int, Path]) -> str:
    gt = (seq.path / "groundtruth.csv").read_bytes()
    return _digest(hashlib.sha256(gt).hexdigest(), [(i, f.name, f.stat().st_size) for i, f in sorted(files.items())])


def _cut_patch(donor: Sequence, size: tuple[int, int], avoid: set[int], rng: np.random.Generator,
               ) -> tuple[np.ndarray, str]:
    """A real image patch with the aspect of ``size`` (w, h), cut from a frame of ``donor`` away
    from its target (and from frames in ``avoid``), and a note of where it was cut."""
    files = _files(donor)
    frames = [f for f in sorted(files) if f not in avoid] or sorted(files)
    f = frames[int(rng.integers(len(frames)))]
    img = cv2.imread(str(files[f]), cv2.IMREAD_COLOR)
    if img is None:
        raise ValueError(f"{files[f]}: not a decodable image")
    H, W = img.shape[:2]
    w, h = size
    scale = min(0.8 * W / w, 0.8 * H / h, 1.0)
    pw, ph = max(int(w * scale), 4), max(int(h * scale), 4)
    box = donor.groundtruth.get(f)
    best: tuple[int, int] | None = None
    for _ in range(100):  # away from the donor's own target, so the occluder is never a copy of a target
        x, y = int(rng.integers(0, W - pw + 1)), int(rng.integers(0, H - ph + 1))
        best = best or (x, y)
        if box is None or (x + pw <= box[0] or box[0] + box[2] <= x or y + ph <= box[1] or box[1] + box[3] <= y):
            best = (x, y)
            break
    assert best is not None  # the loop ran
    x, y = best
    return img[y:y + ph, x:x + pw].copy(), f"{donor.name} frame {f} at {x},{y},{pw},{ph}"


def _write(folder: Path, seq: Sequence, files: dict[int, Path], plan: StressPlan, patch: np.ndarray | None,
           seed: int, first: int = 0) -> None:
    """The derived frames, and the truth and visibility of those that show a labelled frame
    (``plan.source`` counts from the original frame ``first``)."""
    frames = folder / "frames"
    frames.mkdir(parents=True)
    case = plan.case
    for i in range(len(plan)):
        src = files[first + int(plan.source[i])]
        if not plan.changed(i):
            shutil.copyfile(src, frames / f"{i:06d}{src.suffix.lower()}")
            continue
        img = cv2.imread(str(src), cv2.IMREAD_COLOR)
        if img is None:
            raise ValueError(f"{src}: not a decodable image")
        rng = np.random.default_rng([seed, zlib.crc32(seq.name.encode()), zlib.crc32(case.name.encode()), i])
        out = render_frame(img, plan, i, patch, rng)
        if not cv2.imwrite(str(frames / f"{i:06d}.jpg"), out, [cv2.IMWRITE_JPEG_QUALITY, 95]):
            raise OSError(f"could not write {frames / f'{i:06d}.jpg'}")
    scored = [i for i in range(len(plan)) if plan.labelled[i]]
    write_boxes(folder / "groundtruth.csv", {i: tuple(plan.boxes[i]) for i in scored})
    write_visibility(folder / "visibility.csv", {i: float(plan.visible[i]) for i in scored},
                     {i: bool(plan.perturbed[i]) for i in scored}, {i: first + int(plan.source[i]) for i in scored})


def _cached_meta(meta_path: Path, key: str) -> dict | None:
    """The ``stress.json`` of a complete cached folder made with ``key``, else None."""
    try:
        meta = json.loads(meta_path.read_text())
    except (OSError, ValueError):
        return None
    return meta if isinstance(meta, dict) and meta.get("key") == key else None


def derive(seq: Sequence, case: StressCase, donor: Sequence, root: Path, seed: int, lead: int, tail: int) -> Derived:
    """Write (or find in ``root``) the derived sequence of ``case`` on ``seq``, its patch cut from ``donor``."""
    files = _files(seq)
    truth = _truth(seq, files)
    img = cv2.imread(str(files[truth.first]), cv2.IMREAD_COLOR)
    if img is None:
        raise ValueError(f"{files[truth.first]}: not a decodable image")
    size = (img.shape[1], img.shape[0])
    rng = np.random.default_rng([seed, zlib.crc32(seq.name.encode()), zlib.crc32(case.name.encode())])
    plan = plan_case(case, truth.boxes, size, rng, lead=lead, tail=tail, labelled=truth.labelled)
    key = _digest(VERSION, case, lead, tail, seed, seq.name, _source_key(seq, files),
                  donor.name if case.kind in PATCH_KINDS else "", _source_key(donor, _files(donor))
                  if case.kind in PATCH_KINDS else "")
    # one folder per key: runs with another seed, lead or tail sharing the cache never rewrite the
    # frames this run reads; a folder is written under a name of its own and renamed when complete,
    # so a run never sees another's half-written folder, and two runs of one key keep the first
    folder = root / seq.name / f"{case.name}-{key[:12]}"
    meta_path = folder / "stress.json"
    meta = _cached_meta(meta_path, key)
    cached = meta is not None
    if meta is None:
        patch, patch_from = None, ""
        need = occluder_size(plan)
        if case.kind in COPY_KINDS:  # the target's own look at the window's start, mirrored
            w0 = plan.window[0]
            f = truth.first + int(plan.source[w0])
            look = cv2.imread(str(files[f]), cv2.IMREAD_COLOR)
            if look is None:
                raise ValueError(f"{files[f]}: not a decodable image")
            try:  # the box clipped to the image; nothing of it inside: this case cannot be made here
                patch = target_copy(look, plan.boxes[w0])
            except ValueError as e:
                raise CaseNotBuilt(f"on frame {f}, the window's start, {e}: no look of the target to copy") from None
            patch_from = f"{seq.name} frame {f}, the target's box mirrored"
        elif need is not None:
            patch, patch_from = _cut_patch(donor, need, {truth.first + int(f) for f in plan.source} if donor is seq
                                           else set(), rng)
        folder.parent.mkdir(parents=True, exist_ok=True)
        part = Path(tempfile.mkdtemp(prefix=f"{folder.name}.part-", dir=folder.parent))
        _write(part, seq, files, plan, patch, seed, truth.first)
        meta = {"key": key, "version": VERSION, "sequence": seq.name, "source": str(seq.path), "case": case.name,
                "kind": case.kind, "length": case.length, "amount": case.amount, "describe": case.describe(),
                "window": list(plan.window), "frames": len(plan), "scored_frames": int(plan.labelled.sum()),
                "lead": lead, "tail": tail, "seed": seed, "patch_from": patch_from}
        (part / "stress.json").write_text(json.dumps(meta, indent=1))
        try:
            part.rename(folder)
        except OSError:
            if _cached_meta(meta_path, key) is None:  # an incomplete folder (a crash): replace it
                shutil.rmtree(folder, ignore_errors=True)
                part.rename(folder)
            else:  # another run wrote the same folder first: its frames are these
                shutil.rmtree(part, ignore_errors=True)
    gt = read_boxes(folder / "groundtruth.csv")
    dseq = Sequence(name=f"{seq.name}/{case.name}", path=folder, groundtruth=gt, results=())
    return Derived(dseq, plan, seq.name, case, str(meta.get("patch_from", "")), cached)


@dataclass
class StressRow:
    """One tracker (ours, OpenCV's, or the box that never moves) on one derived sequence."""

    sequence: str
    case: str
    tracker: str
    kind: str  # "tracker" | "opencv" | "baseline"
    frames: int = 0
    window: tuple[int, int] = (0, 0)
    cle: float | None = None
    success: float | None = None
    after: float | None = None  # success from AFTER_GAP frames after the window on
    back_in: int | None = None  # frames from the window's end to IoU > 0.5 for 5 frames in a row
    state: StateScore | None = None
    fps: float | None = None
    note: str = ""
    untouched_after: float | None = None  # the after score on the same frames in the untouched run (case none)
    overlap: np.ndarray | None = None  # (T,) per-frame IoU
    extra: dict = field(default_factory=dict)

    @property
    def back(self) -> bool | None:
        return None if self.after is None else self.after >= BACK_AT


def stress_scores(row: StressRow, d: Derived, boxes_csv: str | Path) -> StressRow:
    """Score a tracker's boxes (and states, if the CSV has them) on a derived sequence, on the
    frames that have ground truth (every frame, or those showing a labelled original). The boxes are
    read as ``gflow eval`` reads them (:func:`pipeline.evaluation.scored_boxes.read_scored_boxes`): a row of
    no box (NaN, or w or h 0) is a miss, overlap 0; its state is still read."""
    gt = d.seq.groundtruth
    track = read_track(boxes_csv, allow_nan=True)
    frames = np.array(sorted(gt), dtype=np.int64)
    ov = overlaps(gt, read_scored_boxes(boxes_csv).boxes)
    w0, w1 = d.plan.window
    row.frames, row.window = len(frames), (w0, w1)
    after = ov[frames >= w1 + AFTER_GAP]
    row.after = float((after > 0.5).mean()) if after.size else None
    # per derived frame, NaN where it is not scored
    row.overlap = np.full(len(d.plan), np.nan)
    row.overlap[frames] = ov
    row.back_in = frames_to_recover(ov, w1, frames=frames)
    if track.states is not None:
        conf = None if track.confidence is None else [track.confidence.get(int(f), float("nan")) for f in frames]
        row.state = state_score([track.states.get(int(f)) for f in frames], d.plan.visible[frames],
                                d.plan.perturbed[frames], overlap=ov, confidence=conf, frames=frames)
    return row


def untouched(rows: list[StressRow], cases: dict[str, StressCase]) -> None:
    """Fill each row's ``untouched_after``: the same tracker's after score over the same original
    frames in the untouched run (case ``none``) of its sequence, where that run was made."""
    control = {(r.sequence, r.tracker): r for r in rows if cases[r.case].kind == "none" and r.overlap is not None}
    for r in rows:
        c = control.get((r.sequence, r.tracker))
        if c is None or r.overlap is None or r.after is None:
            continue
        w0, w1 = r.window
        # a fast case's window shows `length` original frames in w1 - w0 derived ones
        idx = np.arange(w1 + AFTER_GAP, r.overlap.shape[0]) + (cases[r.case].length - (w1 - w0))
        assert c.overlap is not None  # control holds rows with overlaps only
        if idx.size and idx[-1] < c.overlap.shape[0]:
            ov = c.overlap[idx]
            ov = ov[~np.isnan(ov)]  # the scored frames (the same original frames as the case's)
            if ov.size:
                r.untouched_after = float((ov > 0.5).mean())


def _from_row(row: StressRow, r: Row) -> None:
    if r.score is not None:
        row.cle, row.success = r.score.cle, r.score.success
    row.fps = r.fps
    row.note = r.note


def _f(v, fmt: str) -> str:
    return "-" if v is None or (isinstance(v, float) and not math.isfinite(v)) else format(v, fmt)


def _back_in(r: StressRow | None) -> str:
    if r is None or r.success is None:
        return "-"
    return "never" if r.back_in is None else str(r.back_in)


def _rate(a: int, b: int) -> str:
    return "-" if b == 0 else f"{a / b:.2f}"


def _rate_of(a: int, b: int) -> str:
    """The fraction with its count: ``"0.99 (8,900 / 8,990)"``."""
    return "-" if b == 0 else f"{a / b:.2f} ({a:,} / {b:,})"


COLUMNS = ("sequence", "case", "CLE px", "success", "after", "untouched after", "back in", "hidden ok", "shown ok")
OTHER_COLUMNS = ("CLE", "success", "after", "back in")


def _table(head: tuple[str, ...], cells: list[list[str]], markdown: bool, right_from: int = 2,
           last_left: bool = True) -> str:
    if markdown:
        return "\n".join(["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
                         + ["| " + " | ".join(c) + " |" for c in cells])
    widths = [max(len(h), *(len(c[i]) for c in cells)) if cells else len(h) for i, h in enumerate(head)]

    def line(c: list[str]) -> str:
        return "  ".join(v.rjust(w) if right_from <= i < len(head) - last_left else v.ljust(w)
                         for i, (v, w) in enumerate(zip(c, widths))).rstrip()

    return "\n".join([line(list(head)), line(["-" * w for w in widths])] + [line(c) for c in cells])


def _group(rows: list[StressRow]) -> dict:
    """Cases got back, mean success and mean after score of some rows of one tracker."""
    scored = [r for r in rows if r.after is not None]
    ok = [r for r in rows if r.success is not None]
    return {"back": [sum(bool(r.back) for r in scored), len(scored)],
            "mean_success": None if not ok else round(float(np.mean([r.success for r in ok])), 4),
            "mean_after": None if not scored else round(float(np.mean([r.after for r in scored])), 4)}


def _summary(rows: list[StressRow]) -> dict:
    """Counts over one tracker's rows: cases got back, the acceptance groups, pooled state rates."""
    every = rows
    rows = [r for r in rows if r.extra.get("case_kind") != "none"]  # the control perturbs nothing to get back from
    scored = [r for r in rows if r.after is not None]

    def back(pred) -> list[int]:
        sel = [r for r in scored if pred(r)]
        return [sum(bool(r.back) for r in sel), len(sel)]

    groups = {
        "full occlusion <= 60 frames": lambda r: r.extra["case_kind"] in ("occlude", "sweep")
        and r.extra["case_length"] <= 60,
        "roll <= 35 degrees": lambda r: r.extra["case_kind"].startswith("roll") and r.extra["case_amount"] <= 35,
        "fast motion": lambda r: r.extra["case_kind"] == "fast",
        "every case": lambda r: True,
    }
    st = [r.state for r in every if r.state is not None]
    ok = [r for r in rows if r.success is not None]
    return {
        "families": {k: _group([r for r in rows if r.extra["case_kind"] == k])
                     for k in dict.fromkeys(r.extra["case_kind"] for r in rows)},
        "sequences": {q: _group([r for r in rows if r.sequence == q]) for q in dict.fromkeys(r.sequence for r in rows)},
        "back": {g: back(p) for g, p in groups.items()},
        "mean_success": None if not ok else round(float(np.mean([r.success for r in ok])), 4),
        "mean_after": None if not scored else round(float(np.mean([r.after for r in scored])), 4),
        "skipped_cases": [f"{r.sequence}/{r.case}" for r in every if r.extra.get("case_skipped")],
        "worse_than_still_box": [f"{r.sequence}/{r.case}" for r in every if r.success is not None
                                 and r.extra.get("still_success") is not None and r.success < r.extra["still_success"]],
        "hidden_reported_occluded_or_lost": [sum(s.hidden_right for s in st), sum(s.hidden for s in st)],
        "undisturbed_reported_tracked": [sum(s.shown_right for s in st), sum(s.shown for s in st)],
        "off_target_reported_tracked": [sum(s.off_tracked for s in st), sum(s.off for s in st)],
        "undisturbed_on_target_reported_tracked": [sum(s.shown_on_tracked for s in st), sum(s.shown_on for s in st)],
        "undisturbed_off_target_reported_occluded_or_lost": [sum(s.shown_off_hidden for s in st),
                                                             sum(s.shown_off for s in st)],
        "confidence_bands": band_json([[sum(s.bands[b][i] for s in st if s.bands) for i in (0, 1)]
                                       for b in range(len(CONFIDENCE_BANDS) + 1)]),
    }


def format_stress(rows: list[StressRow], markdown: bool = False) -> str:
    """One table per tracker, CSRT's and the still box's scores beside each row, and a summary."""
    ours = list(dict.fromkeys(r.tracker for r in rows if r.kind == "tracker"))
    by = {(r.sequence, r.case, r.tracker): r for r in rows}
    cv = next((r.tracker for r in rows if r.kind == "opencv"), None)
    out: list[str] = []
    for name in ours:
        mine = [r for r in rows if r.tracker == name]
        cells = []
        for r in mine:
            c = by.get((r.sequence, r.case, cv)) if cv else None
            s = by.get((r.sequence, r.case, "still box"))
            st = r.state
            cells.append([r.sequence, r.case, _f(r.cle, ".1f"), _f(r.success, ".2f"), _f(r.after, ".2f"),
                          _f(r.untouched_after, ".2f"), _back_in(r),
                          "-" if st is None else _rate(st.hidden_right, st.hidden),
                          "-" if st is None else _rate(st.shown_right, st.shown)]
                         + ([_f(c and c.cle, ".1f"), _f(c and c.success, ".2f"), _f(c and c.after, ".2f"),
                             _back_in(c)] if cv else [])
                         + [_f(s and s.after, ".2f"), r.note])
        head = COLUMNS + (tuple(f"{cv.removeprefix('opencv ').upper()} {h}" for h in OTHER_COLUMNS) if cv else ()) \
            + ("still box after", "note")
        out.append(f"{'### ' if markdown else ''}{name}" + (f" (beside it: {cv})" if cv else ""))
        out.append("")
        out.append(_table(head, cells, markdown))
        out.append("")
        theirs = [r for r in rows if r.tracker == cv] if cv else []
        out += _summary_lines(name, mine, theirs, cv)
        out.append("")
        for group, title in (("families", "family"), ("sequences", "sequence")):
            line = f"{name} per {title}" + (f" (beside it: {cv})" if cv else "")
            out += [f"**{line}**" if markdown else line, "",
                    _group_table(title, _summary(mine)[group], _summary(theirs)[group] if theirs else None, cv,
                                 markdown), ""]
    out += _overview(rows, markdown)
    return "\n".join(out).rstrip()


#: the heading of the tables that put every tracker side by side
OVERVIEW = "every tracker"


def _overview(rows: list[StressRow], markdown: bool) -> list[str]:
    """Every tracker (ours and OpenCV's) side by side: cases got back per family and per sequence,
    and the summary figures."""
    names = list(dict.fromkeys(r.tracker for r in rows if r.kind != "baseline"))
    if not names:
        return []
    sums = {n: _summary([r for r in rows if r.tracker == n]) for n in names}
    head = tuple(n.removeprefix("opencv ").upper() if n.startswith("opencv ") else n for n in names)

    def back(g: dict | None) -> str:
        return "-" if g is None else f"{g['back'][0]}/{g['back'][1]}"

    out = [f"{'### ' if markdown else ''}{OVERVIEW}: cases got back (success >= {BACK_AT} from {AFTER_GAP} frames "
           "after the window) of those run, per family and per sequence", ""]
    for group, title in (("families", "family"), ("sequences", "sequence")):
        keys = list(dict.fromkeys(k for n in names for k in sums[n][group]))
        cells = [[k] + [back(sums[n][group].get(k)) for n in names] for k in keys]
        cells.append(["every case"] + [back({"back": sums[n]["back"]["every case"]}) for n in names])
        out += [_table((title,) + head, cells, markdown, right_from=1, last_left=False), ""]
    rate = [("mean success", lambda a: _f(a["mean_success"], ".3f")),
            ("mean after", lambda a: _f(a["mean_after"], ".3f")),
            ("hidden frames reported occluded or lost", lambda a: _rate(*a["hidden_reported_occluded_or_lost"])),
            ("undisturbed frames reported tracked", lambda a: _rate(*a["undisturbed_reported_tracked"])),
            ("off the target yet reported tracked (lower is better)",
             lambda a: _rate(*a["off_target_reported_tracked"])),
            ("undisturbed, box on the target: reported tracked",
             lambda a: _rate_of(*a["undisturbed_on_target_reported_tracked"])),
            ("undisturbed, box off the target: reported occluded/lost",
             lambda a: _rate_of(*a["undisturbed_off_target_reported_occluded_or_lost"])),
            ("cases worse than a box that never moves", lambda a: str(len(a["worse_than_still_box"])))]
    groups = [g for g in sums[names[0]]["back"] if g != "every case"]
    cells = [[f"got back after {g}"] + [back({"back": sums[n]["back"][g]}) for n in names] for g in groups]
    cells += [[what] + [get(sums[n]) for n in names] for what, get in rate]
    if any(sums[n]["skipped_cases"] for n in names):  # said only when some were: the table of a full run is as it was
        cells.append(["cases skipped (could not be made)"] + [str(len(sums[n]["skipped_cases"])) for n in names])
    out += [_table(("over every case",) + head, cells, markdown, right_from=1, last_left=False), ""]
    return out


def _group_table(title: str, mine: dict, theirs: dict | None, cv: str | None, markdown: bool) -> str:
    """Cases got back, mean success and mean after per family (or per sequence), CSRT's beside."""
    other = () if theirs is None or cv is None else tuple(
        f"{cv.removeprefix('opencv ').upper()} {h}" for h in ("got back", "mean success", "mean after"))
    head = (title, "got back", "mean success", "mean after") + other

    def cells(g: dict | None) -> list[str]:
        if g is None:
            return ["-", "-", "-"]
        return [f"{g['back'][0]}/{g['back'][1]}", _f(g["mean_success"], ".3f"), _f(g["mean_after"], ".3f")]

    body = [[k] + cells(g) + (cells(theirs.get(k)) if theirs is not None and other else []) for k, g in mine.items()]
    return _table(head, body, markdown, right_from=1, last_left=False)


def _summary_lines(name: str, mine: list[StressRow], theirs: list[StressRow], cv: str | None) -> list[str]:
    a, b = _summary(mine), _summary(theirs) if theirs else None
    lines = []
    for g, (k, n) in a["back"].items():
        if n == 0:
            continue
        other = f"; {cv} {b['back'][g][0]}/{b['back'][g][1]}" if b else ""
        lines.append(f"- back after {g} (success >= {BACK_AT} from {AFTER_GAP} frames after the window): "
                     f"{k}/{n}{other}")
    lines.append(f"- mean success {_f(a['mean_success'], '.3f')}, mean after {_f(a['mean_after'], '.3f')}"
                 + (f"; {cv} {_f(b['mean_success'], '.3f')}, {_f(b['mean_after'], '.3f')}" if b else ""))
    h, s = a["hidden_reported_occluded_or_lost"], a["undisturbed_reported_tracked"]
    lines.append(f"- state: hidden frames (past the first 5) reported occluded or lost {_rate(*h)} ({h[0]}/{h[1]}); "
                 f"undisturbed frames reported tracked {_rate(*s)} ({s[0]}/{s[1]})")
    o = a["off_target_reported_tracked"]
    lines.append(f"- box off the target (IoU <= 0.5, target in view) yet reported tracked {_rate(*o)} "
                 f"({o[0]}/{o[1]}; lower is better)")
    on, off = a["undisturbed_on_target_reported_tracked"], a["undisturbed_off_target_reported_occluded_or_lost"]
    lines.append(f"- undisturbed frames split by the box (IoU > 0.5: on the target): box on the target, reported "
                 f"tracked {_rate_of(*on)}; box off the target, reported occluded/lost {_rate_of(*off)}")
    bands = band_text(a["confidence_bands"])
    if bands:
        lines.append(f"- on target by confidence (target in view): {bands}")
    skipped = a["skipped_cases"]
    if skipped:
        lines.append(f"- skipped, the case could not be made on the sequence (not in the counts above): "
                     f"{len(skipped)} case(s): {', '.join(skipped)}")
    worse = a["worse_than_still_box"]
    lines.append(f"- worse than a box that never moves (success): {len(worse)} case(s)"
                 + (f": {', '.join(worse)}" if worse else ""))
    return lines


def stress_json(rows: list[StressRow], meta: dict, cases: list[StressCase]) -> dict:
    """The stress benchmark as JSON: meta, the cases, one object per row, a summary per tracker."""
    out = []
    for r in rows:
        d: dict = {"sequence": r.sequence, "case": r.case, "tracker": r.tracker, "kind": r.kind, "frames": r.frames,
                   "window": list(r.window), "cle_px": None if r.cle is None else round(r.cle, 3),
                   "success": None if r.success is None else round(r.success, 4),
                   "after": None if r.after is None else round(r.after, 4),
                   "untouched_after": None if r.untouched_after is None else round(r.untouched_after, 4),
                   "back": r.back, "back_in": r.back_in,
                   "fps": None if r.fps is None else round(r.fps, 2)}
        if r.state is not None:
            d["state"] = r.state.to_json()
        if r.note:
            d["note"] = r.note
        d.update(r.extra)
        out.append(d)
    names = list(dict.fromkeys(r.tracker for r in rows if r.kind != "baseline"))
    return dict(meta, after_gap=AFTER_GAP, back_at=BACK_AT, hidden_below=HIDDEN_BELOW,
                cases=[{"name": c.name, "kind": c.kind, "length": c.length, "amount": c.amount,
                        "describe": c.describe()} for c in cases],
                rows=out, summary={n: _summary([r for r in rows if r.tracker == n]) for n in names})


def _opencv_cached(r: Row, name: str, d: Derived, out: Path, seed: int, cache: bool) -> None:
    """Run an OpenCV tracker on a derived sequence, or, with the cache, take its boxes from the
    last run on the same derived sequence (OpenCV's trackers do not change while tuning ours)."""
    from pipeline.evaluation.sequence_benchmark import opencv_row, score_row

    kept = d.seq.path / f"opencv_{name}_seed{seed}_cv{cv2.__version__}.csv"
    info = kept.with_suffix(".json")
    if cache and kept.is_file() and info.is_file():
        try:
            fps = _cached_fps(info)
            score_row(r, d.seq.groundtruth, kept)  # a damaged file named as the cache's, not as its copy
            out.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(kept, out)
            r.fps, r.boxes_csv = fps, str(out)
            return
        except ValueError as e:  # a damaged cache is run again (and written again), as a damaged stress.json is
            note(f"{e}; running opencv {name} again")
            r.score = None
    opencv_row(r, name, d.seq, 0, None, d.seq.groundtruth, out, seed, True)
    if cache and r.score is not None:
        shutil.copyfile(out, kept)
        info.write_text(json.dumps({"fps": r.fps}))


def _cached_fps(info: Path) -> float | None:
    """The frames/s a cached OpenCV run's ``.json`` holds (``{"fps": number or null}``); ``ValueError`` in one line
    naming the file when it cannot be read as one (truncated, not JSON, another shape): its boxes are run again."""
    try:
        held = json.loads(info.read_text())
    except (OSError, ValueError) as e:  # UnicodeDecodeError and JSONDecodeError are ValueErrors
        raise ValueError(f"{info}: not a cached OpenCV result ({getattr(e, 'strerror', None) or e})") from None
    fps = held.get("fps") if isinstance(held, dict) else None
    if not isinstance(held, dict) or not (fps is None or (isinstance(fps, (int, float)) and not isinstance(fps, bool)
                                                          and math.isfinite(fps) and fps >= 0)):
        raise ValueError(f"{info}: not a cached OpenCV result (expected {{\"fps\": frames/s or null}}, got "
                         f"{json.dumps(held)[:60]})")
    return fps


def _tracker_rows(d: Derived, names: list[str], folder: Path, extra: dict, plan_of: PlanOf) -> list[StressRow]:
    """Our trackers on one derived sequence, each run exactly as ``gflow benchmark`` runs it."""
    from pipeline.evaluation.sequence_benchmark import tracker_row

    rows = []
    for name in names:
        row = StressRow(d.origin, d.case.name, name, "tracker", extra=dict(extra))
        rows.append(row)
        planned = plan_of(d.seq, name, folder)
        if isinstance(planned, str):
            row.note = f"skipped: {planned}"
            continue
        r = Row(d.seq.name, name, "tracker")
        tracker_row(r, *planned, d.seq.groundtruth, True)
        _from_row(row, r)
        if r.score is not None and r.boxes_csv:
            stress_scores(row, d, r.boxes_csv)
    return rows


def _other_rows(args, d: Derived, cv_names: list[str], folder: Path, extra: dict) -> list[StressRow]:
    """OpenCV's trackers and the box that never moves on one derived sequence."""
    from pipeline.evaluation.sequence_benchmark import static_box

    rows = []
    for cvn in cv_names:
        row = StressRow(d.origin, d.case.name, f"opencv {cvn}", "opencv", extra=dict(extra))
        rows.append(row)
        r = Row(d.seq.name, row.tracker, "opencv")
        out = folder / f"opencv_{cvn}.csv"
        _opencv_cached(r, cvn, d, out, args.seed, bool(args.stress_cache))
        _from_row(row, r)
        if r.score is not None:
            stress_scores(row, d, out)
    r = static_box(d.seq, d.seq.groundtruth, 0, folder)
    still = StressRow(d.origin, d.case.name, "still box", "baseline", extra=dict(extra))
    _from_row(still, r)
    assert r.boxes_csv is not None  # static_box names the CSV it wrote
    stress_scores(still, d, r.boxes_csv)
    return rows + [still]


def _skipped_rows(seq: str, case: StressCase, names: list[str], cv_names: list[str], extra: dict,
                  why: str) -> list[StressRow]:
    """The rows of a case that could not be made on ``seq`` (:class:`CaseNotBuilt`): every tracker's, OpenCV's
    and the still box's, unscored, their note saying why (``extra``'s ``case_skipped`` marks them)."""
    kinds = [(n, "tracker") for n in names] + [(f"opencv {c}", "opencv") for c in cv_names] + [("still box",
                                                                                              "baseline")]
    return [StressRow(seq, case.name, n, k, note=f"skipped: {why}", extra=dict(extra, case_skipped=True))
            for n, k in kinds]


def check_sequences(seqs: list[Sequence]) -> None:
    """Every sequence has an image and a ground-truth box for every frame from 0 on (ValueError
    naming the first that does not), checked before any work."""
    for seq in seqs:
        _truth(seq, _files(seq))


def run_stress(args, seqs: list[Sequence], names: list[str], cv_names: list[str], plan_of: PlanOf,
               donors: list[Sequence] | None = None) -> tuple[list[StressRow], bool, list[StressCase]]:
    """Every tracker, OpenCV tracker (each available) and the still box on every case of every sequence.

    ``donors`` are every sequence of the datasets (default ``seqs``): each sequence's image
    patches are cut from the next one among them, so choosing fewer sequences with
    ``--sequences`` does not change the derived sequences; ``plan_of`` says how each tracker runs
    on a derived sequence. Returns the rows, whether Ctrl-C stopped it, and the cases."""
    cases = select_cases(args.cases)
    runs = len(seqs) * len(cases)
    rows: list[StressRow] = []
    done = 0
    t0 = time.monotonic()
    interrupted = False
    with tempfile.TemporaryDirectory(prefix="gflow-stress-") as tmp:
        cache = Path(args.stress_cache) if args.stress_cache else Path(tmp) / "derived"
        work = Path(args.out_dir) if args.out_dir else Path(tmp) / "runs"
        try:
            pool = donors or seqs
            for seq in seqs:
                donor = pool[(pool.index(seq) + 1) % len(pool)]
                for case in cases:
                    done += 1
                    extra = {"case_kind": case.kind, "case_length": case.length, "case_amount": case.amount}
                    try:
                        d = derive(seq, case, donor, cache, args.seed, args.lead, args.tail)
                    except CaseNotBuilt as e:  # one odd sequence does not stop the run: said, and in the tables
                        note(f"[{done}/{runs}] {seq.name} / {case.name}: skipped: {e}")
                        rows += _skipped_rows(seq.name, case, names, cv_names, extra, str(e))
                        continue
                    eta = (time.monotonic() - t0) / max(done - 1, 1) * (runs - done + 1) if done > 1 else None
                    note(f"[{done}/{runs}] {seq.name} / {case.name}: {len(d.plan)} frames, window "
                         f"{d.plan.window[0]}:{d.plan.window[1]}" + (" (cached)" if d.cached else "")
                         + ("" if eta is None else f", about {eta / 60:.0f} min left" if eta >= 120
                            else f", about {eta:.0f} s left"))
                    folder = work / seq.name / case.name
                    mine = _tracker_rows(d, names, folder, extra, plan_of)
                    rows += mine
                    others = _other_rows(args, d, cv_names, folder, extra)
                    rows += others
                    for row in mine + others:
                        row.extra["still_success"] = others[-1].success
                    if not args.stress_cache:
                        shutil.rmtree(d.seq.path, ignore_errors=True)
                    if not args.out_dir:  # scored: its recordings (tens of MB a run) need not wait for the end
                        shutil.rmtree(folder, ignore_errors=True)
        except KeyboardInterrupt:
            interrupted = True
            note("interrupted: stopped; the tables hold the runs that finished")
    untouched(rows, {c.name: c for c in cases})
    return rows, interrupted, cases
