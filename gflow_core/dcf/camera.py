"""The camera's own motion from frame t-1 to frame t, estimated from the background (``camera_motion``).

A jolt of the camera, a roll of the camera and a zoom move the target in the image as much as its
own motion does, and the constant-velocity prediction knows nothing of them: a 45 px jolt puts the
target three standard deviations of the motion prior away, a roll of the whole frame decorrelates the
upright filter. The background tells them apart from the target's own motion. Multi-object trackers
compensate the camera's motion before the Kalman prediction (BoT-SORT, Aharon, Orfaig & Bobrovsky
2022, sec. 3.2 "camera motion compensation", after the global motion compensation of video
stabilisation): corners of the frame t-1 (Shi & Tomasi's minimum eigenvalue,
``cv2.goodFeaturesToTrack``), tracked to frame t by pyramidal Lucas-Kanade, and a similarity
(rotation, uniform scale, translation; 4 degrees of freedom) fitted to their displacements by
RANSAC, x_t = A x_{t-1} + b with A = s R(phi):

    A = [[s cos phi, -s sin phi], [s sin phi, s cos phi]],   (eq. 1)

and the state's prediction moved through it. :func:`estimate` gives (A, b) and the inliers; the
tracker (:func:`gflow_core.dcf.tracker.step`) moves the last estimate's centre and the proposal's
particles through it, adds log s to their log size, turns the velocity by A and adds phi to the
target's held roll (:mod:`.rotation`: the window is sampled rolled by it).

Departures from BoT-SORT's ``GMC`` (its sparse optical-flow mode):

* the corners are taken outside the target's box widened by ``MARGIN`` of its sides each way (BoT-SORT
  masks no box in that mode): the target's own motion is what must not be in the fit;
* every track is checked forward and backward (the forward-backward error of Kalal et al., ICPR 2010,
  at most ``MAX_FB`` px), not only by LK's status;
* the fit is refused, and the camera taken as still (the identity), with fewer than ``MIN_INLIERS``
  inliers, or fewer than ``MIN_SHARE`` of the points tracked both ways: a frame whose background is
  flat, blurred or mostly moving says nothing reliable of the camera; and a fit that moves no corner of
  the frame by ``MIN_MOTION`` px is taken as a still camera (the fit's own noise, some 0.05 px on a still
  frame, would only jitter the state); its roll is kept only beyond ``MIN_ROLL`` (1 degree) and its zoom
  beyond ``MIN_ZOOM`` (2 %, the scale filter's own step), each with ``SIMILARITY_INLIERS`` inliers or more,
  else the motion is the fit's shift at the target's centre: small rolls and zooms add up (david_indoor's
  fits zoomed out by 0.26 % a frame on average, -1.66 in log size over the sequence, and the box shrank
  from 46 to 19 px wide; a few dozen points on surfer's water gave rolls of 1-3 degrees a frame that were
  not there);
* frames are not downscaled (BoT-SORT halves them); each point is tracked from no motion and, when the
  frames' phase correlation (Kuglin & Hines 1975) finds a shift of a pixel or more, from that shift too,
  the track that comes back closer kept: a 50 px jolt of a fine texture was beyond the ``LEVELS``-level
  pyramid alone;
* BoT-SORT transforms the Kalman state's (x, y, w, h) and velocities by the 2 x 2 part; here the place
  goes through the similarity, the log size adds log s, the velocity turns by A, and the rotation is
  handed to the target's roll (BoT-SORT has no roll);
* BoT-SORT compensates every frame; the tracker leaves a shift within the motion prior's std (with no
  roll or zoom) to the prior, since the fit's own errors would enter the prediction in full (skating1's
  panning camera, followed frame by frame, lost the skater: AUC 0.335 against 0.604), and compensates
  nothing while the target is judged hidden (the camera is taken to follow it) or while its box is not
  inside the frame.

Deterministic: OpenCV's RANSAC seeds its own generator on every call, so the same two frames give the
same bits in every call and in another process (checked by ``tests/core/test_dcf_camera.py``), and no
draw comes from the tracker's streams; phase correlation is a Fourier transform, LK tracks every point
alone.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

__all__ = ["CameraMotion", "IDENTITY", "estimate", "grey8", "MAX_CORNERS", "MARGIN", "MIN_INLIERS", "MIN_SHARE",
           "MIN_MOTION", "MIN_ROLL", "MIN_ZOOM", "SIMILARITY_INLIERS", "MAX_FB", "THRESHOLD", "WINDOW", "LEVELS"]

#: corners at most, their quality relative to the best (Shi & Tomasi) and their least distance apart, px
MAX_CORNERS, QUALITY, MIN_DISTANCE = 300, 0.01, 7
#: the target's box is widened by this many times its sides each way before its corners are masked out
MARGIN = 0.5
#: Lucas-Kanade's window (px per side) and pyramid levels beyond the frame's own
WINDOW, LEVELS = 21, 4
#: px, the frames' width at most for the phase correlation that guesses a jolt (halved until within it)
SHIFT_WIDTH = 200
#: px, the forward-backward error above which a point's track is dropped
MAX_FB = 1.0
#: px, RANSAC's reprojection threshold: a point within it of the fitted similarity is an inlier
THRESHOLD = 1.5
#: the fit is refused with fewer inliers than MIN_INLIERS, or than MIN_SHARE of the points tracked both ways
MIN_INLIERS, MIN_SHARE = 20, 0.5
#: px: a fit that moves no corner of the frame by this much is a still camera (the identity)
MIN_MOTION = 0.5
#: the fit's roll (radians) and zoom (log scale) are kept only beyond these and with SIMILARITY_INLIERS inliers
#: or more; else the camera's motion is the fit's shift at the target's centre
MIN_ROLL, MIN_ZOOM, SIMILARITY_INLIERS = math.radians(1.0), 0.02, 100

_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 0.01)


@dataclass(frozen=True)
class CameraMotion:
    """The camera's similarity from frame t-1 to t: ``matrix`` (2, 3) float64 [A | b], x_t = A x_{t-1} + b
    (eq. 1), and ``inliers`` the points that agree with it (0: refused, the identity)."""

    matrix: np.ndarray
    inliers: int

    @property
    def still(self) -> bool:
        """Whether the camera is taken as still: the identity (a refused fit, or a motion below MIN_MOTION)."""
        return bool((self.matrix == IDENTITY.matrix).all())

    @property
    def linear(self) -> np.ndarray:
        """(2, 2) A = s R(phi)."""
        return self.matrix[:, :2]

    @property
    def angle(self) -> float:
        """phi, radians: the frame's roll (positive turns it clockwise on the screen, y down)."""
        return math.atan2(float(self.matrix[1, 0]), float(self.matrix[0, 0]))

    @property
    def log_scale(self) -> float:
        """log s: the frame's zoom."""
        # s = sqrt(det A) for A = s R(phi)
        return 0.5 * math.log(max(float(np.linalg.det(self.linear)), 1e-12))

    def apply(self, pts: np.ndarray) -> np.ndarray:
        """(N, 2) float64 the points (N, 2) (x, y) of frame t-1 moved to frame t: A x + b."""
        # x_t = A x_{t-1} + b   (eq. 1)
        return pts @ self.linear.T + self.matrix[:, 2]


