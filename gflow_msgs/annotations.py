"""What a frame's estimate looks like: the overlays of one tracker message as Foxglove's
``ImageAnnotations`` (the render stage's ``annotations``, ``gflow render``'s video, ``gflow view`` and
``gflow foxglove``'s box channel).

Drawn: the estimated box (green while the target is tracked, orange while the tracker judges it
occluded, magenta while lost), the ground-truth box when the source knows it (white), the particles'
positions (red) or every G-flow expert's projected vertices (the paper's fig. 2, cyan), the MAP
contour or mean mesh points (yellow), for G-flow the mean pose's rotated axes (x red, y magenta, z
blue, as in fig. 2), and a text line with the frame, ESS, state, the target's state and the
confidence (and a face's yaw, pitch, roll).
"""

from __future__ import annotations

import numpy as np

from .foxglove import (LINE_LIST, LINE_LOOP, POINTS, Color, ImageAnnotations, PointsAnnotation, TextAnnotation, point,
                       time_of)
from .messages import Estimate, Frame, Particles, PoseEstimate

__all__ = ["annotations_for", "estimate_annotations", "STATE_COLOURS", "GREEN", "ORANGE", "MAGENTA"]

GREEN = Color(0.1, 0.9, 0.2, 1.0)
WHITE = Color(1.0, 1.0, 1.0, 0.9)
RED = Color(1.0, 0.2, 0.2, 0.8)
CYAN = Color(0.2, 0.9, 1.0, 0.6)
YELLOW = Color(1.0, 0.9, 0.1, 1.0)
ORANGE = Color(1.0, 0.6, 0.1, 1.0)
MAGENTA = Color(1.0, 0.2, 0.8, 1.0)
CLEAR = Color(0.0, 0.0, 0.0, 0.0)
#: colour of the estimated box by the target's state: seen, hidden where expected, searched for
STATE_COLOURS = {"tracked": GREEN, "occluded": ORANGE, "lost": MAGENTA}
SHADE = Color(0.0, 0.0, 0.0, 0.6)


def _box(b, color: Color, ts, thickness: float = 2.0) -> PointsAnnotation:
    x, y, w, h = (float(v) for v in b)
    # corners of the box around pixel centres x..x+w-1, in pixel-edge coordinates
    pts = [point(x - 0.5, y - 0.5), point(x + w - 0.5, y - 0.5), point(x + w - 0.5, y + h - 0.5),
           point(x - 0.5, y + h - 0.5)]
    return PointsAnnotation(ts, LINE_LOOP, pts, color, [], CLEAR, thickness)


def _points(xy: np.ndarray, color: Color, ts, size: float, limit: int) -> PointsAnnotation:
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    if limit and xy.shape[0] > limit:
        xy = xy[np.linspace(0, xy.shape[0] - 1, limit).round().astype(np.intp)]
    return PointsAnnotation(ts, POINTS, [point(x, y) for x, y in xy], color, [], color, size)


#: the rotated axes x, y, z: red, magenta, blue (green is the box)
AXIS_COLOURS = (Color(1.0, 0.2, 0.2, 1.0), Color(1.0, 0.3, 1.0, 1.0), Color(0.3, 0.5, 1.0, 1.0))


def _axes(est: PoseEstimate, ts) -> list[PointsAnnotation]:
    """The mean pose's rotated model axes from the projected origin ``l``, half the face's scale ``c_1``
    long (the paper's fig. 2): ``l + 0.5 c_1 g r e_a`` for a = x, y, z."""
    r = np.asarray(est.rotation, dtype=np.float64).reshape(3, 3)
    lx, ly, c1 = est.pose[3], est.pose[4], est.pose[5]
    out = []
    for a, colour in enumerate(AXIS_COLOURS):
        ex, ey = 0.5 * abs(c1) * r[0, a], 0.5 * abs(c1) * r[1, a]
        out.append(PointsAnnotation(ts, LINE_LIST, [point(lx, ly), point(lx + ex, ly + ey)], colour, [], colour, 2.0))
    return out


def annotations_for(frame: Frame, est: Estimate | PoseEstimate, particles: Particles | None,
                    max_points: int = 400) -> ImageAnnotations:
    """The overlays of one frame (pure; also used by ``gflow render``)."""
    return estimate_annotations(est, frame.header.stamp_ns, frame.truth, particles, max_points)


def estimate_annotations(est: Estimate | PoseEstimate, stamp_ns: int, truth=None, particles: Particles | None = None,
                         max_points: int = 400) -> ImageAnnotations:
    """The overlays of an estimate on the frame stamped ``stamp_ns`` (ground-truth box ``truth``
    (x, y, w, h) or None): what :func:`annotations_for` draws, also where no render stage ran
    (``gflow view``, ``gflow foxglove`` draw the box over the recorded frames with it)."""
    ts = time_of(stamp_ns)
    pts: list[PointsAnnotation] = []
    if truth is not None:
        pts.append(_box(truth, WHITE, ts, 1.0))
    if isinstance(est, PoseEstimate):
        experts = est.expert_points.array()
        pts.append(_points(experts.reshape(-1, 2), CYAN, ts, 2.0, max_points))
        # a learned face has many vertices close together: smaller dots
        pts.append(_points(est.mean_points.array(), YELLOW, ts, 3.0 if est.landmarks is None else 1.5, 0))
        pts.extend(_axes(est, ts))
        label = f"frame {est.header.seq}  ESS {est.ess:.1f}/{experts.shape[0]}  spread {est.spread_px:.1f}px  {est.state}"
        if est.landmarks is not None:
            label += "  yaw {} pitch {} roll {}".format(*(int(round(v)) for v in est.yaw_pitch_roll))
    else:
        if particles is not None:
            pts.append(_points(particles.alpha.array()[:, :2], RED, ts, 2.0, max_points))
        pts.append(_points(est.contour.array(), YELLOW, ts, 2.0, 0))
        label = f"frame {est.header.seq}  ESS {est.ess:.0f}/{est.n}  k={est.k}  {est.state}"
    pts.append(_box(est.box, STATE_COLOURS.get(est.target_state, GREEN), ts, 2.0))
    label += f"  target {est.target_state} {est.confidence:.2f}"
    text = TextAnnotation(ts, point(4, 14), label, 12.0, WHITE, SHADE)
    return ImageAnnotations(circles=[], points=pts, texts=[text])
