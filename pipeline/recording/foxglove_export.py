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
* every estimate's box (and the ground truth a synthetic frame carries) as
  ``foxglove.ImageAnnotations`` on ``gflow/<stream>/box``, stamped with its frame, so an Image
  panel on ``frames`` draws the box whatever made the run (the render stage's overlays of
  :func:`gflow_msgs.annotations.estimate_annotations`, without particles);
* nothing of the large binary messages (features, particles, proposals, snapshots, G-flow
  states) nor the end-of-stream markers: they are counted as left out, by topic and apart.

The original stays the one to re-run, diff and step; the copy is for looking.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

from gflow_msgs.messages import FOXGLOVE_TYPES, Estimate, Frame, MessageError, PoseEstimate, decode
from gflow_msgs.annotations import estimate_annotations

from pipeline.io.foxglove_messages import BOX_TOPIC, frame_image, sdk_schema, to_sdk
from pipeline.io.mcap_io import iter_records, read_metadata
from pipeline.recording.plain import to_plain

__all__ = ["export_for_foxglove", "ExportSummary", "JSON_TYPES"]

#: gflow message types written as JSON (EndOfStream is left out: on a frames topic it would
#: put a second, schemaless channel beside the images)
JSON_TYPES = ("Estimate", "PoseEstimate", "ErrorReport", "StageStatus", "Control")


@dataclass
class ExportSummary:
    """What the copy holds: ``by_topic`` its messages per topic (``.../box``: the annotations made
    from the estimates), ``left_out`` the messages not copied per topic (end-of-stream markers
    apart, in ``markers``)."""

    messages: int = 0
    by_topic: dict[str, int] = field(default_factory=dict)
    left_out: dict[str, int] = field(default_factory=dict)
    markers: int = 0  # end-of-stream markers, not copied


def export_for_foxglove(src: str | Path, dst: IO[bytes], image_format: str = "jpeg",
                        quality: int = 90, topics: list[str] | None = None) -> ExportSummary:
    """Write the Foxglove-readable copy of ``src`` into the binary file ``dst`` (see the module docstring);
    with ``topics``, of those topics only (exact names). The caller names the file: ``gflow foxglove`` writes
    it beside its name and moves it there once whole."""
    from mcap.writer import CompressionType, Writer

    out = ExportSummary()
    w = Writer(dst, compression=CompressionType.LZ4)
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

    def put(topic: str, fox: str | None, data: bytes, log_ns: int, publish_ns: int) -> None:
        cid = channel(topic, fox)
        seqs[cid] = seqs.get(cid, -1) + 1
        w.add_message(cid, log_time=log_ns, publish_time=publish_ns or log_ns, data=data, sequence=seqs[cid])
        out.messages += 1
        out.by_topic[topic] = out.by_topic.get(topic, 0) + 1

    frames: dict[tuple[str, int], tuple[int, object]] = {}  # (stream, seq) -> the frame's stamp and truth
    for r in iter_records(src, topics=topics):
        data: bytes | None = None
        fox: str | None = None
        msg = None
        if r.type in FOXGLOVE_TYPES or r.type == "Frame" or r.type in JSON_TYPES or r.type in ("unknown",
                                                                                               "EndOfStream"):
            try:
                msg = decode(r.data)
            except MessageError:
                msg = None
            if isinstance(msg, Frame):
                frames[(msg.header.stream, msg.header.seq)] = (msg.header.stamp_ns, msg.truth)
                msg = frame_image(msg, image_format, quality)
            if msg is not None and type(msg).__name__ in FOXGLOVE_TYPES:
                data, fox = to_sdk(msg).encode(), type(msg).__name__
            elif msg is not None and type(msg).__name__ in JSON_TYPES:
                data = json.dumps(to_plain(msg), allow_nan=False, default=str).encode()
        if data is None:
            if type(msg).__name__ == "EndOfStream":
                out.markers += 1
            else:
                out.left_out[r.topic] = out.left_out.get(r.topic, 0) + 1
            continue
        put(r.topic, fox, data, r.log_ns, r.publish_ns)
        if isinstance(msg, (Estimate, PoseEstimate)):  # its box over its frame
            stamp, truth = frames.pop((msg.header.stream, msg.header.seq), (msg.header.stamp_ns, None))
            box_topic = r.topic.rsplit("/", 1)[0] + "/" + BOX_TOPIC
            put(box_topic, "ImageAnnotations", to_sdk(estimate_annotations(msg, stamp, truth)).encode(),
                r.log_ns, r.publish_ns)
    for name, md in read_metadata(src).items():
        w.add_metadata(name, md)
    w.finish()
    return out
