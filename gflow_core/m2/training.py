"""Training items for M2 from frames in memory (Toyama & Blake 2002, sec. 4.1 and 5.1).

The paper learns exemplars from a fixed-camera training sequence: "simple background
subtraction and edge-detection routines" separate the foreground, whose edges become
the training curves, "approximately aligned from the outset". Two paths are provided:

* unsupervised (the paper's): :func:`median_background`, :func:`foreground_mask` (threshold
  on the difference from a median background, morphological opening and closing, largest
  connected component), then :func:`curves_from_background`: Canny edges of the frame
  masked by the dilated foreground, centred on the foreground centroid;
* supervised, from ground-truth boxes (x, y, w, h): :func:`curves_from_boxes` (Canny edges
  inside the box, optionally masked by the foreground) and :func:`patches_from_boxes`,
  centred on the box centre and scaled to a common reference box size; plus
  :func:`patches_from_frames` for pre-cropped video such as the mouth sequences (sec. 5.2).

Each returns a :class:`TrainingSet`: items in their own frame (points relative to the
reference point, (x, y) pixels, origin at the top-left pixel centre) and the *placement*
transform alpha_t with image point = T_alpha_t(item point), which is the starting
estimate of the state alpha_t used to learn dynamics.

Frames with no usable foreground are skipped (their index is kept in ``frame_index``,
so dynamics are not learned across the gap); if none is usable a ValueError says why.
Curves are subsampled to at most ``max_points`` points evenly along raster order.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, Sequence

import cv2
import numpy as np

from .. import similarity
from ..features import edge_map, to_grey
from .curves import Curves, subsample_points
from .edge_settings import BLUR, CANNY_HIGH, CANNY_LOW

__all__ = ["TrainingSet", "median_background", "foreground_mask", "curves_from_background", "curves_from_boxes",
           "patches_from_boxes", "patches_from_frames", "concat_training_sets", "check_frames"]


@dataclass(frozen=True)
class TrainingSet:
    """Training items with their image placement.

    Attributes
    ----------
    items : Curves (N curves) or (N, h, w) float64 patches.
    placement : (N, 4) float64, alpha_t = (ux, uy, theta, s): image point = T_alpha_t(item point).
    frame_index : (N,) int64, the frame each item came from.
    sequence : (N,) int64, sequence id (dynamics are learned within a sequence only).
    ref_size : (2,) float64, (w, h) of the reference box in item coordinates (s = 1).
    kind : "curve" or "patch".
    """

    items: Curves | np.ndarray
    placement: np.ndarray
    frame_index: np.ndarray
    sequence: np.ndarray
    ref_size: np.ndarray
    kind: Literal["curve", "patch"]

    def __post_init__(self) -> None:
        n = len(self.items)
        pl = similarity.check_alpha(np.asarray(self.placement, dtype=np.float64).reshape(-1, 4))
        fi = np.asarray(self.frame_index, dtype=np.int64)
        sq = np.asarray(self.sequence, dtype=np.int64)
        rs = np.asarray(self.ref_size, dtype=np.float64)
        if pl.shape != (n, 4) or fi.shape != (n,) or sq.shape != (n,):
            raise ValueError(f"placement, frame_index and sequence must have {n} rows")
        if rs.shape != (2,) or not (rs > 0).all():
            raise ValueError(f"ref_size must be (2,) positive, got {rs}")
        if self.kind not in ("curve", "patch"):
            raise ValueError(f"kind must be 'curve' or 'patch', got {self.kind!r}")
        object.__setattr__(self, "placement", pl)
        object.__setattr__(self, "frame_index", fi)
        object.__setattr__(self, "sequence", sq)
        object.__setattr__(self, "ref_size", rs)

    def __len__(self) -> int:
        return len(self.items)


def check_frames(frames: Sequence[np.ndarray] | np.ndarray, min_frames: int = 1) -> list[np.ndarray]:
    """Validate frames: a non-empty sequence of same-shape (H, W) or (H, W, 3) images."""
    if frames is None or len(frames) == 0:
        raise ValueError("no training frames given")
    out = [np.asarray(f) for f in frames]
    shape = out[0].shape
    for i, f in enumerate(out):
        if f.ndim not in (2, 3) or f.shape[0] < 2 or f.shape[1] < 2:
            raise ValueError(f"frame {i} must be (H, W) or (H, W, C), got shape {f.shape}")
        if f.shape != shape:
            raise ValueError(f"frame {i} has shape {f.shape}, expected {shape} like frame 0")
        if f.dtype.kind == "f" and not np.isfinite(f).all():
            raise ValueError(f"frame {i} contains NaN or inf")
    if len(out) < min_frames:
        raise ValueError(f"need at least {min_frames} frames, got {len(out)}")
    return out


def median_background(frames: Sequence[np.ndarray] | np.ndarray, max_frames: int = 60) -> np.ndarray:
    """Per-pixel median over (at most ``max_frames`` evenly spaced) frames: the static background.

    Parameters
    ----------
    frames : T frames (H, W) or (H, W, 3), same shape.
    max_frames : int, frames used for the median.

    Returns
    -------
    (H, W) or (H, W, 3) float64
    """
    fr = check_frames(frames)
    pick = np.unique(np.linspace(0, len(fr) - 1, min(len(fr), max_frames)).round().astype(np.intp))
    return np.median(np.stack([fr[i].astype(np.float64) for i in pick]), axis=0)


def _disk(radius: int) -> np.ndarray:
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))


def foreground_mask(frame: np.ndarray, background: np.ndarray, threshold: float = 30.0, open_radius: int = 1,
                    close_radius: int = 4, min_area: int = 50, largest: bool = True) -> np.ndarray:
    """Foreground by background subtraction: |frame - background| > threshold, cleaned up.

    Parameters
    ----------
    frame, background : (H, W) or (H, W, 3), same shape; the difference is the maximum over channels.
    threshold : float, grey levels.
    open_radius, close_radius : int, radii (pixels) of the opening (removes specks) and
        closing (fills gaps) with a disc.
    min_area : int, components smaller than this are discarded.
    largest : bool, keep only the largest component (one target).

    Returns
    -------
    (H, W) bool, all False if nothing passes.
    """
    f = np.asarray(frame, dtype=np.float64)
    b = np.asarray(background, dtype=np.float64)
    if f.shape != b.shape:
        raise ValueError(f"frame {f.shape} and background {b.shape} differ in shape")
    diff = np.abs(f - b)
    if diff.ndim == 3:
        diff = diff.max(axis=2)
    m: np.ndarray = (diff > threshold).astype(np.uint8)
    if open_radius > 0:
        m = cv2.morphologyEx(m, cv2.MORPH_OPEN, _disk(open_radius))
    if close_radius > 0:
        m = cv2.morphologyEx(m, cv2.MORPH_CLOSE, _disk(close_radius))
    n, lab, stats, _ = cv2.connectedComponentsWithStats(m, connectivity=8)
    if n <= 1:
        return np.zeros(m.shape, dtype=bool)
    areas = stats[1:, cv2.CC_STAT_AREA]
    if largest:
        k = int(np.argmax(areas))
        return (lab == k + 1) if areas[k] >= min_area else np.zeros(m.shape, dtype=bool)
    keep = np.nonzero(areas >= min_area)[0] + 1
    return np.isin(lab, keep)


def _edge_points(grey: np.ndarray, mask: np.ndarray | None, canny: tuple[float, float, float]) -> np.ndarray:
    edges = edge_map(grey, *canny)
    if mask is not None:
        edges = np.where(mask, edges, 0)
    rows, cols = np.nonzero(edges)
    return np.stack([cols, rows], axis=1).astype(np.float64)


def curves_from_background(frames: Sequence[np.ndarray] | np.ndarray, background: np.ndarray | None = None, *,
                           threshold: float = 30.0, open_radius: int = 1, close_radius: int = 4,
                           min_area: int = 50, dilate: int = 3, max_points: int = 200, min_points: int = 10,
                           canny_low: float = CANNY_LOW, canny_high: float = CANNY_HIGH, blur: float = BLUR,
                           sequence: int = 0, first_frame: int = 0) -> TrainingSet:
    """The paper's training curves: edges of the background-subtracted foreground (sec. 5.1).

    Parameters
    ----------
    frames : T frames of a fixed camera, (H, W) or (H, W, 3) uint8 (BGR).
    background : optional background image; default :func:`median_background` of ``frames``.
    threshold, open_radius, close_radius, min_area : see :func:`foreground_mask`.
    dilate : int, the foreground mask is dilated by this many pixels before masking the
        Canny edges (so the silhouette's own boundary edges are kept).
    max_points : int, points per curve (evenly subsampled).
    min_points : int, frames with fewer edge points are skipped.
    canny_low, canny_high, blur : Canny parameters (:func:`gflow_core.features.edge_map`).
    sequence, first_frame : int, sequence id and index of ``frames[0]``.

    Returns
    -------
    TrainingSet of curves centred on the foreground centroid; placement (cx, cy, 0, 1);
    ref_size = median foreground bounding box (w, h).

    Raises
    ------
    ValueError
        No frames, or no frame with a foreground of at least ``min_area`` pixels and
        ``min_points`` edge points.
    """
    fr = check_frames(frames)
    bg = median_background(fr) if background is None else np.asarray(background, dtype=np.float64)
    curves, place, idx, sizes = [], [], [], []
    kernel = _disk(dilate) if dilate > 0 else None
    for t, f in enumerate(fr):
        mask = foreground_mask(f, bg, threshold, open_radius, close_radius, min_area)
        if not mask.any():
            continue
        wide = cv2.dilate(mask.astype(np.uint8), kernel) > 0 if kernel is not None else mask
        pts = _edge_points(to_grey(f), wide, (canny_low, canny_high, blur))
        if pts.shape[0] < min_points:
            continue
        rows, cols = np.nonzero(mask)
        centre = np.array([cols.mean(), rows.mean()])
        curves.append(subsample_points(pts, max_points) - centre)
        place.append([centre[0], centre[1], 0.0, 1.0])
        idx.append(first_frame + t)
        sizes.append([cols.max() - cols.min() + 1.0, rows.max() - rows.min() + 1.0])
    if not curves:
        raise ValueError(f"no foreground found in any of the {len(fr)} training frames (threshold {threshold}, "
                         f"min_area {min_area}, min_points {min_points}); is the camera fixed and the target moving?")
    return TrainingSet(items=Curves.from_list(curves), placement=np.array(place), frame_index=np.array(idx),
                       sequence=np.full(len(idx), sequence), ref_size=np.median(np.array(sizes), axis=0),
                       kind="curve")


def _check_boxes(boxes: np.ndarray, n: int) -> np.ndarray:
    b = np.asarray(boxes, dtype=np.float64)
    if b.shape != (n, 4):
        raise ValueError(f"need one box (x, y, w, h) per frame: expected shape ({n}, 4), got {b.shape}")
    return b


def _box_scale(b: np.ndarray, ref: np.ndarray) -> float:
    # s = sqrt(w h / (w_ref h_ref)): a similarity has one scale for both axes
    return float(np.sqrt(b[2] * b[3] / (ref[0] * ref[1])))


def curves_from_boxes(frames: Sequence[np.ndarray] | np.ndarray, boxes: np.ndarray, *, max_points: int = 200,
                      min_points: int = 10, ref_size: tuple[float, float] | None = None,
                      background: np.ndarray | None = None, threshold: float = 30.0, dilate: int = 3,
                      canny_low: float = CANNY_LOW, canny_high: float = CANNY_HIGH, blur: float = BLUR,
                      frame_index: np.ndarray | None = None, sequence: int = 0) -> TrainingSet:
    """Supervised training curves: Canny edges inside ground-truth boxes, roughly aligned by the box.

    Parameters
    ----------
    frames : T frames (H, W) or (H, W, 3) uint8.
    boxes : (T, 4) float64, (x, y, w, h) top-left corner and size; rows with NaN or
        non-positive size are skipped.
    max_points, min_points : see :func:`curves_from_background`.
    ref_size : (w, h) of the reference box; default the median box size.
    background : optional background image; if given, edges are also masked by the dilated
        foreground (:func:`foreground_mask` with ``threshold``), removing background clutter.
    frame_index : (T,) int64, default 0..T-1.

    Returns
    -------
    TrainingSet; item point = (image point - box centre) / s_t with s_t = sqrt(w h / (w_ref h_ref)),
    placement (cx, cy, 0, s_t).
    """
    fr = check_frames(frames)
    b = _check_boxes(boxes, len(fr))
    fi = np.arange(len(fr)) if frame_index is None else np.asarray(frame_index, dtype=np.int64)
    ok = np.isfinite(b).all(axis=1) & (b[:, 2] > 0) & (b[:, 3] > 0)
    if not ok.any():
        raise ValueError("no valid ground-truth box (all NaN or empty)")
    ref = np.median(b[ok, 2:], axis=0) if ref_size is None else np.asarray(ref_size, dtype=np.float64)
    kernel = _disk(dilate) if dilate > 0 else None
    curves, place, idx = [], [], []
    for t in np.nonzero(ok)[0]:
        f = fr[t]
        x, y, w, h = b[t]
        H, W = f.shape[:2]
        mask = np.zeros((H, W), dtype=bool)
        c0, r0 = max(int(np.floor(x)), 0), max(int(np.floor(y)), 0)
        c1, r1 = min(int(np.ceil(x + w)), W), min(int(np.ceil(y + h)), H)
        if c0 >= c1 or r0 >= r1:
            continue
        mask[r0:r1, c0:c1] = True
        if background is not None:
            fg = foreground_mask(f, background, threshold, largest=False)
            if kernel is not None:
                fg = cv2.dilate(fg.astype(np.uint8), kernel) > 0
            mask &= fg
        pts = _edge_points(to_grey(f), mask, (canny_low, canny_high, blur))
        if pts.shape[0] < min_points:
            continue
        centre = np.array([x + (w - 1) / 2.0, y + (h - 1) / 2.0])
        s = _box_scale(b[t], ref)
        curves.append((subsample_points(pts, max_points) - centre) / s)
        place.append([centre[0], centre[1], 0.0, s])
        idx.append(fi[t])
    if not curves:
        raise ValueError(f"no edge points inside any of the {int(ok.sum())} boxes (min_points {min_points}); "
                         "lower the Canny thresholds")
    return TrainingSet(items=Curves.from_list(curves), placement=np.array(place), frame_index=np.array(idx),
                       sequence=np.full(len(idx), sequence), ref_size=ref, kind="curve")


def patches_from_boxes(frames: Sequence[np.ndarray] | np.ndarray, boxes: np.ndarray, shape: tuple[int, int], *,
                       frame_index: np.ndarray | None = None, sequence: int = 0) -> TrainingSet:
    """Supervised training patches: the grey box contents resampled to ``shape`` = (rows, cols).

    The patch pixel spacing is s_t = sqrt(w h / (cols rows)) image pixels, the patch centre
    the box centre: patch(r) = grey(T_alpha_t r), alpha_t = (cx, cy, 0, s_t)
    (:func:`gflow_core.similarity.warp_patch`). Returns float64 grey levels.
    """
    fr = check_frames(frames)
    b = _check_boxes(boxes, len(fr))
    rows, cols = (int(v) for v in shape)
    if rows < 1 or cols < 1:
        raise ValueError(f"patch shape must be positive, got {shape}")
    fi = np.arange(len(fr)) if frame_index is None else np.asarray(frame_index, dtype=np.int64)
    ok = np.isfinite(b).all(axis=1) & (b[:, 2] > 0) & (b[:, 3] > 0)
    if not ok.any():
        raise ValueError("no valid ground-truth box (all NaN or empty)")
    patches, place = [], []
    for t in np.nonzero(ok)[0]:
        x, y, w, h = b[t]
        alpha = np.array([x + (w - 1) / 2.0, y + (h - 1) / 2.0, 0.0, _box_scale(b[t], np.array([cols, rows]))])
        patches.append(similarity.warp_patch(to_grey(fr[t]), alpha, (rows, cols)).astype(np.float64))
        place.append(alpha)
    return TrainingSet(items=np.stack(patches), placement=np.array(place), frame_index=fi[ok],
                       sequence=np.full(int(ok.sum()), sequence), ref_size=np.array([cols, rows], dtype=np.float64),
                       kind="patch")


def patches_from_frames(frames: Sequence[np.ndarray] | np.ndarray, shape: tuple[int, int] | None = None, *,
                        frame_index: np.ndarray | None = None, sequence: int = 0) -> TrainingSet:
    """Pre-cropped, registered frames (e.g. mouths, sec. 5.2) as patches, optionally resized.

    Parameters
    ----------
    frames : T frames (H, W) or (H, W, 3).
    shape : (rows, cols), optional; frames are resized with area averaging.

    Returns
    -------
    TrainingSet of (T, rows, cols) float64 grey patches; placement centres the patch on the
    frame with s = H / rows.
    """
    fr = check_frames(frames)
    H, W = fr[0].shape[:2]
    rows, cols = (H, W) if shape is None else (int(shape[0]), int(shape[1]))
    if rows < 1 or cols < 1:
        raise ValueError(f"patch shape must be positive, got {shape}")
    out = np.empty((len(fr), rows, cols))
    for t, f in enumerate(fr):
        g = to_grey(f)
        if (rows, cols) != (H, W):
            g = cv2.resize(g.astype(np.float32), (cols, rows), interpolation=cv2.INTER_AREA)
        out[t] = g
    fi = np.arange(len(fr)) if frame_index is None else np.asarray(frame_index, dtype=np.int64)
    s = np.sqrt(H * W / (rows * cols))
    place = np.tile([(W - 1) / 2.0, (H - 1) / 2.0, 0.0, s], (len(fr), 1))
    return TrainingSet(items=out, placement=place, frame_index=fi, sequence=np.full(len(fr), sequence),
                       ref_size=np.array([cols, rows], dtype=np.float64), kind="patch")


def concat_training_sets(sets: Sequence[TrainingSet]) -> TrainingSet:
    """Several training sequences as one set (give each a distinct ``sequence`` id).

    Curves are re-padded to a common length; ref_size is the mean of the inputs'.
    """
    if not sets:
        raise ValueError("no training sets to concatenate")
    kinds = {s.kind for s in sets}
    if len(kinds) != 1:
        raise ValueError("cannot mix curve and patch training sets")
    if kinds == {"curve"}:
        items: Curves | np.ndarray = Curves.from_list([c for s in sets for c in _as_curves(s.items).to_list()])
    else:
        patches = [np.asarray(s.items) for s in sets]
        shapes = {p.shape[1:] for p in patches}
        if len(shapes) != 1:
            raise ValueError(f"patch sizes differ between training sets: {shapes}")
        items = np.concatenate(patches)
    return TrainingSet(items=items, placement=np.concatenate([s.placement for s in sets]),
                       frame_index=np.concatenate([s.frame_index for s in sets]),
                       sequence=np.concatenate([s.sequence for s in sets]),
                       ref_size=np.mean([s.ref_size for s in sets], axis=0), kind=kinds.pop())


def _as_curves(items: Curves | np.ndarray) -> Curves:
    """The items of a curve training set (its kind says they are curves)."""
    assert isinstance(items, Curves)
    return items
