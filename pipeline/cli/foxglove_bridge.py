"""``gflow view``: a live pipeline in the Foxglove app, over Foxglove's WebSocket protocol
(served by the ``foxglove-sdk`` package).

A bridge subscribes to ``gflow/<stream>/**`` on zenoh and republishes, on channels named
like the topics:

* the render stage's ``image`` and ``annotations`` as foxglove-sdk's well-known messages
  ``foxglove.CompressedImage`` / ``foxglove.ImageAnnotations``, on the SDK's typed channels
  (protobuf, with the SDK's schemas: :mod:`pipeline.io.foxglove_messages`): an Image panel
  shows the video with the overlays;
* the messages a user plots (``estimate``: box, pose, ESS, state; ``errors``; every stage's
  heartbeat ``_status/<stage>``; ``_control``) as JSON objects (small arrays as lists, large
  ones as dtype and shape: :func:`pipeline.recording.plain.to_plain`), which the Plot and Raw Messages
  panels read (e.g. ``/gflow/demo/estimate.ess``).

* the source's ``frames`` as ``foxglove.CompressedImage`` (JPEG) and every estimate's box as
  ``foxglove.ImageAnnotations`` on ``box`` (stamped with its frame: what the render stage draws,
  without particles), so an Image panel on ``frames`` with the annotations ``box`` shows any
  run, whatever started it (``gflow track``, ``demo``, ``run``), with or without a render stage.

Features, particles and snapshots (large binary arrays) are not forwarded, nor end-of-stream
markers on an image channel or on a topic nothing else was forwarded on.
"""

from __future__ import annotations

import json
import queue
import threading
import time
from dataclasses import dataclass, field

from gflow_msgs.messages import FOXGLOVE_TYPES, Estimate, Frame, MessageError, PoseEstimate, decode
from gflow_msgs.annotations import estimate_annotations

from pipeline.io.foxglove_messages import BOX_TOPIC, frame_image, to_sdk
from pipeline.recording.plain import to_plain
from pipeline.runtime.transport import Bus, ZenohSettings, open_session

__all__ = ["FoxgloveBridge", "FORWARDED_TYPES"]

#: gflow message types forwarded as JSON (besides the Foxglove image / annotation messages)
FORWARDED_TYPES = ("Estimate", "PoseEstimate", "ErrorReport", "StageStatus", "Control", "EndOfStream")
#: frames remembered (stamp and ground truth) to stamp their estimates' boxes
_FRAMES_KEPT = 256


@dataclass
class FoxgloveBridge:
    """zenoh -> Foxglove WebSocket server. ``start()``, then ``stop()``.

    host / port: where the WebSocket server listens (Foxglove's default is 8765; 0 picks one).
    """

    settings: ZenohSettings
    stream: str | None = None
    host: str = "127.0.0.1"
    port: int = 8765
    forwarded: dict[str, int] = field(default_factory=dict)
    failed: dict[str, str] = field(default_factory=dict)
    dropped: int = 0

    def start(self) -> "FoxgloveBridge":
        import foxglove

        self._fx = foxglove
        self._ctx = foxglove.Context()
        self._channels: dict[str, object] = {}
        self._q: queue.Queue = queue.Queue(maxsize=256)
        self._frames: dict[tuple[str, int], tuple[int, object]] = {}  # (stream, seq) -> stamp, truth
        self._stop = threading.Event()
        self.server = foxglove.start_server(name="gflow", host=self.host, port=self.port, context=self._ctx)
        self.port = self.server.port
        self._session = open_session(self.settings)
        Bus(self._session).subscribe(f"gflow/{self.stream or '*'}/**", self._on_sample, with_type=True)
        self._worker = threading.Thread(target=self._run, name="foxglove-bridge", daemon=True)
        self._worker.start()
        return self

    @property
    def url(self) -> str:
        return f"ws://{self.host}:{self.port}"

    # zenoh's thread: hand over, never block (a slow viewer drops frames, not the pipeline)
    def _on_sample(self, key: str, payload: bytes, pub_ns: int, seq: int, type_name: str) -> None:
        try:
            self._q.put_nowait((key, payload, pub_ns, type_name))
        except queue.Full:
            self.dropped += 1

    def _channel(self, topic: str, type_name: str):
        ch = self._channels.get(topic)
        if ch is None:
            if type_name in FOXGLOVE_TYPES:  # the SDK's typed channel: its schema, its encoding
                from foxglove import channels

                ch = getattr(channels, f"{type_name}Channel")(topic, context=self._ctx)
            else:
                ch = self._fx.Channel(topic, message_encoding="json", context=self._ctx)  # schemaless JSON
            self._channels[topic] = ch
        return ch

    def _log(self, topic: str, type_name: str, body, log_ns: int) -> None:
        self._channel(topic, type_name).log(body, log_time=log_ns)
        self.forwarded[topic] = self.forwarded.get(topic, 0) + 1

    def _forward(self, key: str, payload: bytes, pub_ns: int, type_name: str) -> None:
        topic = "/" + key
        log_ns = pub_ns or time.time_ns()
        if type_name and type_name not in FORWARDED_TYPES and type_name not in FOXGLOVE_TYPES and type_name != "Frame":
            return  # features, particles, snapshots: not decoded at all
        try:
            msg = decode(payload)
        except MessageError:
            return
        name = type(msg).__name__
        if isinstance(msg, Frame):  # the video of any run, as the SDK's image
            self._frames[(msg.header.stream, msg.header.seq)] = (msg.header.stamp_ns, msg.truth)
            while len(self._frames) > _FRAMES_KEPT:
                self._frames.pop(next(iter(self._frames)))
            img = frame_image(msg, "jpeg", 85)
            if img is not None:
                self._log(topic, "CompressedImage", to_sdk(img), log_ns)
        elif name in FOXGLOVE_TYPES:  # the render stage's: as the SDK's message
            self._log(topic, name, to_sdk(msg), log_ns)
        elif name in FORWARDED_TYPES:
            if name == "EndOfStream" and (key.endswith("/frames") or topic not in self._channels):
                return  # not on an image channel (Foxglove reads one schema per topic), nor alone on a topic
            body = json.dumps(to_plain(msg), allow_nan=False, default=str).encode("utf-8")
            self._log(topic, name, body, log_ns)
            if isinstance(msg, (Estimate, PoseEstimate)):  # its box, over its frame
                stamp, truth = self._frames.pop((msg.header.stream, msg.header.seq), (msg.header.stamp_ns, None))
                box = topic.rsplit("/", 1)[0] + "/" + BOX_TOPIC
                self._log(box, "ImageAnnotations", to_sdk(estimate_annotations(msg, stamp, truth)), log_ns)

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                item = self._q.get(timeout=0.1)
            except queue.Empty:
                continue
            try:
                self._forward(*item)
            except Exception as e:  # a message the viewer cannot take must not stop the bridge
                self.failed["/" + item[0]] = f"{type(e).__name__}: {e}"

    def stop(self) -> None:
        self._stop.set()
        self._worker.join(timeout=2.0)
        try:
            self._session.close()
        finally:
            self.server.stop()