#: no motion: what a refused fit gives
IDENTITY = CameraMotion(np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]), 0)


def grey8(grey: np.ndarray) -> np.ndarray:
    """The (H, W) grey levels as uint8 (what Lucas-Kanade reads)."""
    return np.clip(np.rint(grey), 0, 255).astype(np.uint8)


def _mask(shape: tuple[int, int], box: tuple[float, float, float, float]) -> np.ndarray:
    """(H, W) uint8: 255 where corners may be taken, 0 on ``box`` (x, y, w, h) widened by MARGIN of its sides
    each way."""
    H, W = shape
    x, y, w, h = box
    m = np.full((H, W), 255, np.uint8)
    x0, x1 = int(max(math.floor(x - MARGIN * w), 0)), int(min(math.ceil(x + w + MARGIN * w), W))
    y0, y1 = int(max(math.floor(y - MARGIN * h), 0)), int(min(math.ceil(y + h + MARGIN * h), H))
    if x1 > x0 and y1 > y0:
        m[y0:y1, x0:x1] = 0
    return m


def _shift(prev: np.ndarray, cur: np.ndarray) -> np.ndarray:
    """(2,) float64 the frame's global shift (dx, dy) from ``prev`` to ``cur`` by phase correlation (Kuglin &
    Hines 1975) under a Hann window: the peak of the inverse transform of the normalised cross-power spectrum,
    on the frames halved (Gaussian pyramid) until at most SHIFT_WIDTH px wide (a guess for Lucas-Kanade)."""
    f = 1.0
    while prev.shape[1] > SHIFT_WIDTH:
        prev, cur, f = cv2.pyrDown(prev), cv2.pyrDown(cur), 2.0 * f
    win = cv2.createHanningWindow((prev.shape[1], prev.shape[0]), cv2.CV_64F)
    (dx, dy), _ = cv2.phaseCorrelate(prev.astype(np.float64), cur.astype(np.float64), win)
    return f * np.array([dx, dy])


