"""The render stage's messages match Foxglove's published JSON schemas (foxglove/schemas,
schemas/jsonschema/CompressedImage.json and ImageAnnotations.json): names, fields, types; and
every one of them reaches foxglove-sdk's message of the same name whole (what ``gflow view`` and
``gflow foxglove`` send to the Foxglove app)."""

from __future__ import annotations

import base64
import json

import cv2
import numpy as np

from pipeline.runtime.build import apply_defaults
from pipeline.runtime.graph import load_graph
from pipeline.runtime.inline import run_inline
from pipeline.io.mcap_io import iter_records
from gflow_msgs.foxglove import CompressedImage, ImageAnnotations, foxglove_schema

# The published schemas, reduced to their structure: property -> JSON type (or nested structure).
TIME = {"sec": "integer", "nsec": "integer"}
POINT2 = {"x": "number", "y": "number"}
COLOR = {"r": "number", "g": "number", "b": "number", "a": "number"}
PUBLISHED = {
    "foxglove.CompressedImage": {"timestamp": TIME, "frame_id": "string", "data": "string", "format": "string"},
    "foxglove.ImageAnnotations": {
        "circles": [{"timestamp": TIME, "position": POINT2, "diameter": "number", "thickness": "number",
                     "fill_color": COLOR, "outline_color": COLOR}],
        "points": [{"timestamp": TIME, "type": "integer", "points": [POINT2], "outline_color": COLOR,
                    "outline_colors": [COLOR], "fill_color": COLOR, "thickness": "number"}],
        "texts": [{"timestamp": TIME, "position": POINT2, "text": "string", "font_size": "number",
                   "text_color": COLOR, "background_color": COLOR}],
    },
}


def _structure(schema: dict):
    t = schema.get("type")
    if t == "object":
        return {k: _structure(v) for k, v in schema["properties"].items()}
    if t == "array":
        return [_structure(schema["items"])]
    return t


def _conforms(value, spec) -> bool:
    if isinstance(spec, dict):
        return isinstance(value, dict) and set(value) <= set(spec) and all(_conforms(value[k], spec[k]) for k in value)
    if isinstance(spec, list):
        return isinstance(value, list) and all(_conforms(v, spec[0]) for v in value)
    return {"integer": lambda v: isinstance(v, int) and not isinstance(v, bool),
            "number": lambda v: isinstance(v, (int, float)) and not isinstance(v, bool),
            "string": lambda v: isinstance(v, str)}[spec](value)


def test_schemas_have_foxglove_names_fields_and_types():
    for typ in (CompressedImage, ImageAnnotations):
        s = foxglove_schema(typ)
        assert s["title"] in PUBLISHED
        assert _structure(s) == PUBLISHED[s["title"]]
        assert "$ref" not in json.dumps(s)  # inlined, as Foxglove's are
    assert foxglove_schema(CompressedImage)["properties"]["data"]["contentEncoding"] == "base64"


def test_recorded_render_messages_conform_and_decode(tmp_path):
    rec = tmp_path / "demo.mcap"
    plan = apply_defaults(load_graph("demo", overrides={"source": {"frames": 5}, "filter": {"particles": 100}}))
    run_inline(plan, recording=str(rec))
    seen = {}
    for r in iter_records(rec):
        if r.schema.startswith("foxglove."):
            obj = json.loads(r.data)
            assert _conforms(obj, PUBLISHED[r.schema]), (r.schema, obj)
            seen[r.schema] = seen.get(r.schema, 0) + 1
            if r.schema == "foxglove.CompressedImage":
                img = cv2.imdecode(np.frombuffer(base64.b64decode(obj["data"]), np.uint8), cv2.IMREAD_COLOR)
                assert img.shape == (240, 320, 3) and obj["format"] == "jpeg"
            else:
                types = {p["type"] for p in obj["points"]}
                assert {1, 2} <= types  # particles / contour as POINTS, boxes as LINE_LOOP
                assert obj["texts"] and obj["texts"][0]["text"].startswith("frame ")
    assert seen == {"foxglove.CompressedImage": 5, "foxglove.ImageAnnotations": 5}
    channels = {(r.topic, r.schema) for r in iter_records(rec) if r.schema.startswith("foxglove.")}
    assert channels == {("gflow/demo/image", "foxglove.CompressedImage"),
                        ("gflow/demo/annotations", "foxglove.ImageAnnotations")}


def test_independent_reader_sees_json_foxglove_channels(tmp_path):
    from tests.conftest import read_mcap_js

    rec = tmp_path / "demo.mcap"
    plan = apply_defaults(load_graph("demo", overrides={"source": {"frames": 3}, "filter": {"particles": 50}}))
    run_inline(plan, recording=str(rec))
    js = read_mcap_js(rec)
    assert js["topics"]["gflow/demo/image"] == {"count": 3, "encoding": "json", "schemas": ["foxglove.CompressedImage"]}
    assert js["topics"]["gflow/demo/annotations"]["schemas"] == ["foxglove.ImageAnnotations"]
    assert js["topics"]["gflow/demo/estimate"]["encoding"] == "msgpack"


def test_every_render_message_reaches_the_sdk_message_whole(tmp_path):
    """Each recorded render message, converted to foxglove-sdk's message and decoded with the SDK's
    schema (as Foxglove decodes it), equals the recorded one field for field."""
    import msgspec

    from gflow_msgs.messages import decode
    from gflow_msgs.foxglove import FOXGLOVE_SCHEMAS
    from tests.foxglove_protobuf import decode_with_schema

    from pipeline.io.foxglove_messages import sdk_schema, to_sdk

    rec = tmp_path / "demo.mcap"
    plan = apply_defaults(load_graph("demo", overrides={"source": {"frames": 4}, "filter": {"particles": 60},
                                                        "render": {"particles": True}}))
    run_inline(plan, recording=str(rec))
    n = 0
    for r in iter_records(rec):
        if not r.schema.startswith("foxglove."):
            continue
        msg = decode(r.data)
        schema = sdk_schema(r.type)
        assert schema.name == r.schema == FOXGLOVE_SCHEMAS[type(msg)] and schema.encoding == "protobuf"
        got = decode_with_schema(schema.name, schema.data, to_sdk(msg).encode())
        if isinstance(msg, ImageAnnotations):  # the SDK's annotations have a time of their own: the frame's
            assert got.pop("timestamp") == msgspec.to_builtins(msg.texts[0].timestamp)
            assert len(msg.points) >= 3
        assert got == msgspec.to_builtins(msg, builtin_types=(bytes,)), r.type
        n += 1
    assert n == 8
