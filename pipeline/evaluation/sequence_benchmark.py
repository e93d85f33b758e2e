"""``gflow benchmark``: every tracker on every sequence folder, scored like ``gflow eval``.

A sequence folder holds ``frames/`` and ``groundtruth.csv`` (``frame,x,y,w,h``), and
optionally ``results/TRACKER.csv``, other trackers' published per-frame boxes (the layout of
``../shared/data``). Each selected tracker runs through the same code as ``gflow track``
(:func:`pipeline.app.track`), from the ground-truth box of the first frame,
with one seed; its boxes are written with the same CSV writer and scored by the same
function as ``gflow eval`` (:func:`gflow_core.evaluation.metrics.score`). Published results, a box that
never moves ("static box") and, where OpenCV has them, OpenCV's trackers are scored the same
way over the same frames.

fps is frames tracked / wall time of tracking: from the first frame the source published to
the last estimate, read from the run's recording, so process start-up is left out (it is in
``seconds_total`` of the JSON).
"""

from __future__ import annotations

import math
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from gflow_core.evaluation.metrics import OVERLAP_THRESHOLDS, TrackScore, precision_curve, score, size_kept, success_curve

from pipeline.io.frame_readers import folder_frames
from pipeline.io.path_errors import MissingPath
from pipeline.io.recording_files import save_figure_new
from pipeline.evaluation.scored_boxes import read_scored_boxes
from pipeline.recording.results import write_boxes
from pipeline.app import TrackPlan

__all__ = ["Sequence", "Row", "find_sequences", "score_row", "static_box", "published_rows", "opencv_tracker",
           "run_opencv", "tracking_seconds", "tracker_row", "opencv_row", "plot_success", "plot_precision",
           "PRECISION_THRESHOLDS", "PRECISION_AT"]

Box = tuple[float, float, float, float]

#: centre-error thresholds (px) of the precision plot; the legend gives precision at 20 px (OTB)
PRECISION_THRESHOLDS = np.arange(0.0, 51.0)
#: the centre error (px) the tables give the precision at (OTB's representative threshold)
PRECISION_AT = 20

#: OpenCV tracker names for ``--opencv`` and the class each one is
OPENCV_TRACKERS = {"csrt": "TrackerCSRT", "kcf": "TrackerKCF", "mil": "TrackerMIL", "boosting": "TrackerBoosting",
                   "medianflow": "TrackerMedianFlow", "mosse": "TrackerMOSSE", "tld": "TrackerTLD"}


@dataclass(frozen=True)
class Sequence:
    """One sequence folder: its frames, its ground truth and its published results files."""

    name: str
    path: Path
    groundtruth: dict[int, Box]
    results: tuple[Path, ...]

    def truth(self, start: int, stop: int | None) -> dict[int, Box]:
        """Ground truth of the frames ``start <= f < stop``."""
        return {f: b for f, b in self.groundtruth.items() if f >= start and (stop is None or f < stop)}


@dataclass
class Row:
    """One line of the table: a tracker (ours, published, baseline or OpenCV) on one sequence."""

    sequence: str
    tracker: str
    kind: str  # "tracker" | "published" | "baseline" | "opencv"
    score: TrackScore | None = None
    curve: np.ndarray | None = None  # success rate at OVERLAP_THRESHOLDS
    precision: np.ndarray | None = None  # precision at PRECISION_THRESHOLDS
    size_2x: float | None = None  # on-target frames with the box area within 2x of the truth
    fps: float | None = None
    seconds: float | None = None  # wall time of tracking
    seconds_total: float | None = None  # including start-up
    note: str = ""
    boxes_csv: str | None = None
    extra: dict = field(default_factory=dict)

    @property
    def auc(self) -> float | None:
        return None if self.curve is None else float(self.curve.mean())

    @property
    def precision_at(self) -> float | None:
        """Precision at :data:`PRECISION_AT` px: the fraction of ground-truth frames with the centre that near."""
        return None if self.precision is None else float(self.precision[PRECISION_AT])


def _is_sequence(p: Path) -> bool:
    return (p / "frames").is_dir() and (p / "groundtruth.csv").is_file()


