"""Live sources: network streams through OpenCV's FFmpeg backend and V4L2 cameras.

A live source does not wait for the tracker, so it is read on a thread of its own, as fast as
it delivers, and **the newest frame wins**: :meth:`LiveCapture.take` returns the newest frame
not taken yet together with the number of frames decoded since the previous one taken and not
taken (skipped, never lost silently). The first frame decoded is held until it is taken: it is
the frame the tracker starts on, the one ``--init`` describes.

* **Frame numbers** count every frame decoded since the open (skipped ones included; frames
  that never arrived during a reconnect are not counted, their time is reported instead).
* **Capture stamps** come from the receiving host's clock (``time.time_ns()``), taken as
  ``read()`` returns each frame.
* **Opening** can block (a server that accepts and sends nothing; a stream FFmpeg cannot
  probe), so every open runs with FFmpeg's own open timeout and on a helper thread that is
  abandoned after ``open_timeout`` plus a second. A failure is a :class:`LiveSourceError`
  of one line naming the source and what FFmpeg said (:mod:`pipeline.io.ffmpeg_messages`).
* **Reconnecting.** A read that fails (the server closed, a read timeout of
  ``READ_TIMEOUT_S``) is retried with back-off (0.25 s doubling to 1 s) for ``reconnect``
  seconds; the next frame taken carries the gap (seconds, frames missed at the nominal
  rate). Not back in time, the capture ends and says why.

Sources: ``rtsp://``, ``rtmp://``, ``http(s)://``, ``tcp://``, ``udp://``, ``srt://``, ``rtp://``
URLs, and V4L2 devices ``/dev/videoN`` (``--camera N``).
"""

from __future__ import annotations

import glob
import os
import re
import threading
import time
from dataclasses import dataclass, field

import numpy as np

from pipeline.io.ffmpeg_messages import ffmpeg_messages

__all__ = ["LiveCapture", "LiveFrame", "LiveSourceError", "is_live_source", "camera_device", "READ_TIMEOUT_S"]

#: URL schemes that are opened as live streams through FFmpeg
LIVE_SCHEMES = ("rtsp", "rtsps", "rtmp", "rtmps", "http", "https", "tcp", "udp", "srt", "rtp")
#: a stream that delivers nothing for this long is taken as lost (FFmpeg's read timeout)
READ_TIMEOUT_S = 5.0
#: back-off between reconnection attempts: first wait, and the most it grows to
BACKOFF_FIRST_S, BACKOFF_MAX_S = 0.25, 1.0
_DEVICE = re.compile(r"^/dev/video\d+$")
CAP_PROP_FPS = 5  # cv2.CAP_PROP_FPS (this module imports cv2 only when it opens a source)


class LiveSourceError(ValueError):
    """A live source that cannot be opened: one line naming it and what FFmpeg (or the OS) said."""


def is_live_source(text: str) -> bool:
    """True for a stream URL (``scheme://...`` with a scheme of :data:`LIVE_SCHEMES`) or a V4L2 device."""
    scheme = text.split("://", 1)[0].lower() if "://" in text else ""
    return scheme in LIVE_SCHEMES or bool(_DEVICE.match(text))


def camera_device(index: int) -> str:
    """The V4L2 device of camera ``index`` (``--camera 0`` is ``/dev/video0``)."""
    if index < 0:
        raise LiveSourceError(f"--camera takes a camera number >= 0, got {index}")
    return f"/dev/video{index}"


@dataclass(frozen=True)
class Captured:
    """One decoded frame: its number since the open, its host capture stamp, the image."""

    frame: int
    stamp_ns: int
    image: np.ndarray | None  # None for a skipped frame whose image was not kept


@dataclass(frozen=True)
class LiveFrame:
    """A frame taken from a :class:`LiveCapture` and what happened since the previous one taken.

    skipped : frames decoded since the previous frame taken, and not taken (newest frame wins).
    skipped_frames : those frames, when the capture keeps them (``keep_skipped``).
    gap_s : seconds without frames while the stream was lost and reopened since then.
    events : ``(kind, message)`` reports: ``reconnected`` (with the gap), in order.
    """

    frame: int
    stamp_ns: int
    image: np.ndarray
    skipped: int = 0
    skipped_frames: tuple[Captured, ...] = ()
    gap_s: float = 0.0
    events: tuple[tuple[str, str], ...] = ()


@dataclass
class _Slot:
    held: Captured | None = None  # the first frame, kept until taken
    latest: Captured | None = None
    skipped: int = 0
    kept: list[Captured] = field(default_factory=list)
    gap_s: float = 0.0
    events: list[tuple[str, str]] = field(default_factory=list)


