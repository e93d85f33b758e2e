"""The frame source stage: validates decoded frames and stamps them as :class:`Frame` messages.

Decoding (image folders, video files, MCAP, the synthetic scene) is I/O and lives in
``pipeline/io/frame_readers.py``; the runner hands each decoded frame to :meth:`SourceStage.emit`.
The capture stamp is media time, ``index * 1e9 / fps``, never the wall clock, so a re-run
gives the same messages.

Bad input: a frame that could not be decoded, is empty, or changes size mid-stream is
reported on the error topic and skipped; the stream goes on.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, Mapping

import numpy as np

from .base import Output, Params, Stage
from .messages import Frame, Message, NDArray

__all__ = ["SourceStage", "SourceParams", "RawFrame"]


class SourceParams(Params):
    """Where frames come from and how fast.

    kind: ``synthetic`` (built-in scene with ground truth), ``folder`` (image files sorted
    by name), ``video`` (any file OpenCV reads) or ``mcap`` (the Frame topic of a recording).
    realtime: pace frames at ``fps`` (live playback) instead of as fast as the pipeline allows.
    max_ahead: in a multi-process run, the source stays at most this many frames ahead of
    the slowest stage (flow control; 0 = unbounded). It bounds memory and latency and does
    not change any result.
    """

    kind: Literal["synthetic", "folder", "video", "mcap"] = "synthetic"
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

    def __post_init__(self) -> None:
        if not self.fps > 0:
            raise ValueError(f"fps must be positive, got {self.fps}")
        if self.start < 0 or (self.stop is not None and self.stop <= self.start):
            raise ValueError(f"need 0 <= start < stop, got start={self.start}, stop={self.stop}")
        if self.kind != "synthetic" and not self.path:
            raise ValueError(f"source kind {self.kind!r} needs a path")
        if self.blank_every < 0 or not 0 <= self.blank_count <= self.blank_every:
            raise ValueError("need 0 <= blank_count <= blank_every")


@dataclass(frozen=True)
class RawFrame:
    """A decoded frame handed to the source by the pipeline's reader.

    index : 0-based frame index in the source.
    image : (H, W, 3) or (H, W) uint8, or None if it could not be decoded.
    error : why ``image`` is None.
    truth : ground-truth box (x, y, w, h) when the source knows it.
    """

    index: int
    image: np.ndarray | None
    error: str = ""
    truth: tuple[float, float, float, float] | None = None
    name: str = ""


class SourceStage(Stage):
    """Turns decoded frames into :class:`Frame` messages on port ``frames``."""

    kind = "source"
    Params = SourceParams
    inputs: Mapping[str, type] = {}
    outputs = {"frames": Frame}

    def __init__(self, params: SourceParams, ctx) -> None:
        super().__init__(params, ctx)
        self._shape: tuple[int, ...] | None = None
        self.emitted = 0

    def step(self, seq: int, inputs: Mapping[str, Message | None]) -> list[Output]:
        raise TypeError("the source stage has no inputs; the runner calls emit()")

    def emit(self, raw: RawFrame) -> list[Output]:
        """Validate one decoded frame and return ``[("frames", Frame)]`` or ``[]`` if unusable."""
        p: SourceParams = self.params  # type: ignore[assignment]
        seq = raw.index
        where = f"frame {seq}" + (f" ({raw.name})" if raw.name else "")
        img = raw.image
        if img is None:
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
        stamp = int(round(seq * 1e9 / p.fps))
        self.emitted += 1
        return [("frames", Frame(header=self.header(seq, stamp), image=NDArray.of(img), source=raw.name, truth=raw.truth))]

    def summary(self) -> dict:
        return {"emitted": self.emitted, "shape": self._shape}