def _load(p: Path) -> Sequence:
    # a row of no size (w or h 0, or NaN) marks the target absent: left out, as gflow eval leaves it out
    gt = read_scored_boxes(p / "groundtruth.csv").boxes
    if not gt:
        raise ValueError(f"{p / 'groundtruth.csv'}: the target is absent (w or h 0, or NaN) on every frame")
    frames = [i for i, _ in folder_frames(p / "frames")]
    beyond = [f for f in gt if not frames or f > frames[-1]]
    if beyond:  # scored as frames the tracker missed, though no tracker could see them (gflow export vot refuses them)
        raise ValueError(f"{p / 'groundtruth.csv'}: ground truth for frame {min(beyond)}, after the last frame of "
                         + (f"{p / 'frames'} ({frames[-1]})" if frames else f"{p / 'frames'}, which holds no image"))
    res = tuple(sorted((p / "results").glob("*.csv"))) if (p / "results").is_dir() else ()
    return Sequence(name=p.name, path=p, groundtruth=gt, results=res)


def find_sequences(paths: list[str]) -> tuple[list[Sequence], list[str]]:
    """Sequence folders among ``paths`` (each a sequence or a folder of sequences) and notes on
    the entries skipped. A path that is neither raises FileNotFoundError / ValueError (one line)."""
    seqs: list[Sequence] = []
    notes: list[str] = []
    for text in paths:
        p = Path(text)
        if not p.exists():
            raise MissingPath(f"dataset folder not found: {text}")
        if not p.is_dir():
            raise ValueError(f"{text} is not a folder (give a sequence folder with frames/ and groundtruth.csv, "
                             "or a folder of them)")
        if _is_sequence(p):
            seqs.append(_load(p))
            continue
        if (p / "frames").is_dir():
            raise ValueError(f"{text} has frames/ but no groundtruth.csv (frame,x,y,w,h per line)")
        if (p / "groundtruth.csv").is_file():
            raise ValueError(f"{text} has groundtruth.csv but no frames/ folder")
        children = sorted(c for c in p.iterdir() if c.is_dir() and not c.name.startswith("."))
        found = [c for c in children if _is_sequence(c)]
        if not found:
            raise ValueError(f"{text} is not a sequence folder (frames/ and groundtruth.csv) and holds none")
        for c in children:
            if c in found:
                seqs.append(_load(c))
            else:
                notes.append(f"skipped {c}: not a sequence folder (needs frames/ and groundtruth.csv)")
    names = [s.name for s in seqs]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise ValueError(f"two sequences are named {dup[0]}; give each sequence once")
    return seqs, notes


def score_row(row: Row, gt: dict[int, Box], csv_path: Path) -> Row:
    """Score the boxes in ``csv_path`` as ``gflow eval --gt ... --pred csv_path`` does, over ``gt``'s frames (a
    box of no size, as a published tracker writes a failure, is a miss)."""
    pred = read_scored_boxes(csv_path).boxes
    row.score = score(gt, pred)
    row.curve = success_curve(gt, pred)
    row.precision = precision_curve(gt, pred, PRECISION_THRESHOLDS)
    row.size_2x = size_kept(gt, pred)
    return row


def static_box(seq: Sequence, gt: dict[int, Box], start: int, folder: Path) -> Row:
    """The baseline: the first frame's ground-truth box held still on every frame."""
    path = folder / "static_box.csv"
    write_boxes(path, {f: seq.groundtruth[start] for f in gt})
    return score_row(Row(seq.name, "static box", "baseline", boxes_csv=str(path)), gt, path)


def published_rows(seq: Sequence, gt: dict[int, Box]) -> list[Row]:
    """``results/*.csv`` scored over the same frames (a file that cannot be read gets a note)."""
    rows = []
    for p in seq.results:
        row = Row(seq.name, p.stem, "published", boxes_csv=str(p))
        try:
            score_row(row, gt, p)
        except (ValueError, FileNotFoundError) as e:
            row.note = f"not scored: {e}"
        rows.append(row)
    return rows


def opencv_tracker(name: str) -> tuple[Callable | None, str]:
    """(factory, "") for an OpenCV tracker, or (None, why it is unavailable)."""
    import cv2

    cls = OPENCV_TRACKERS.get(name)
    if cls is None:
        return None, f"unknown OpenCV tracker (known: {', '.join(OPENCV_TRACKERS)})"
    for mod in (cv2, getattr(cv2, "legacy", None)):
        if mod is None:
            continue
        f = getattr(mod, f"{cls}_create", None) or getattr(getattr(mod, cls, None), "create", None)
        if f is not None:
            return f, ""
    return None, f"unavailable: this OpenCV ({cv2.__version__}) has no {cls} (it is in opencv-contrib-python)"


