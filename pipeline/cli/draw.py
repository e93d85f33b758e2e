"""Draw Foxglove ImageAnnotations into images with OpenCV, for ``gflow render``."""

from __future__ import annotations

import cv2
import numpy as np

from gflow_msgs.foxglove import LINE_LIST, LINE_LOOP, LINE_STRIP, POINTS, Color, ImageAnnotations

__all__ = ["draw_annotations"]

_SHIFT = 4  # sub-pixel drawing: coordinates in 1/16 pixel


def _bgr(c: Color) -> tuple[int, int, int]:
    return int(round(c.b * 255)), int(round(c.g * 255)), int(round(c.r * 255))


def _fixed(x: float, y: float) -> tuple[int, int]:
    # Foxglove's origin is the top-left corner of the top-left pixel; OpenCV's is its centre
    return int(round((x - 0.5) * (1 << _SHIFT))), int(round((y - 0.5) * (1 << _SHIFT)))


def _blend(img: np.ndarray, overlay: np.ndarray, alpha: float) -> None:
    cv2.addWeighted(overlay, alpha, img, 1 - alpha, 0, dst=img)


def draw_annotations(img: np.ndarray, ann: ImageAnnotations, scale: int = 1) -> np.ndarray:
    """Return a copy of ``img`` (H, W, 3) uint8 BGR with the annotations drawn, upscaled by ``scale``."""
    out = cv2.resize(img, None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST) if scale != 1 else img.copy()
    for p in ann.points:
        pts = np.array([_fixed(q.x * scale, q.y * scale) for q in p.points], dtype=np.int32)
        if pts.size == 0:
            continue
        layer = out.copy()
        colour = _bgr(p.outline_color)
        th = max(1, int(round(p.thickness)))
        if p.type == POINTS:
            r = max(1, int(round(p.thickness * scale / 2))) << _SHIFT
            for q in pts:
                cv2.circle(layer, (int(q[0]), int(q[1])), r, colour, -1, cv2.LINE_AA, _SHIFT)
        elif p.type in (LINE_LOOP, LINE_STRIP):
            cv2.polylines(layer, [pts.reshape(-1, 1, 2)], p.type == LINE_LOOP, colour, th, cv2.LINE_AA, _SHIFT)
        elif p.type == LINE_LIST:
            for a, b in zip(pts[0::2], pts[1::2]):
                cv2.line(layer, tuple(map(int, a)), tuple(map(int, b)), colour, th, cv2.LINE_AA, _SHIFT)
        _blend(out, layer, p.outline_color.a)
    for c in ann.circles:
        layer = out.copy()
        cx, cy = _fixed(c.position.x * scale, c.position.y * scale)
        cv2.circle(layer, (cx, cy), int(c.diameter * scale / 2) << _SHIFT, _bgr(c.outline_color),
                   max(1, int(c.thickness)), cv2.LINE_AA, _SHIFT)
        _blend(out, layer, c.outline_color.a)
    for t in ann.texts:
        x, y = int(t.position.x * scale), int(t.position.y * scale)
        fs = t.font_size * scale / 36.0
        (tw, th), base = cv2.getTextSize(t.text, cv2.FONT_HERSHEY_SIMPLEX, fs, 1)
        if t.background_color.a > 0:
            layer = out.copy()
            cv2.rectangle(layer, (x - 2, y - th - 3), (x + tw + 2, y + base), _bgr(t.background_color), -1)
            _blend(out, layer, t.background_color.a)
        cv2.putText(out, t.text, (x, y), cv2.FONT_HERSHEY_SIMPLEX, fs, _bgr(t.text_color), 1, cv2.LINE_AA)
    return out
