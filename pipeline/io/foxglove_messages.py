"""The render stage's messages as foxglove-sdk's, for the Foxglove app: ``gflow view`` logs them on
the SDK's channels and ``gflow foxglove`` writes them with the SDK's schemas.

The render stage (``stages/overlay.py``) keeps its output in the stage layer's own message
types (``gflow_msgs/foxglove.py``: plain msgspec structs, no I/O library), recorded as
JSON so that a recording re-runs bit for bit and gflow's tools read it as they read any other
message. Where the messages leave gflow for Foxglove, this module converts them to the SDK's
well-known messages (``foxglove.messages.CompressedImage`` / ``ImageAnnotations``), which the
SDK encodes as protobuf with its own schemas: no schema is written by hand on that path.
"""

from __future__ import annotations

from typing import Any

import foxglove
from foxglove import messages as fm

from gflow_msgs.messages import Frame, MessageError
from gflow_msgs.foxglove import (CircleAnnotation, Color, CompressedImage, ImageAnnotations, Point2,
                                      PointsAnnotation, TextAnnotation, Time, time_of)

__all__ = ["to_sdk", "sdk_schema", "SDK_TYPES", "frame_image", "BOX_TOPIC"]

#: the topic beside ``frames`` on which ``gflow view`` and ``gflow foxglove`` put the estimate's
#: box as ``foxglove.ImageAnnotations`` (whatever made the run: no render stage is needed)
BOX_TOPIC = "box"

#: gflow's message type name -> the SDK's message type
SDK_TYPES: dict[str, Any] = {"CompressedImage": fm.CompressedImage, "ImageAnnotations": fm.ImageAnnotations}


#: the SDK's points annotation types by number (foxglove.PointsAnnotationType)
_POINTS_TYPE = {t.value: t for t in (fm.PointsAnnotationType.Unknown, fm.PointsAnnotationType.Points,
                                     fm.PointsAnnotationType.LineLoop, fm.PointsAnnotationType.LineStrip,
                                     fm.PointsAnnotationType.LineList)}


def _time(t: Time) -> fm.Timestamp:
    return fm.Timestamp(t.sec, t.nsec)


def _point(p: Point2) -> fm.Point2:
    return fm.Point2(x=p.x, y=p.y)


def _color(c: Color) -> fm.Color:
    return fm.Color(r=c.r, g=c.g, b=c.b, a=c.a)


def _points(p: PointsAnnotation) -> fm.PointsAnnotation:
    return fm.PointsAnnotation(timestamp=_time(p.timestamp), type=_POINTS_TYPE[p.type],
                               points=[_point(q) for q in p.points], outline_color=_color(p.outline_color),
                               outline_colors=[_color(c) for c in p.outline_colors],
                               fill_color=_color(p.fill_color), thickness=p.thickness)


def _text(t: TextAnnotation) -> fm.TextAnnotation:
    return fm.TextAnnotation(timestamp=_time(t.timestamp), position=_point(t.position), text=t.text,
                             font_size=t.font_size, text_color=_color(t.text_color),
                             background_color=_color(t.background_color))


def to_sdk(msg: CompressedImage | ImageAnnotations) -> Any:
    """The SDK's message with the same content (``.encode()`` gives its protobuf bytes)."""
    if isinstance(msg, CompressedImage):
        return fm.CompressedImage(timestamp=_time(msg.timestamp), frame_id=msg.frame_id, data=msg.data,
                                  format=msg.format)
    if isinstance(msg, ImageAnnotations):
        # the SDK's annotations carry a time of their own: the frame's, which every annotation has
        annotations: list[PointsAnnotation | CircleAnnotation | TextAnnotation] = [*msg.points, *msg.circles,
                                                                                   *msg.texts]
        first = next(iter(annotations), None)
        return fm.ImageAnnotations(
            timestamp=_time(first.timestamp) if first is not None else None,
            circles=[fm.CircleAnnotation(timestamp=_time(c.timestamp), position=_point(c.position), diameter=c.diameter,
                                         thickness=c.thickness, fill_color=_color(c.fill_color),
                                         outline_color=_color(c.outline_color)) for c in msg.circles],
            points=[_points(p) for p in msg.points], texts=[_text(t) for t in msg.texts])
    raise TypeError(f"not a Foxglove message of the render stage: {type(msg).__name__}")


def sdk_schema(type_name: str) -> foxglove.Schema:
    """The SDK's schema (name ``foxglove.<Type>``, protobuf) of gflow's message type ``type_name``."""
    return SDK_TYPES[type_name].get_schema()


def frame_image(frame: Frame, fmt: str = "jpeg", quality: int = 90) -> CompressedImage | None:
    """A frame as a ``foxglove.CompressedImage`` (JPEG or PNG), stamped with the frame's time;
    None when its image cannot be read or encoded."""
    import cv2

    try:
        img = frame.image.array()
    except MessageError:
        return None
    ok, buf = (cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, quality]) if fmt == "jpeg"
               else cv2.imencode(".png", img))
    if not ok:
        return None
    return CompressedImage(timestamp=time_of(frame.header.stamp_ns), frame_id=frame.header.stream,
                           data=buf.tobytes(), format=fmt)
