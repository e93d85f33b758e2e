"""A copy of a recording that the Foxglove app reads entirely (``gflow foxglove IN OUT``).

gflow records its own messages as MessagePack, which Foxglove cannot decode. The copy keeps
every message's topic and times and writes:

* the render stage's ``foxglove.CompressedImage`` / ``foxglove.ImageAnnotations`` as
  foxglove-sdk's messages, encoded by the SDK (protobuf) under the SDK's schemas
  (:mod:`pipeline.io.foxglove_messages`);
* ``Frame`` messages as ``foxglove.CompressedImage`` (JPEG or PNG) the same way, so a recording
  without a render stage still shows its video;
* the messages a user plots (estimates: box, pose, ESS, state; errors; heartbeats; control;
  end of stream) as JSON objects, with small arrays as lists and large ones as dtype and
  shape (:func:`pipeline.recording.plain.to_plain`), on schemaless JSON channels;
* nothing of the large binary messages (features, particles, proposals, snapshots, G-flow
  states) nor the end-of-stream markers: they are counted as left out.

The original stays the one to re-run, diff and step; the copy is for looking.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import cv2

from stages.messages import FOXGLOVE_TYPES, Frame, MessageError, decode
from stages.messages_foxglove import CompressedImage, time_of

from pipeline.io.foxglove_messages import sdk_schema, to_sdk
from pipeline.io.mcap_io import iter_records, read_metadata
from pipeline.recording.plain import to_plain

__all__ = ["export_for_foxglove", "ExportSummary", "JSON_TYPES"]

#: gflow message types written as JSON (EndOfStream is left out: on a frames topic it would
#: put a second, schemaless channel beside the images)
JSON_TYPES = ("Estimate", "PoseEstimate", "ErrorReport", "StageStatus", "Control")


@dataclass
class ExportSummary:
    messages: int = 0
    by_topic: dict[str, int] = field(default_factory=dict)
    left_out: dict[str, int] = field(default_factory=dict)


def _image_message(frame: Frame, fmt: str, quality: int) -> CompressedImage | None:
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


def export_for_foxglove(src: str | Path, dst: str | Path, image_format: str = "jpeg",
                        quality: int = 90) -> ExportSummary:
    """Write the Foxglove-readable copy of ``src`` to ``dst`` (see the module docstring)."""
    from mcap.writer import CompressionType, Writer

    out = ExportSummary()
    with open(dst, "wb") as f:
        w = Writer(f, compression=CompressionType.LZ4)
        w.start(profile="", library="gflow foxglove export")
        schemas: dict[str, int] = {}
        channels: dict[tuple[str, str], int] = {}

        def channel(topic: str, fox: str | None) -> int:
            key = (topic, fox or "")
            cid = channels.get(key)
            if cid is None:
                sid = 0
                if fox is not None:
                    sid = schemas.get(fox, 0)
                    if not sid:
                        schema = sdk_schema(fox)
                        sid = schemas[fox] = w.register_schema(schema.name, schema.encoding, schema.data)
                cid = channels[key] = w.register_channel(topic, "protobuf" if fox is not None else "json", sid)
            return cid

        seqs: dict[int, int] = {}
        for r in iter_records(src):
            data: bytes | None = None
            fox: str | None = None
            if r.type in FOXGLOVE_TYPES or r.type == "Frame" or r.type in JSON_TYPES or r.type == "unknown":
                try:
                    msg = decode(r.data)
                except MessageError:
                    msg = None
                if isinstance(msg, Frame):
                    msg = _image_message(msg, image_format, quality)
                if msg is not None and type(msg).__name__ in FOXGLOVE_TYPES:
                    data, fox = to_sdk(msg).encode(), type(msg).__name__
                elif msg is not None and type(msg).__name__ in JSON_TYPES:
                    data = json.dumps(to_plain(msg), allow_nan=False, default=str).encode()
            if data is None:
                out.left_out[r.topic] = out.left_out.get(r.topic, 0) + 1
                continue
            cid = channel(r.topic, fox)
            seqs[cid] = seqs.get(cid, -1) + 1
            w.add_message(cid, log_time=r.log_ns, publish_time=r.publish_ns or r.log_ns, data=data,
                          sequence=seqs[cid])
            out.messages += 1
            out.by_topic[r.topic] = out.by_topic.get(r.topic, 0) + 1
        for name, md in read_metadata(src).items():
            w.add_metadata(name, md)
        w.finish()
    return out