class LiveCapture:
    """A live source read on its own thread; the newest frame wins (see the module docstring).

    Parameters
    ----------
    source : stream URL or V4L2 device path.
    fps : nominal frame rate, used to say how many frames a gap missed when the stream does not
        declare its own.
    open_timeout : seconds an open (and its first frame) may take.
    reconnect : seconds to keep trying after the stream is lost (0: end at once).
    keep_skipped : keep the images of skipped frames (for the recording).
    stop : end after this many frames (None: when the stream ends).
    """

    def __init__(self, source: str, fps: float = 25.0, open_timeout: float = 10.0, reconnect: float = 5.0,
                 keep_skipped: bool = False, stop: int | None = None) -> None:
        self.source = source
        self.fps = fps
        self.open_timeout = open_timeout
        self.reconnect = reconnect
        self.keep_skipped = keep_skipped
        self.stop = stop
        self.captured = 0  # frames decoded since the open
        self.skipped = 0  # frames decoded and never taken
        self.reconnects = 0
        self.ended = ""  # why the capture ended ('' while it runs)
        self.shape: tuple[int, ...] = ()
        self.declared_fps = 0.0  # what the stream says its rate is (0: it does not say)
        self._cap = None
        self._slot = _Slot()
        self._cond = threading.Condition()
        self._closing = threading.Event()
        self._thread: threading.Thread | None = None
        self._messages = ffmpeg_messages()
        self._listening = False
        self._last_ns = 0  # host stamp of the last frame decoded

    # -- opening -------------------------------------------------------------------------------
    def open(self) -> "LiveCapture":
        """Open the source and decode its first frame, then start reading. Raises :class:`LiveSourceError`."""
        if _DEVICE.match(self.source) and not os.path.exists(self.source):
            cams = sorted(glob.glob("/dev/video*"))
            raise LiveSourceError(f"no camera at {self.source}: the device does not exist (cameras here: "
                                  f"{', '.join(cams) or 'none'})")
        self._messages.start()
        self._listening = True
        try:
            cap, first, stamp = self._open_once(self.open_timeout)
        except LiveSourceError:
            self._stop_listening()
            raise
        self._cap = cap
        self.shape = tuple(first.shape)
        fps = float(cap.get(CAP_PROP_FPS))
        self.declared_fps = fps if 0 < fps < 1000 else 0.0
        self._put(first, stamp)
        self._thread = threading.Thread(target=self._read_loop, name="live-capture", daemon=True)
        self._thread.start()
        return self

    def _open_once(self, timeout: float):
        """(capture, first image, its stamp), or LiveSourceError within ``timeout`` + 1 s."""
        import cv2

        box: dict = {}
        t0 = time.monotonic()

        def attempt() -> None:
            try:
                if _DEVICE.match(self.source):
                    cap = cv2.VideoCapture(self.source, cv2.CAP_V4L2)
                else:
                    ms = int(max(timeout, 0.1) * 1000)
                    cap = cv2.VideoCapture(self.source, cv2.CAP_FFMPEG,
                                           [cv2.CAP_PROP_OPEN_TIMEOUT_MSEC, ms,
                                            cv2.CAP_PROP_READ_TIMEOUT_MSEC, int(READ_TIMEOUT_S * 1000)])
                if not cap.isOpened():
                    timed_out = time.monotonic() - t0 >= 0.95 * timeout
                    box["error"] = f"nothing received within {timeout:g} s" if timed_out else "could not be opened"
                    return
                ok, img = cap.read()
                if not ok or img is None:
                    cap.release()
                    box["error"] = "opened, but no frame could be read"
                    return
                box["result"] = (cap, img, time.time_ns())
            except cv2.error as e:  # an OpenCV exception: one line of it
                box["error"] = str(e).strip().splitlines()[-1] if str(e).strip() else "OpenCV error"

        t = threading.Thread(target=attempt, name="live-open", daemon=True)
        t.start()
        t.join(timeout + 1.0)
        if t.is_alive():  # blocked inside FFmpeg: abandon the thread (it holds nothing we need)
            said = self._messages.collect()
            raise LiveSourceError(f"{self.source}: nothing received within {timeout:g} s"
                                  + (f" (FFmpeg: {said[-1]})" if said else self._hint(True)))
        if "result" in box:
            self._messages.collect()
            return box["result"]
        said = self._messages.collect()
        error = box.get("error", "could not be opened")
        raise LiveSourceError(f"{self.source}: {error}"
                              + (f" (FFmpeg: {said[-1]})" if said else self._hint(error.startswith("nothing"))))

    def _hint(self, timed_out: bool) -> str:
        if _DEVICE.match(self.source):
            return " (is another program using the camera?)"
        if timed_out:
            return " (no video arrived: is the stream being sent there?)"
        return " (FFmpeg gave no reason: is it a video stream FFmpeg can decode?)"

    # -- reading -------------------------------------------------------------------------------
    def _put(self, img: np.ndarray, stamp: int) -> None:
        with self._cond:
            f = Captured(self.captured, stamp, img)
            self.captured += 1
            self._last_ns = stamp
            s = self._slot
            if f.frame == 0:
                s.held = f
            else:
                if s.latest is not None:  # never taken: the newer frame wins
                    s.skipped += 1
                    self.skipped += 1
                    if self.keep_skipped:
                        s.kept.append(s.latest)
                s.latest = f
            self._cond.notify_all()

    def _read_loop(self) -> None:
        import cv2

        cap = self._cap
        heard = time.monotonic()
        while not self._closing.is_set() and cap is not None:
            try:
                ok, img = cap.read()
            except cv2.error:
                ok, img = False, None
            stamp = time.time_ns()
            if ok and img is not None:  # a frame of another size too: the source stage reports it
                self._put(img, stamp)
                if time.monotonic() - heard > 1.0:  # what FFmpeg said while frames came explains no loss
                    heard = time.monotonic()
                    self._messages.collect()
                if self.stop is not None and self.captured >= self.stop:
                    self._end(f"{self.source}: stopped after frame {self.captured - 1} (--stop {self.stop})")
                    break
                continue
            if self._closing.is_set():
                break
            cap.release()
            cap = self._reconnect()
        if cap is not None:
            cap.release()
        self._cap = None

    def _reconnect(self):
        """Reopen a lost stream with back-off for ``reconnect`` seconds; None when it is not back."""
        last = self.captured - 1
        lost_at = time.monotonic()
        said = self._messages.collect()
        why = f"FFmpeg: {said[-1]}" if said else "the stream ended or the connection closed"
        wait, attempts = BACKOFF_FIRST_S, 0
        while not self._closing.is_set():
            left = self.reconnect - (time.monotonic() - lost_at)
            if left <= 0:
                break
            attempts += 1
            try:
                cap, img, stamp = self._open_once(min(self.open_timeout, max(left, 0.5)))
            except LiveSourceError:
                if self._closing.wait(min(wait, max(0.0, self.reconnect - (time.monotonic() - lost_at)))):
                    break
                wait = min(2 * wait, BACKOFF_MAX_S)
                continue
            gap = (stamp - self._last_ns) / 1e9
            rate = self.declared_fps or self.fps  # the stream's own rate when it says it
            missed = max(0, int(round(gap * rate)) - 1)
            self.reconnects += 1
            with self._cond:
                self._slot.gap_s += gap
                self._slot.events.append(("reconnected", (
                    f"{self.source}: lost after frame {last} ({why}); back after {gap:.2f} s "
                    f"(attempt {attempts}), about {missed} frames missed at {rate:g} frames/s; "
                    f"tracking resumes at frame {self.captured} with the motion model's uncertainty "
                    f"grown for the {gap:.2f} s")))
            self._put(img, stamp)
            return cap
        if not self._closing.is_set():
            self._end(f"{self.source}: lost after frame {last} ({why}) and not back within "
                      f"{self.reconnect:g} s (--reconnect)")
        return None

    def _end(self, why: str) -> None:
        with self._cond:
            self.ended = why
            self._cond.notify_all()

    def take(self, timeout: float | None = None) -> LiveFrame | None:
        """The held first frame, else the newest frame not taken yet (waiting for one); None once
        the capture has ended (:attr:`ended` says why) or ``timeout`` passed."""
        deadline = None if timeout is None else time.monotonic() + timeout
        with self._cond:
            s = self._slot
            while s.held is None and s.latest is None:
                if self.ended or self._closing.is_set():
                    return None
                left = None if deadline is None else deadline - time.monotonic()
                if left is not None and left <= 0:
                    return None
                self._cond.wait(0.1 if left is None else min(left, 0.1))
            if s.held is not None:
                first, s.held = s.held, None
                assert first.image is not None  # _put keeps every decoded frame's image
                return LiveFrame(first.frame, first.stamp_ns, first.image)
            f, s.latest = s.latest, None
            assert f is not None and f.image is not None  # the wait above ended with a latest frame, kept whole
            out = LiveFrame(f.frame, f.stamp_ns, f.image, s.skipped, tuple(s.kept), s.gap_s,
                            tuple(s.events))
            s.skipped, s.kept, s.gap_s, s.events = 0, [], 0.0, []
            return out

    def interrupt(self) -> None:
        """Wake a :meth:`take` that waits, and stop reading (from any thread; :meth:`close` releases)."""
        self._closing.set()
        with self._cond:
            self._cond.notify_all()

    def close(self) -> None:
        """Stop reading and release the source (idempotent)."""
        self._closing.set()
        with self._cond:
            self._cond.notify_all()
        t = self._thread
        if t is not None and t is not threading.current_thread():
            t.join(timeout=READ_TIMEOUT_S + 1.0)
        self._stop_listening()
        self._thread = None
        if self._cap is not None and (t is None or not t.is_alive()):
            self._cap.release()
            self._cap = None

    def _stop_listening(self) -> None:
        if self._listening:
            self._listening = False
            self._messages.stop()

    def pending_events(self) -> list[tuple[str, str]]:
        """Reports not yet attached to a taken frame (the stream ended before another came)."""
        with self._cond:
            out, self._slot.events = self._slot.events, []
        return out

    def __enter__(self) -> "LiveCapture":
        return self.open()

    def __exit__(self, *exc) -> None:
        self.close()