def run_opencv(name: str, seq: Sequence, start: int, stop: int | None, out_csv: Path,
               seed: int = 1) -> tuple[int, float]:
    """Run OpenCV's tracker ``name`` over the frames from the ground-truth box of ``start`` in a
    fresh process, and write its boxes. Returns (frames, seconds reading and tracking).

    A fresh process because OpenCV's trackers keep state between runs in one process (MIL gives
    another result on its second run even with ``cv2.setRNGSeed``), so a row would depend on
    what ran before it. Raises RuntimeError if the tracker fails.
    """
    import multiprocessing as mp

    ctx = mp.get_context("spawn")
    recv, send = ctx.Pipe(duplex=False)
    proc = ctx.Process(target=_opencv_child, args=(send, name, seq, start, stop, str(out_csv), seed), daemon=True)
    proc.start()
    send.close()
    try:
        res = recv.recv()
    except EOFError:
        proc.join(5.0)
        raise RuntimeError(f"the OpenCV {name} process died (exit status {proc.exitcode})") from None
    except BaseException:  # Ctrl-C: stop it now
        proc.terminate()
        raise
    finally:
        proc.join(5.0)
        if proc.is_alive():
            proc.kill()
            proc.join()
        recv.close()
    if isinstance(res, str):
        raise RuntimeError(res)
    return res


