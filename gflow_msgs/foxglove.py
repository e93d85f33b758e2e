"""Foxglove's well-known image schemas, so a recording opens in Foxglove with no plugin.

These messages are encoded as JSON (bytes become base64 strings, as Foxglove's JSON
schemas say with ``"contentEncoding": "base64"``) and recorded with message encoding
``json`` and schema encoding ``jsonschema`` under Foxglove's schema names
(``foxglove.CompressedImage``, ``foxglove.ImageAnnotations``). Field names and types
follow Foxglove's published JSON schemas (foxglove/schemas, ``schemas/jsonschema``);
``tests/test_foxglove.py`` checks them.

Coordinates: Foxglove puts the image origin at the top-left *corner* of the top-left
pixel; gflow's (x, y) have it at that pixel's *centre*. :func:`point` adds the half pixel.
"""

from __future__ import annotations

from typing import Any

import msgspec

__all__ = ["Time", "Point2", "Color", "PointsAnnotation", "CircleAnnotation", "TextAnnotation", "ImageAnnotations",
           "CompressedImage", "FOXGLOVE_SCHEMAS", "POINTS", "LINE_LOOP", "LINE_STRIP", "LINE_LIST", "point",
           "time_of", "foxglove_schema"]

# foxglove.PointsAnnotationType
POINTS, LINE_LOOP, LINE_STRIP, LINE_LIST = 1, 2, 3, 4


class Time(msgspec.Struct, frozen=True):
    sec: int
    nsec: int


class Point2(msgspec.Struct, frozen=True):
    x: float
    y: float


class Color(msgspec.Struct, frozen=True):
    r: float
    g: float
    b: float
    a: float


class PointsAnnotation(msgspec.Struct, frozen=True):
    timestamp: Time
    type: int
    points: list[Point2]
    outline_color: Color
    outline_colors: list[Color]
    fill_color: Color
    thickness: float


class CircleAnnotation(msgspec.Struct, frozen=True):
    timestamp: Time
    position: Point2
    diameter: float
    thickness: float
    fill_color: Color
    outline_color: Color


class TextAnnotation(msgspec.Struct, frozen=True):
    timestamp: Time
    position: Point2
    text: str
    font_size: float
    text_color: Color
    background_color: Color


class ImageAnnotations(msgspec.Struct, frozen=True):
    """foxglove.ImageAnnotations: circles, points (boxes, particles, contours) and text."""

    circles: list[CircleAnnotation]
    points: list[PointsAnnotation]
    texts: list[TextAnnotation]


class CompressedImage(msgspec.Struct, frozen=True):
    """foxglove.CompressedImage: ``data`` is the encoded image, ``format`` e.g. ``jpeg``."""

    timestamp: Time
    frame_id: str
    data: bytes
    format: str


FOXGLOVE_SCHEMAS: dict[type, str] = {
    CompressedImage: "foxglove.CompressedImage",
    ImageAnnotations: "foxglove.ImageAnnotations",
}


def point(x: float, y: float) -> Point2:
    """A gflow (x, y) point (origin: centre of the top-left pixel) in Foxglove's convention."""
    return Point2(float(x) + 0.5, float(y) + 0.5)


def time_of(stamp_ns: int) -> Time:
    return Time(sec=int(stamp_ns // 1_000_000_000), nsec=int(stamp_ns % 1_000_000_000))


def _inline(schema: dict[str, Any]) -> dict[str, Any]:
    """Replace every ``$ref`` by its definition (Foxglove's schemas have none)."""
    defs = schema.get("$defs", {})

    def walk(node: Any) -> Any:
        if isinstance(node, dict):
            if "$ref" in node:
                return walk(defs[node["$ref"].rsplit("/", 1)[-1]])
            return {k: walk(v) for k, v in node.items() if k != "$defs"}
        if isinstance(node, list):
            return [walk(v) for v in node]
        return node

    return walk(schema)


def foxglove_schema(typ: type) -> dict[str, Any]:
    """The JSON schema recorded for a Foxglove message: msgspec's, inlined, titled with the
    Foxglove name (msgspec already marks bytes with ``contentEncoding: base64``)."""
    s = _inline(msgspec.json.schema(typ))
    s["title"] = FOXGLOVE_SCHEMAS[typ]
    return s
