"""The frame source stage: validates decoded frames and stamps them as :class:`Frame` messages.

Decoding (image folders, video files, MCAP, the synthetic scene, live streams and cameras) is
I/O and lives in ``pipeline/io/``; the runner hands each decoded frame to :meth:`SourceStage.emit`.

Stamps. A file's frames are stamped with media time, ``index * 1e9 / fps``, never the wall
clock, so a re-run gives the same messages. A live source's frames carry the receiving host's
clock, taken by the reader as each frame was read (``RawFrame.stamp_ns``; the stage itself
reads no clock), and so does an MCAP source with ``clock: host`` (the recorded stamps): a
recording of a live run re-runs with the stamps it was tracked with.

Live sources (``kind: live``). The reader decodes every frame the camera or stream delivers;
the runner takes the newest one when the pipeline has room for it (``live_ahead``) and skips
the others. The frames sent are numbered 0, 1, 2, ... (``seq``, what every stage joins on);
each also goes out as a :class:`Capture` on port ``captures`` with the camera's frame number
and how many frames were skipped before it, and with ``keep_skipped`` the skipped frames
themselves go out on port ``skipped`` (their ``seq`` is the camera's frame number), so a
recording can keep every frame captured.

Bad input: a frame that could not be decoded, is empty, or changes size mid-stream is
reported on the error topic and skipped; the stream goes on.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, Mapping

import numpy as np

from .base import Output, Params, Stage
from gflow_msgs.messages import Capture, Frame, Message, NDArray

__all__ = ["SourceStage", "SourceParams", "RawFrame"]


class SourceParams(Params, frozen=True):
    """Where frames come from and how fast.

    kind: ``synthetic`` (built-in scene with ground truth), ``folder`` (image files sorted
    by name), ``video`` (any file OpenCV reads), ``mcap`` (the Frame topic of a recording) or
    ``live`` (``path`` is a stream URL or a V4L2 device such as ``/dev/video0``).
    realtime: pace frames at ``fps`` (live playback) instead of as fast as the pipeline allows.
    max_ahead: in a multi-process run, the source stays at most this many frames ahead of
    the slowest stage (flow control; 0 = unbounded). It bounds memory and latency and does
    not change any result.
    clock: how frames are stamped: ``media`` (index / fps), ``host`` (the host clock when each
    frame was read: live sources; an mcap source keeps the recorded stamps), ``auto`` (host
    for live sources, else media). With host stamps ``fps`` is the nominal rate, the unit of
    the trackers' time step (:mod:`stages.time_step`).
    Live sources only: ``live_ahead`` frames may be in flight ahead of the slowest stage (the
    newest frame wins beyond them); ``reconnect``: seconds to keep reopening a lost stream;
    ``open_timeout``: seconds an open may take; ``keep_skipped``: send the skipped frames on
    port ``skipped`` (for the recording); ``stop``: end after this many frames decoded;
    ``relay``: where to read ``path``'s bytes instead (a UDP port bound before the pipeline
    started, served on loopback: :mod:`pipeline.io.udp_relay`).
    """

    kind: Literal["synthetic", "folder", "video", "mcap", "live"] = "synthetic"
    path: str = ""
    fps: float = 25.0
    realtime: bool = False
    max_ahead: int = 8
    start: int = 0
    stop: int | None = None
    # synthetic scene
    width: int = 320
    height: int = 240
    frames: int = 120
    scene_seed: int = 0
    noise: float = 4.0
    # occlusion test (M2 paper sec. 5.1.2, fig. 7): blank `blank_count` of every `blank_every` frames
    blank_every: int = 0
    blank_count: int = 0
    clock: Literal["auto", "media", "host"] = "auto"
    live_ahead: int = 1
    reconnect: float = 5.0
    open_timeout: float = 10.0
    keep_skipped: bool = False
    relay: str = ""

    @property
    def host_clock(self) -> bool:
        """Frames carry host capture stamps (a live source, or a recording of one)."""
        return self.clock == "host" or (self.clock == "auto" and self.kind == "live")

    def __post_init__(self) -> None:
        if not self.fps > 0:
            raise ValueError(f"fps must be positive, got {self.fps}")
        if self.start < 0 or (self.stop is not None and self.stop <= self.start):
            raise ValueError(f"need 0 <= start < stop, got start={self.start}, stop={self.stop}")
        if self.kind != "synthetic" and not self.path:
            raise ValueError(f"source kind {self.kind!r} needs a path")
        if self.blank_every < 0 or not 0 <= self.blank_count <= self.blank_every:
            raise ValueError("need 0 <= blank_count <= blank_every")
        if self.kind == "live" and (self.clock == "media" or self.start or self.realtime):
            raise ValueError("a live source is stamped with the host clock, starts at its first frame and "
                             "runs at the camera's pace (no clock: media, start or realtime)")
        if self.clock == "host" and self.kind not in ("live", "mcap"):
            raise ValueError(f"clock: host is for live sources and their recordings, not kind {self.kind!r}")
        if self.live_ahead < 1 or self.reconnect < 0 or not self.open_timeout > 0:
            raise ValueError(f"need live_ahead >= 1, reconnect >= 0 and open_timeout > 0, got {self.live_ahead}, "
                             f"{self.reconnect}, {self.open_timeout}")


@dataclass(frozen=True)
class RawFrame:
    """A decoded frame handed to the source by the pipeline's reader.

    index : 0-based frame index in the source (for a live source: in the frames it sends).
    image : (H, W, 3) or (H, W) uint8, or None if it could not be decoded.
    error : why ``image`` is None.
    truth : ground-truth box (x, y, w, h) when the source knows it.
    Live sources (host stamps) also give: ``frame`` the camera's frame number, ``stamp_ns``
    the host clock when it was read, ``skipped`` the frames skipped since the previous one,
    ``gap_s`` seconds lost to a reconnect before it, ``skipped_frames`` those frames'
    ``(frame, stamp_ns, image)`` when they are kept, ``events`` ``(kind, message)`` reports
    (a frame with no image and only events is just the reports: the end of a stream),
    ``missed`` the frames that never arrived since the previous one and ``damaged`` whether it
    was decoded from damaged data.
    """

    index: int
    image: np.ndarray | None
    error: str = ""
    truth: tuple[float, float, float, float] | None = None
    name: str = ""
    frame: int = -1
    stamp_ns: int = 0
    skipped: int = 0
    gap_s: float = 0.0
    skipped_frames: tuple[tuple[int, int, np.ndarray], ...] = ()
    events: tuple[tuple[str, str], ...] = ()
    missed: int = 0
    damaged: bool = False


class SourceStage(Stage[SourceParams]):
    """Turns decoded frames into :class:`Frame` messages on port ``frames``."""

    kind = "source"
    Params = SourceParams
    inputs: Mapping[str, type] = {}
    outputs = {"frames": Frame}

    @classmethod
    def ports(cls, params: SourceParams) -> tuple[Mapping[str, type], Mapping[str, type]]:
        outs: dict[str, type] = {"frames": Frame}
        if params.host_clock:
            outs["captures"] = Capture
        if params.keep_skipped:
            outs["skipped"] = Frame
        return cls.inputs, outs

    def __init__(self, params: SourceParams, ctx) -> None:
        super().__init__(params, ctx)
        self._shape: tuple[int, ...] | None = None
        self.emitted = 0
        self.skipped = 0  # live: frames decoded and not sent
        self.last_frame = -1  # live: the camera's number of the last frame sent

    def step(self, seq: int, inputs: Mapping[str, Message | None]) -> list[Output]:
        raise TypeError("the source stage has no inputs; the runner calls emit()")

    def emit(self, raw: RawFrame) -> list[Output]:
        """Validate one decoded frame and return ``[("frames", Frame)]`` or ``[]`` if unusable."""
        p = self.params
        seq = raw.index
        where = f"frame {seq}" + (f" ({raw.name})" if raw.name else "")
        for kind, message in raw.events:
            self.report(kind, message, max(seq, 0))
        img = raw.image
        if img is None:
            if not (raw.events and not raw.error):
                self.report("missing_frame", f"{where}: {raw.error or 'could not be decoded'}", seq)
            return []
        img = np.asarray(img)
        if img.dtype != np.uint8 or img.ndim not in (2, 3) or img.size == 0 or (img.ndim == 3 and img.shape[2] != 3):
            self.report("bad_frame", f"{where}: expected (H, W) or (H, W, 3) uint8, got {img.dtype} {img.shape}", seq)
            return []
        if self._shape is None:
            self._shape = img.shape
        elif img.shape != self._shape:
            self.report("frame_size_changed", f"{where}: size changed from {self._shape} to {img.shape}; skipped", seq)
            return []
        if p.blank_every and (seq % p.blank_every) >= p.blank_every - p.blank_count:
            img = np.zeros_like(img)
        stamp = raw.stamp_ns if p.host_clock else int(round(seq * 1e9 / p.fps))
        self.emitted += 1
        out: list[Output] = [("frames", Frame(header=self.header(seq, stamp), image=NDArray.of(img), source=raw.name,
                                              truth=raw.truth))]
        if p.host_clock:
            self.skipped += raw.skipped
            self.last_frame = raw.frame
            out.append(("captures", Capture(header=self.header(seq, stamp), frame=raw.frame, skipped=raw.skipped,
                                            gap_s=raw.gap_s, missed=raw.missed, damaged=raw.damaged)))
        if p.keep_skipped:
            name = raw.name.rsplit("#", 1)[0]
            out += [("skipped", Frame(header=self.header(frame, stamp_ns), image=NDArray.of(image),
                                      source=f"{name}#{frame}")) for frame, stamp_ns, image in raw.skipped_frames]
        return out

    def summary(self) -> dict:
        return {"emitted": self.emitted, "shape": self._shape, "skipped": self.skipped}
