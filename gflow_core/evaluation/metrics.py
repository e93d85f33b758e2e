"""Tracking accuracy: centre location error, overlap (IoU) and success rate.

Boxes are (x, y, w, h): top-left corner and size in 0-based pixels, as in ``../shared/data``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["centre_error", "iou", "TrackScore", "score", "OVERLAP_THRESHOLDS", "success_curve", "precision_curve",
           "size_kept", "auc", "place_and_size", "TARGET_STATES", "HIDDEN_BELOW", "overlaps", "frames_to_recover",
           "StateScore", "state_score", "CONFIDENCE_BANDS", "band_json", "band_text"]

#: overlap thresholds of the OTB success plot (Wu, Lim & Yang, CVPR 2013); its AUC is the mean over them
OVERLAP_THRESHOLDS = np.linspace(0.0, 1.0, 21)


def _boxes(b: np.ndarray, name: str) -> np.ndarray:
    b = np.asarray(b, dtype=np.float64)
    if b.ndim != 2 or b.shape[1] != 4:
        raise ValueError(f"{name} boxes must be (N, 4) = (x, y, w, h), got shape {b.shape}")
    if not np.isfinite(b).all():
        raise ValueError(f"{name} boxes contain NaN or inf")
    neg = np.flatnonzero((b[:, 2:] < 0).any(axis=1))
    if neg.size:
        # a box reaching back from its corner would be scored with its centre on the wrong side of it
        raise ValueError(f"{name} box {int(neg[0])} has a negative width or height ({b[neg[0], 2]:g} x "
                         f"{b[neg[0], 3]:g}): a box of no size is w = 0 or h = 0")
    return b


def centre_error(gt: np.ndarray, pred: np.ndarray) -> np.ndarray:
    """Distance between box centres, (N,) pixels. gt, pred: (N, 4)."""
    g, p = _boxes(gt, "ground-truth"), _boxes(pred, "predicted")
    # c = (x + w/2, y + h/2)
    cg = g[:, :2] + g[:, 2:] / 2.0
    cp = p[:, :2] + p[:, 2:] / 2.0
    return np.linalg.norm(cg - cp, axis=1)


def iou(gt: np.ndarray, pred: np.ndarray) -> np.ndarray:
    """Intersection over union, (N,) in [0, 1]. gt, pred: (N, 4)."""
    g, p = _boxes(gt, "ground-truth"), _boxes(pred, "predicted")
    x0 = np.maximum(g[:, 0], p[:, 0])
    y0 = np.maximum(g[:, 1], p[:, 1])
    x1 = np.minimum(g[:, 0] + g[:, 2], p[:, 0] + p[:, 2])
    y1 = np.minimum(g[:, 1] + g[:, 3], p[:, 1] + p[:, 3])
    inter = np.clip(x1 - x0, 0, None) * np.clip(y1 - y0, 0, None)
    union = np.clip(g[:, 2], 0, None) * np.clip(g[:, 3], 0, None) + np.clip(p[:, 2], 0, None) * np.clip(p[:, 3], 0, None) - inter
    return np.where(union > 0, inter / np.where(union > 0, union, 1.0), 0.0)


@dataclass(frozen=True)
class TrackScore:
    frames: int
    cle: float
    mean_overlap: float
    success: float
    missing: int

    def to_json(self) -> dict:
        return {"frames": self.frames, "cle_px": round(self.cle, 3), "mean_overlap": round(self.mean_overlap, 4),
                "success_rate_0.5": round(self.success, 4), "missing_predictions": self.missing}


def score(gt: dict[int, tuple], pred: dict[int, tuple], threshold: float = 0.5) -> TrackScore:
    """Score predictions against ground truth over the frames that have ground truth.

    A frame with ground truth but no prediction counts as a failure (overlap 0) and is
    left out of the CLE, which is averaged over the frames that have both.
    """
    frames = sorted(gt)
    if not frames:
        raise ValueError("ground truth is empty")
    both = [f for f in frames if f in pred]
    if not both:
        raise ValueError("no frame has both a ground-truth box and a prediction (are the frame numbers aligned?)")
    g = np.array([gt[f] for f in both])
    p = np.array([pred[f] for f in both])
    ov = iou(g, p)
    missing = len(frames) - len(both)
    overlaps = np.concatenate([ov, np.zeros(missing)])
    return TrackScore(frames=len(frames), cle=float(centre_error(g, p).mean()), mean_overlap=float(overlaps.mean()),
                      success=float((overlaps > threshold).mean()), missing=missing)


def _per_frame(gt: dict[int, tuple], pred: dict[int, tuple]) -> tuple[np.ndarray, np.ndarray]:
    """Overlap and centre error on every ground-truth frame, (F,) each; a frame without a
    prediction has overlap 0 and centre error inf."""
    frames = sorted(gt)
    if not frames:
        raise ValueError("ground truth is empty")
    g = np.array([gt[f] for f in frames], dtype=np.float64)
    has = np.array([f in pred for f in frames])
    p = np.array([pred.get(f, gt[f]) for f in frames], dtype=np.float64)
    ov = np.where(has, iou(g, p), 0.0)
    err = np.where(has, centre_error(g, p), np.inf)
    return ov, err


def success_curve(gt: dict[int, tuple], pred: dict[int, tuple],
                  thresholds: np.ndarray = OVERLAP_THRESHOLDS) -> np.ndarray:
    """Success rate (fraction of ground-truth frames with overlap > t) for each threshold t, (T,).

    Frames without a prediction count as failures, as in :func:`score` (whose success rate is
    this curve at t = 0.5). The area under the curve is its mean over ``OVERLAP_THRESHOLDS``.
    """
    ov, _ = _per_frame(gt, pred)
    return (ov[None, :] > np.asarray(thresholds, dtype=np.float64)[:, None]).mean(axis=1)


def precision_curve(gt: dict[int, tuple], pred: dict[int, tuple], thresholds: np.ndarray) -> np.ndarray:
    """Precision (fraction of ground-truth frames with centre error <= t pixels) per threshold, (T,)."""
    _, err = _per_frame(gt, pred)
    return (err[None, :] <= np.asarray(thresholds, dtype=np.float64)[:, None]).mean(axis=1)


def size_kept(gt: dict[int, tuple], pred: dict[int, tuple], factor: float = 2.0) -> float | None:
    """Fraction of the frames where the tracker is on target (its box overlaps the true one,
    IoU > 0) on which the box's area is within ``factor`` of the true area: 1/f <= a / a* <= f.

    A box that collapses (or balloons) while its centre stays on the target fails this even
    when the centre error looks moderate. None when the tracker is never on target.
    """
    frames = [f for f in sorted(gt) if f in pred]
    if not frames:
        return None
    g = np.array([gt[f] for f in frames], dtype=np.float64)
    p = np.array([pred[f] for f in frames], dtype=np.float64)
    on = iou(g, p) > 0
    if not on.any():
        return None
    # a / a* = (w h) / (w* h*)
    ratio = (p[on, 2] * p[on, 3]) / np.maximum(g[on, 2] * g[on, 3], 1e-12)
    return float(np.mean((ratio >= 1.0 / factor) & (ratio <= factor)))


def auc(gt: dict[int, tuple], pred: dict[int, tuple]) -> float:
    """The area under the success plot (the OTB headline): the mean of :func:`success_curve` over
    ``OVERLAP_THRESHOLDS``."""
    return float(success_curve(gt, pred).mean())


def place_and_size(gt: dict[int, tuple], pred: dict[int, tuple]) -> tuple[dict[int, tuple], dict[int, tuple]]:
    """The predicted boxes with one of their two errors taken away, to tell which costs the overlap: (the truth's
    size at each predicted centre: the place's error alone, the predicted size at the truth's centre: the size's
    error alone), on the frames that have both a true and a predicted box. Scored by :func:`auc`, each is the AUC the
    tracker would have with its size, or its place, right."""
    place: dict[int, tuple] = {}
    size: dict[int, tuple] = {}
    for f in sorted(gt.keys() & pred.keys()):
        gx, gy, gw, gh = (float(v) for v in gt[f])
        px, py, pw, ph = (float(v) for v in pred[f])
        # centres c = (x + w / 2, y + h / 2); a box of size (w', h') at centre c is (c_x - w' / 2, c_y - h' / 2, w', h')
        place[f] = (px + pw / 2.0 - gw / 2.0, py + ph / 2.0 - gh / 2.0, gw, gh)
        size[f] = (gx + gw / 2.0 - pw / 2.0, gy + gh / 2.0 - ph / 2.0, pw, ph)
    return place, size


#: the target states a tracker reports: seen in its box, hidden where it is expected, searched for
TARGET_STATES = ("tracked", "occluded", "lost")

#: a target with less than this fraction of its box in view counts as hidden
HIDDEN_BELOW = 0.1


def overlaps(gt: dict[int, tuple], pred: dict[int, tuple]) -> np.ndarray:
    """Overlap (IoU) on every ground-truth frame in frame order, (F,); 0 where there is no prediction."""
    return _per_frame(gt, pred)[0]


def frames_to_recover(overlap: np.ndarray, start: int, threshold: float = 0.5, hold: int = 5,
                      frames: ArrayLike | None = None) -> int | None:
    """Frames from ``start`` to the first of ``hold`` frames in a row with overlap above
    ``threshold`` (0: on target from ``start`` on); None if that never happens.

    Parameters
    ----------
    overlap : (F,) per-frame overlap in frame order.
    start : the first index to look from (e.g. the first frame after a perturbation); with
        ``frames``, the first frame number.
    threshold, hold : what "on target" means: IoU > threshold for ``hold`` frames in a row
        (fewer if the sequence ends first, as long as it ends on target).
    frames : (F,) increasing frame numbers of the entries, where only some frames are scored
        (sparse ground truth); then a run is the scored frames in a row on target, and it holds
        once it spans ``hold`` frames (from its first frame to its last). None: entry i is frame i.
    """
    ov = np.asarray(overlap, dtype=np.float64)
    if ov.ndim != 1:
        raise ValueError(f"overlap must be (F,), got shape {ov.shape}")
    f = np.arange(ov.shape[0]) if frames is None else np.asarray(frames, dtype=np.int64)
    if f.shape != ov.shape:
        raise ValueError(f"frames {f.shape} and overlap {ov.shape} must have the same shape")
    if frames is None and not 0 <= start <= ov.shape[0]:
        raise ValueError(f"start {start} is outside 0..{ov.shape[0]}")
    first = int(np.searchsorted(f, start))
    run = 0
    for i in range(first, ov.shape[0]):
        run = run + 1 if ov[i] > threshold else 0
        if run and (f[i] - f[i - run + 1] + 1 >= hold or i == ov.shape[0] - 1):
            j = i - run + 1
            return 0 if j == first else int(f[j] - start)
    return None


#: the inner edges of the confidence bands a state score counts frames on target in:
#: [0, 0.25), [0.25, 0.5), [0.5, 0.75), [0.75, 0.95), [0.95, 1]
CONFIDENCE_BANDS = (0.25, 0.5, 0.75, 0.95)


@dataclass(frozen=True)
class StateScore:
    """How often a tracker's ``state`` was right.

    hidden : frames where the target was hidden (less than ``HIDDEN_BELOW`` of it in view),
        after the first few of each hidden stretch; hidden_right : of those, reported
        ``occluded`` or ``lost``.
    shown : undisturbed frames (the target in view and nothing perturbed); shown_right : of
        those, reported ``tracked``.
    off : frames with the target in view whose box missed it (overlap at or below the success
        threshold), scored when the overlaps are given; off_tracked : of those, reported
        ``tracked`` -- the box is off the target and the output does not say so (lower is better).
    shown_on : of the ``shown`` frames, those with the box on the target (overlap above the success
        threshold; every shown frame when the overlaps are not given); shown_on_tracked : of those,
        reported ``tracked``. A miss here is a state that is wrong: the box is right and the output
        says it is not.
    shown_off : of the ``shown`` frames, those with the box off the target (overlap at or below the
        threshold); shown_off_hidden : of those, reported ``occluded`` or ``lost``. A frame counted
        here is one ``shown_rate`` counts as wrong although the state is honest: the box is what
        is wrong (the tracker did not find the target again).
        ``shown_right = shown_on_tracked + (shown_off - shown_off_hidden - frames with no state)``.
    bands : per band of :data:`CONFIDENCE_BANDS`, (frames with the target in view, of those with
        the box on it), scored when the confidences and overlaps are given: how far a user may
        trust a confidence (it is P(visible), not a calibrated P(on target)).
    """

    hidden: int
    hidden_right: int
    shown: int
    shown_right: int
    off: int = 0
    off_tracked: int = 0
    bands: tuple[tuple[int, int], ...] = ()
    shown_on: int = 0
    shown_on_tracked: int = 0
    shown_off: int = 0
    shown_off_hidden: int = 0

    @property
    def hidden_rate(self) -> float | None:
        return _rate(self.hidden_right, self.hidden)

    @property
    def shown_rate(self) -> float | None:
        return _rate(self.shown_right, self.shown)

    @property
    def off_rate(self) -> float | None:
        return _rate(self.off_tracked, self.off)

    @property
    def shown_on_rate(self) -> float | None:
        return _rate(self.shown_on_tracked, self.shown_on)

    @property
    def shown_off_rate(self) -> float | None:
        return _rate(self.shown_off_hidden, self.shown_off)

    def to_json(self) -> dict:
        r = [None if x is None else round(x, 4)
             for x in (self.hidden_rate, self.shown_rate, self.off_rate, self.shown_on_rate, self.shown_off_rate)]
        return {"hidden_frames": self.hidden, "hidden_reported_occluded_or_lost": r[0],
                "undisturbed_frames": self.shown, "undisturbed_reported_tracked": r[1],
                "off_target_frames": self.off, "off_target_reported_tracked": r[2],
                "undisturbed_on_target_frames": self.shown_on, "undisturbed_on_target_reported_tracked": r[3],
                "undisturbed_off_target_frames": self.shown_off,
                "undisturbed_off_target_reported_occluded_or_lost": r[4],
                "confidence_bands": band_json(self.bands)}


def _rate(count: int, frames: int) -> float | None:
    """``count / frames``, or None when no frame was scored."""
    return count / frames if frames else None


def band_json(bands: tuple[tuple[int, int], ...] | list[list[int]]) -> list[dict]:
    """Per confidence band (:data:`CONFIDENCE_BANDS`): its range, frames with the target in view, and
    of those the share with the box on it."""
    edges = (0.0, *CONFIDENCE_BANDS, 1.0)
    return [{"from": edges[i], "to": edges[i + 1], "frames": int(n), "on_target": None if n == 0 else round(k / n, 4)}
            for i, (n, k) in enumerate(bands)]


def band_text(bands: list[dict]) -> str:
    """One line of :func:`band_json`'s bands that hold frames: ``"0.00-0.25 0.63 of 1260; ..."``."""
    return "; ".join(f"{b['from']:.2f}-{b['to']:.2f} {b['on_target']:.2f} of {b['frames']}" for b in bands if b["frames"])


