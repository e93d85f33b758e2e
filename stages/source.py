"""The frame source stage: validates decoded frames and stamps them as :class:`Frame` messages.

Decoding (image folders, video files, MCAP, the synthetic scene, live streams and cameras) is
I/O and lives in ``pipeline/io/``; the runner hands each decoded frame to :meth:`SourceStage.emit`
(the parameters and the decoded frame, which the readers share with the stage, are
:mod:`gflow_msgs.source`'s).

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

from typing import Mapping

import numpy as np

from .base import Output, Stage
from gflow_msgs.messages import Capture, Frame, Message, NDArray
from gflow_msgs.source import RawFrame, SourceParams

__all__ = ["SourceStage", "SourceParams", "RawFrame"]


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