def _lk(prev: np.ndarray, cur: np.ndarray, p0: np.ndarray, guess: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The points (N, 1, 2) float32 ``p0`` of ``prev`` tracked to ``cur`` by pyramidal Lucas-Kanade from the
    initial flow ``guess`` (2,) px, and back: ((N, 2) float64 where they landed, (N,) their forward-backward
    error, inf for a point lost either way)."""
    win = (WINDOW, WINDOW)
    flags = cv2.OPTFLOW_USE_INITIAL_FLOW
    # forward p0 -> p1 on (t-1, t) from p0 + guess, backward p1 -> p0b on (t, t-1) from p0
    p1, st1, _ = cv2.calcOpticalFlowPyrLK(prev, cur, p0, (p0 + guess.astype(np.float32)).copy(), winSize=win,
                                          maxLevel=LEVELS, criteria=_CRITERIA, flags=flags)
    p0b, st2, _ = cv2.calcOpticalFlowPyrLK(cur, prev, p1, p0.copy(), winSize=win, maxLevel=LEVELS,
                                           criteria=_CRITERIA, flags=flags)
    b, back = p1[:, 0].astype(np.float64), p0b[:, 0].astype(np.float64)
    ok = (st1[:, 0] == 1) & (st2[:, 0] == 1) & np.isfinite(b).all(axis=1) & np.isfinite(back).all(axis=1)
    # forward-backward error |p0 - p0b| (Kalal et al. 2010, eq. 1)
    fb = np.where(ok, np.hypot(*(p0[:, 0].astype(np.float64) - np.where(ok[:, None], back, 0.0)).T), np.inf)
    return b, fb


def _tracks(prev: np.ndarray, cur: np.ndarray, p0: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The corners (N, 1, 2) float32 ``p0`` of ``prev`` tracked to ``cur``: ((N, 2) float64 where they started,
    (N, 2) where they landed, (N,) bool whether the track came back within MAX_FB px). Each point is tracked
    from no motion and, when the frame's phase correlation finds a shift of a pixel or more, from that shift
    too (a jolt beyond Lucas-Kanade's pyramid on a fine texture), keeping the track that comes back closer."""
    b, fb = _lk(prev, cur, p0, np.zeros(2))
    shift = _shift(prev, cur)
    if np.hypot(*shift) >= 1.0:
        b2, fb2 = _lk(prev, cur, p0, shift)
        better = fb2 < fb
        b, fb = np.where(better[:, None], b2, b), np.where(better, fb2, fb)
    return p0[:, 0].astype(np.float64), b, fb <= MAX_FB


def _reduced(mo: CameraMotion, box: tuple[float, float, float, float]) -> CameraMotion:
    """The fit ``mo`` with its roll phi dropped when |phi| < MIN_ROLL, its zoom s when |log s| < MIN_ZOOM, and both
    with fewer than SIMILARITY_INLIERS inliers, keeping where it puts the centre c of ``box`` (x, y, w, h): A' =
    s' R(phi'), b' = A c + b - A' c."""
    phi, ls = mo.angle, mo.log_scale
    many = mo.inliers >= SIMILARITY_INLIERS
    phi = phi if many and abs(phi) >= MIN_ROLL else 0.0
    ls = ls if many and abs(ls) >= MIN_ZOOM else 0.0
    c = np.array([box[0] + (box[2] - 1) / 2.0, box[1] + (box[3] - 1) / 2.0])
    # A' = s' R(phi')   (eq. 1)
    a = math.exp(ls) * np.array([[math.cos(phi), -math.sin(phi)], [math.sin(phi), math.cos(phi)]])
    # b' = A c + b - A' c: the target's centre goes where the fit puts it
    b = mo.apply(c[None, :])[0] - a @ c
    return CameraMotion(np.column_stack([a, b]), mo.inliers)


def estimate(prev: np.ndarray, cur: np.ndarray, box: tuple[float, float, float, float]) -> CameraMotion:
    """The background's similarity from frame t-1 to frame t.

    Parameters
    ----------
    prev, cur : (H, W) uint8 grey frames t-1 and t.
    box : the target's box (x, y, w, h) in frame t-1, px: no corner is taken within MARGIN of its sides.

    Returns
    -------
    The similarity and its inliers (module docstring), or :data:`IDENTITY` when the fit is refused.
    """
    if prev.shape != cur.shape or prev.dtype != np.uint8 or cur.dtype != np.uint8 or prev.ndim != 2:
        raise ValueError(f"camera motion needs two (H, W) uint8 frames of one size, got {prev.shape} and {cur.shape}")
    p0 = cv2.goodFeaturesToTrack(prev, MAX_CORNERS, QUALITY, MIN_DISTANCE, mask=_mask(prev.shape, box))
    if p0 is None or len(p0) < MIN_INLIERS:
        return IDENTITY
    a, b, ok = _tracks(prev, cur, p0.astype(np.float32))
    n = int(ok.sum())
    if n < MIN_INLIERS:
        return IDENTITY
    # the similarity [A | b] minimising the inliers' squared residuals, by RANSAC then Levenberg-Marquardt
    m, inl = cv2.estimateAffinePartial2D(a[ok], b[ok], method=cv2.RANSAC, ransacReprojThreshold=THRESHOLD,
                                         maxIters=2000, confidence=0.995, refineIters=10)
    k = 0 if inl is None else int(inl.sum())
    if m is None or not np.isfinite(m).all() or k < MIN_INLIERS or k < MIN_SHARE * n:
        return IDENTITY
    mo = _reduced(CameraMotion(np.asarray(m, dtype=np.float64), k), box)
    H, W = prev.shape
    corners = np.array([[0.0, 0.0], [W - 1.0, 0.0], [0.0, H - 1.0], [W - 1.0, H - 1.0]])
    # a still camera: max_corners |A x + b - x| < MIN_MOTION (below the fit's noise, which would only jitter the state)
    if np.hypot(*(mo.apply(corners) - corners).T).max() < MIN_MOTION:
        return CameraMotion(IDENTITY.matrix, k)
    return mo