def _opencv_child(conn, name: str, seq: Sequence, start: int, stop: int | None, out_csv: str, seed: int) -> None:
    """The body of :func:`run_opencv`'s process: sends (frames, seconds) or an error message."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent stops this process on Ctrl-C
    try:
        conn.send(_track_opencv(name, seq, start, stop, Path(out_csv), seed))
    except Exception as e:  # reported as the row's note
        conn.send(f"{type(e).__name__}: {e}")
    finally:
        conn.close()


def _track_opencv(name: str, seq: Sequence, start: int, stop: int | None, out_csv: Path,
                  seed: int) -> tuple[int, float]:
    """An OpenCV tracker from the box of ``start``; a frame where it reports failure keeps its last box."""
    import cv2

    from stages.source import SourceParams

    from pipeline.io.frame_readers import open_reader

    factory, why = opencv_tracker(name)
    if factory is None:
        raise RuntimeError(why)
    cv2.setRNGSeed(seed)  # MIL and Boosting draw from OpenCV's global RNG
    params = SourceParams(kind="folder", path=str((seq.path / "frames").resolve()), start=start, stop=stop)
    boxes: dict[int, Box] = {}
    tracker = None
    last: Box = seq.groundtruth[start]
    t0 = time.perf_counter()  # reading the frames is timed too, as in the pipeline's source stage
    for raw in open_reader(params):
        if raw.image is not None:
            if tracker is None:
                tracker = factory()
                x, y, w, h = last
                tracker.init(raw.image, (int(round(x)), int(round(y)), max(1, int(round(w))), max(1, int(round(h)))))
            else:
                ok, b = tracker.update(raw.image)
                if ok:
                    bx, by, bw, bh = (float(v) for v in b)  # OpenCV's Rect: four numbers
                    last = (bx, by, bw, bh)
        boxes[raw.index] = last
    secs = time.perf_counter() - t0
    write_boxes(out_csv, boxes)
    return len(boxes), secs


def tracking_seconds(recording: str | Path) -> float | None:
    """Wall time from the first Frame published to the last estimate, from a recording."""
    from pipeline.io.mcap_io import iter_records

    first = last = None
    for r in iter_records(recording):
        if r.type == "Frame" and first is None:
            first = r.publish_ns
        elif r.type in ("Estimate", "PoseEstimate"):
            last = r.publish_ns if last is None else max(last, r.publish_ns)
    if first is None or last is None or last <= first:
        return None
    return (last - first) / 1e9


def tracker_row(row, out: str, plan: TrackPlan, gt: dict, keep: bool) -> None:
    """Run one tracker's plan as ``gflow track`` does (:func:`pipeline.app.track`), write its boxes
    to ``out`` and score them as ``gflow eval`` does."""
    from pipeline.app import track

    try:
        run = track(plan)
    except Exception as e:  # noqa: BLE001 - a tracker that fails is a result of the benchmark, not its end
        row.note = f"failed: {e}"
        note(f"{row.sequence} / {row.tracker}: {row.note}")
        return
    if run.info.get("interrupted"):
        raise KeyboardInterrupt
    run.write_csv(out)
    row.boxes_csv = out if keep else None
    try:
        score_row(row, gt, Path(out))
    except ValueError as e:
        row.note = f"not scored: {e}"
    # the span was read with the estimates (one pass over the recording); read it here only if it was not
    span = run.tracking_seconds if run.tracking_seconds is not None else (
        tracking_seconds(run.recording) if run.recording else None)
    secs = span or run.seconds
    row.seconds, row.seconds_total = secs, run.seconds
    if not keep and run.recording:  # scored and timed: a temporary recording need not wait for the run's end
        Path(run.recording).unlink(missing_ok=True)
    row.fps = len(run.estimates) / secs if secs > 0 else None
    failures = run.info.get("failures")
    if failures is not None and failures.every and not run.estimates:  # said as gflow track says it, with its reason
        row.note = (row.note + "; " if row.note else "") + failures.line()
    elif run.info.get("errors"):
        row.note = (row.note + "; " if row.note else "") + f"stages reported errors: {run.info['errors']}"
    note(f"{row.sequence} / {row.tracker}: {len(run.estimates)} frames in {secs:.2f} s"
         + (f" ({row.fps:.1f} fps)" if row.fps else "")
         + (f", CLE {row.score.cle:.2f} px, success {row.score.success:.3f}" if row.score else ""))


def opencv_row(row, name: str, seq, start: int, stop: int | None, gt: dict, out: Path, seed: int,
                keep: bool) -> None:
    """Run one OpenCV tracker (in its own process) and score it."""
    try:
        n, secs = run_opencv(name, seq, start, stop, out, seed=seed)
        score_row(row, gt, out)
    except (RuntimeError, ValueError, OSError) as e:
        row.note = f"failed: {e}"
        return
    row.seconds, row.fps = secs, (n / secs if secs > 0 else None)
    row.boxes_csv = str(out) if keep else None


_STYLE = {"tracker": "-", "opencv": "-.", "published": "--", "baseline": ":"}


def _plot(rows: list[Row], path: str, attr: str, x: np.ndarray, xlabel: str, ylabel: str, label: Callable[[Row], str],
          title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    seqs = list(dict.fromkeys(r.sequence for r in rows))
    # one colour per tracker across every subplot; ours first, the static box grey
    names = list(dict.fromkeys(r.tracker for r in sorted(rows, key=lambda r: r.kind != "tracker")
                               if r.kind != "baseline"))
    cmap = plt.get_cmap("tab10" if len(names) <= 10 else "tab20")
    colour = {n: cmap(i % cmap.N) for i, n in enumerate(names)}
    n = max(1, len(seqs))
    cols = min(n, 3)
    nrows = math.ceil(n / cols)
    fig, axes = plt.subplots(nrows, cols, figsize=(5.2 * cols, 4.2 * nrows), squeeze=False)
    for ax, seq in zip(axes.flat, seqs):
        mine = [r for r in rows if r.sequence == seq and getattr(r, attr) is not None]
        mine.sort(key=lambda r: -(r.auc or 0.0) if attr == "curve" else -(r.precision_at or 0.0))
        for r in mine:
            ax.plot(x, getattr(r, attr), _STYLE.get(r.kind, "-"), lw=2.0 if r.kind == "tracker" else 1.2,
                    color=colour.get(r.tracker, "0.5"), label=label(r))
        ax.set_title(f"{title}: {seq}")
        ax.set_xlabel(xlabel)
        ax.set_ylabel(ylabel)
        ax.set_xlim(x[0], x[-1])
        ax.set_ylim(0, 1.02)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="best")
    for ax in list(axes.flat)[len(seqs):]:
        ax.axis("off")
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    save_figure_new(fig, path, 100)  # never over a file, nothing left of a save cut short
    plt.close(fig)


def plot_success(rows: list[Row], path: str) -> None:
    """The OTB success plot: success rate against overlap threshold, one subplot per sequence,
    one curve per tracker, AUC in the legend."""
    _plot(rows, path, "curve", OVERLAP_THRESHOLDS, "overlap threshold", "success rate",
          lambda r: f"{r.tracker} [{r.auc:.3f}]", "success plot")


def plot_precision(rows: list[Row], path: str) -> None:
    """The OTB precision plot: fraction of frames within a centre error, precision at 20 px in the legend."""
    def label(r: Row) -> str:
        assert r.precision_at is not None  # _plot labels only the rows that have the curve it draws
        return f"{r.tracker} [{r.precision_at:.3f}]"

    _plot(rows, path, "precision", PRECISION_THRESHOLDS, "location error threshold (px)", "precision", label,
          "precision plot")


def note(text: str) -> None:
    """A progress line on stderr."""
    print(f"benchmark: {text}", file=sys.stderr, flush=True)
