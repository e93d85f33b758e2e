"""``gflow.track``: one target through any source ``gflow track`` reads, estimates as they come."""

from __future__ import annotations

import logging
import os
import types
from pathlib import Path
from typing import Any, Iterable, Iterator, Sequence

import numpy as np

from gflow_core.tracker import Estimate

from .errors import GflowError, UnusableFrameError
from .tracker import Tracker, check_box

__all__ = ["track"]

#: the built-in scene's name as a source (``gflow run demo`` tracks it)
SYNTHETIC = "synthetic"


def track(source: str | os.PathLike[str] | Iterable[np.ndarray | None] | Any, init: Sequence[float] | None = None,
          tracker: str = "dcf", seed: int = 1, *, start: int = 0, stop: int | None = None, fps: float = 25.0,
          **params: Any) -> Iterator[Estimate]:
    """Track one target from ``init`` through ``source``, yielding an estimate per frame.

    The same frames, parameters and draws as ``gflow track SOURCE --init X,Y,W,H --tracker TRACKER
    --seed SEED``, so the same boxes bit for bit (``--inline`` and the processes agree).

    Parameters
    ----------
    source
        An image folder (or a dataset folder with ``frames/``), a video file, an ``.mcap``
        recording, a live source (a stream URL such as ``rtsp://...`` or a camera ``/dev/videoN``),
        ``"synthetic"`` (the built-in scene), a ``stages.source.SourceParams``, or an iterable of
        frames (numpy arrays as OpenCV gives them; ``None`` for a frame that was lost).
    init : (x, y, w, h)
        The box in the first frame (``start``); for the synthetic scene, its true box by default.
    tracker, seed, params
        As :class:`gflow.Tracker` takes them.
    start, stop : int
        The first frame index, and the one to stop before (live: the number of frames to take).
    fps : float
        The source's frame rate: time stamps, and a live source's nominal rate (the unit of the
        time between frames the trackers scale their motion noise with).

    Yields
    ------
    Estimate
        In frame order. Frames before the first usable one (a uniform frame, say) give none; a
        frame lost or unusable later gives a coasted estimate (``phase == "coast"``).

    Raises
    ------
    GflowError (a ValueError)
        A source that cannot be read, ``start`` beyond its end, a box that misses the first
        frame, with the one-line message ``gflow track`` prints.
    """
    from stages.source import SourceParams

    t = Tracker(tracker, seed, **params)
    if isinstance(source, (str, os.PathLike, SourceParams)):
        frames, init = _read(source, init, start, stop, fps)
    else:
        if init is None:
            raise GflowError("give init=(x, y, w, h): the box of the target in the first frame")
        frames = ((start + i, None if f is None else np.asarray(f), 0) for i, f in enumerate(source))
    box = check_box(init) if init is not None else None
    yield from _run(t, frames, box, _period(source, fps))


def _source_params(source: Any, start: int, stop: int | None, fps: float) -> Any:
    from stages.source import SourceParams

    if isinstance(source, SourceParams):
        return source
    if str(source) == SYNTHETIC and not Path(source).exists():
        try:
            return SourceParams(kind="synthetic", start=start, stop=stop, fps=fps)
        except ValueError as e:
            raise GflowError(str(e)) from None
    from pipeline.cli.commands.common import CliError
    from pipeline.cli.commands.track import source_params

    args = types.SimpleNamespace(fps=fps, realtime=False, start=start, stop=stop, reconnect=None, open_timeout=None)
    try:
        return SourceParams(**source_params(str(source), args))
    except CliError as e:
        raise GflowError(str(e)) from None
    except ValueError as e:
        raise GflowError(f"{source}: {e}") from None


def _read(source: Any, init: Sequence[float] | None, start: int, stop: int | None,
          fps: float) -> tuple[Iterator[tuple[int, np.ndarray | None, int]], Sequence[float] | None]:
    """``(frame index, image or None, stamp ns)`` of the frames the source stage would send, and the
    initial box (the synthetic scene's truth when not given)."""
    from pipeline.io.frame_readers import open_reader
    from pipeline.runtime.preflight import PreflightError, check_source
    from stages.base import StageContext
    from gflow_msgs.messages import Frame
    from stages.source import SourceStage

    sp = _source_params(source, start, stop, fps)
    if sp.kind != "live":  # a live source is opened once, by the reader
        try:
            first = check_source(sp, init if init is None else check_box(init))
        except PreflightError as e:
            raise GflowError(str(e)) from None
        if init is None and first.truth is not None:
            init = first.truth
    if init is None:
        raise GflowError("give init=(x, y, w, h): the box of the target in the first frame")
    stage = SourceStage(sp, StageContext(name="source", stream="cam0"))

    def frames() -> Iterator[tuple[int, np.ndarray | None, int]]:
        try:
            reader = open_reader(sp)
        except (OSError, ValueError) as e:
            raise GflowError(str(e)) from None
        for raw in reader:
            # the source stage's checks: an unreadable frame or one of another size is not sent
            for port, msg in stage.emit(raw):
                if port == "frames" and isinstance(msg, Frame):
                    yield msg.header.seq, msg.image.array(), msg.header.stamp_ns
            for kind, message, _ in stage.drain_reports():  # a recording damaged inside: said, as by the CLI
                if kind == "damaged_input":
                    logging.getLogger("gflow.recording").warning("%s", message)
    return frames(), init


def _period(source: Any, fps: float) -> float:
    """The frame period (ns) that live stamps are measured in; 0 for media time."""
    from stages.source import SourceParams

    if isinstance(source, SourceParams):
        return 1e9 / source.fps if source.host_clock else 0.0
    if isinstance(source, (str, os.PathLike)):
        from pipeline.io.live_capture import is_live_source

        return 1e9 / fps if is_live_source(str(source)) else 0.0
    return 0.0


def _run(t: Tracker, frames: Iterator[tuple[int, np.ndarray | None, int]], box: Any,
         period: float) -> Iterator[Estimate]:
    from stages.base import StageContext
    from stages.time_step import time_step

    ctx = StageContext(name="api", stream="cam0", frame_period_ns=period)
    prev_stamp = 0
    for seq, image, stamp in frames:
        if t.frame_index < 0:
            if image is None:
                continue
            try:
                yield t.init(image, box, frame_index=seq)
            except UnusableFrameError:
                continue  # as the filters do: wait for a usable first frame
        else:
            dt = time_step(ctx, stamp, prev_stamp if seq == t.frame_index + 1 else 0) if image is not None else 1.0
            yield from t.step(image, seq, dt)
        prev_stamp = stamp if image is not None else 0