def state_score(states: list[str | None], visible: ArrayLike, perturbed: ArrayLike | None = None,
                grace: int = 5, hidden_below: float = HIDDEN_BELOW, overlap: ArrayLike | None = None,
                threshold: float = 0.5, confidence: ArrayLike | None = None,
                frames: ArrayLike | None = None) -> StateScore:
    """Score reported target states against how much of the target was in view.

    Parameters
    ----------
    states : (F,) the state reported on each frame (``"tracked"``, ``"occluded"``, ``"lost"``;
        None where the tracker gave none, which counts as wrong).
    visible : (F,) float, fraction of the target in view on each frame.
    perturbed : (F,) bool, frames changed by a perturbation; None: a frame is undisturbed when
        the whole target is in view.
    grace : the first ``grace`` frames of each hidden stretch are not scored (a tracker cannot
        know at once that the target went behind something).
    hidden_below : a frame is hidden when less than this fraction of the target is in view.
    overlap : (F,) the box's overlap (IoU) with the truth on each frame (:func:`overlaps`); with it,
        the frames with the target in view and overlap at or below ``threshold`` are scored for
        whether they were reported ``tracked`` (``off``, ``off_tracked``), and the undisturbed frames
        are split by whether the box is on the target (``shown_on``, ``shown_off``).
    confidence : (F,) the confidence reported on each frame (NaN where none); with ``overlap``, the
        frames with the target in view are counted per confidence band (``bands``).
    frames : (F,) increasing frame numbers of the entries, where only some frames are scored
        (sparse ground truth): ``grace`` then counts frames from the first scored frame of a
        hidden stretch. None: entry i is frame i.
    """
    vis = np.asarray(visible, dtype=np.float64)
    if vis.ndim != 1 or len(states) != vis.shape[0]:
        raise ValueError(f"states ({len(states)}) and visible {vis.shape} must both be one value per frame")
    bad = sorted({s for s in states if s is not None and s not in TARGET_STATES})
    if bad:
        raise ValueError(f"unknown target state {bad[0]!r} (known: {', '.join(TARGET_STATES)})")
    if perturbed is None:
        calm = vis >= 1.0 - 1e-9
    else:
        calm = ~np.asarray(perturbed, dtype=bool)
        if calm.shape != vis.shape:
            raise ValueError(f"perturbed {calm.shape} and visible {vis.shape} must have the same shape")
    hidden = vis < hidden_below
    f = np.arange(vis.shape[0]) if frames is None else np.asarray(frames, dtype=np.int64)
    if f.shape != vis.shape:
        raise ValueError(f"frames {f.shape} and visible {vis.shape} must have the same shape")
    # how many frames each frame is into its hidden stretch
    within = np.zeros(vis.shape[0], dtype=np.int64)
    for i in range(1, vis.shape[0]):
        within[i] = within[i - 1] + int(f[i] - f[i - 1]) if hidden[i] and hidden[i - 1] else 0
    scored_hidden = hidden & (within >= grace)
    said_hidden = np.array([s in ("occluded", "lost") for s in states], dtype=bool)
    said_tracked = np.array([s == "tracked" for s in states], dtype=bool)
    shown = calm & ~hidden
    on = np.ones_like(hidden)
    if overlap is not None:
        ov = np.asarray(overlap, dtype=np.float64)
        if ov.shape != vis.shape:
            raise ValueError(f"overlap {ov.shape} and visible {vis.shape} must have the same shape")
        on = ov > threshold
    off = ~hidden & ~on
    bands: tuple[tuple[int, int], ...] = ()
    if overlap is not None and confidence is not None:
        conf = np.asarray(confidence, dtype=np.float64)
        if conf.shape != vis.shape:
            raise ValueError(f"confidence {conf.shape} and visible {vis.shape} must have the same shape")
        band = np.searchsorted(np.asarray(CONFIDENCE_BANDS), conf, side="right")
        seen = ~hidden & np.isfinite(conf)
        bands = tuple((int((seen & (band == b)).sum()), int((seen & (band == b) & on).sum()))
                      for b in range(len(CONFIDENCE_BANDS) + 1))
    return StateScore(hidden=int(scored_hidden.sum()), hidden_right=int((scored_hidden & said_hidden).sum()),
                      shown=int(shown.sum()), shown_right=int((shown & said_tracked).sum()),
                      off=int(off.sum()), off_tracked=int((off & said_tracked).sum()), bands=bands,
                      shown_on=int((shown & on).sum()), shown_on_tracked=int((shown & on & said_tracked).sum()),
                      shown_off=int((shown & ~on).sum()), shown_off_hidden=int((shown & ~on & said_hidden).sum()))
