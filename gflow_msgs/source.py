"""What a source reads and hands on: its parameters and the frames its readers decode.

:class:`SourceParams` are a graph's ``source`` stage settings: where frames come from (read by the
frame readers of ``pipeline/io``, which open and decode them) and how the source stage
(``stages/source.py``) stamps and sends them. :class:`RawFrame` is a frame as a reader decoded it,
which the source stage validates and turns into a :class:`~gflow_msgs.messages.Frame` message. Both
are the contract between the readers and the stage, below both, like the messages.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import msgspec
import numpy as np

from .params import Params

__all__ = ["SourceParams", "RawFrame", "FOREVER_S"]

#: ``reconnect`` or ``open_timeout`` of ``inf`` ("until the stream is back or Ctrl-C") is held as this many
#: seconds (about 32 years): JSON, which carries the plan to each stage and the parameters into the recording,
#: has no infinity (msgspec writes it as null, which no stage could read back).
FOREVER_S = 1e9
#: the slowest frame rate: a frame every 1000 s. A file's frame is stamped ``index * 1e9 / fps`` ns, which at a
#: rate of 1e-300 (a mistyped exponent) was no integer and ended the source in an OverflowError
MIN_FPS = 1e-3


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
    ``open_timeout``: seconds an open may take; ``read_timeout``: seconds without a new frame
    before the stream is taken as lost (then reopened for ``reconnect`` seconds, or ended);
    ``keep_skipped``: send the skipped frames on port ``skipped`` (for the recording); ``stop``:
    end after this many frames decoded; ``relay``: where to read ``path``'s bytes instead (a UDP
    port bound before the pipeline started, served on loopback: :mod:`pipeline.io.udp_relay`).
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
    read_timeout: float = 5.0
    keep_skipped: bool = False
    relay: str = ""

    @property
    def host_clock(self) -> bool:
        """Frames carry host capture stamps (a live source, or a recording of one)."""
        return self.clock == "host" or (self.clock == "auto" and self.kind == "live")

    def __post_init__(self) -> None:
        for name in ("reconnect", "open_timeout"):
            if getattr(self, name) == math.inf:
                msgspec.structs.force_setattr(self, name, FOREVER_S)
        if not self.fps > 0:
            raise ValueError(f"fps must be positive, got {self.fps}")
        if not MIN_FPS <= self.fps < math.inf:
            raise ValueError(f"fps must be a finite rate of at least {MIN_FPS:g} frames/s (a frame every "
                             f"{1 / MIN_FPS:g} s), got {self.fps}")
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
        if self.live_ahead < 1 or not self.reconnect >= 0 or not self.open_timeout > 0:  # `not >=`: NaN too
            raise ValueError(f"need live_ahead >= 1, reconnect >= 0 and open_timeout > 0, got {self.live_ahead}, "
                             f"{self.reconnect}, {self.open_timeout}")
        if not 0 < self.read_timeout < math.inf:
            raise ValueError(f"read_timeout must be a positive, finite number of seconds, got {self.read_timeout}")


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
