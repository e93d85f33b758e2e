"""Live sources: network streams through OpenCV's FFmpeg backend and V4L2 cameras.

A live source does not wait for the tracker, so it is read on a thread of its own, as fast as
it delivers, and **the newest frame wins**: :meth:`LiveCapture.take` returns the newest frame
not taken yet together with the number of frames decoded since the previous one taken and not
taken (skipped, never lost silently). The first frame decoded is held until it is taken: it is
the frame the tracker starts on, the one ``--init`` describes.

* **Frame numbers** are the camera's: from the stream's own timestamps where it has them, so
  frames that never arrived (an outage, packets lost, a reconnect to a sender that went on)
  leave a gap in the numbers and are counted and reported; else counting every frame decoded
  (skipped ones included), a reconnect's gap estimated by the host clock
  (:mod:`pipeline.io.frame_numbers`).
* **Damage.** FFmpeg's messages are read after every frame: a frame decoded while FFmpeg
  reported corrupt or undecodable data is **damaged**, and so is every frame decoded from it
  until the next keyframe (``CAP_PROP_FRAME_TYPE`` I: predicted frames carry the damage on).
  Damaged frames are counted, marked on the frame taken, and the start of each damaged run is
  reported with what FFmpeg said. FFmpeg decodes as many frames ahead of the one it hands over
  as it has threads, less one, and says what went wrong as it decodes: the frame handed over
  when it spoke and that many after it are marked, so a damaged run can start a frame early.
* **Capture stamps** come from the receiving host's clock (``time.time_ns()``), taken as
  ``read()`` returns each frame.
* **Opening** can block (a server that accepts and sends nothing; a stream FFmpeg cannot
  probe), so every open runs with FFmpeg's own open timeout and on a helper thread that is
  abandoned after ``open_timeout`` plus a second. A failure is a :class:`LiveSourceError`
  of one line naming the source and what FFmpeg said (:mod:`pipeline.io.ffmpeg_messages`).
* **Reconnecting.** A read that fails (the server closed, nothing for ``read_timeout``
  seconds, by default ``READ_TIMEOUT_S``) is retried with back-off (0.25 s doubling to 1 s)
  for ``reconnect`` seconds; the next frame taken carries the gap (seconds, frames missed at
  the nominal rate). Not back in time, the capture ends and says why.

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

from pipeline.io.ffmpeg_messages import ffmpeg_messages, is_damage
from pipeline.io.frame_numbers import FrameNumbers
from pipeline.io.udp_relay import kept_since

__all__ = ["LiveCapture", "LiveFrame", "LiveSourceError", "is_live_source", "camera_device", "READ_TIMEOUT_S"]

#: URL schemes that are opened as live streams through FFmpeg
LIVE_SCHEMES = ("rtsp", "rtsps", "rtmp", "rtmps", "http", "https", "tcp", "udp", "srt", "rtp")
#: by default, a stream that delivers nothing for this long is taken as lost (FFmpeg's read timeout)
READ_TIMEOUT_S = 5.0
#: back-off between reconnection attempts: first wait, and the most it grows to
BACKOFF_FIRST_S, BACKOFF_MAX_S = 0.25, 1.0
_DEVICE = re.compile(r"^/dev/video\d+$")
# OpenCV's property ids (this module imports cv2 only when it opens a source)
CAP_PROP_FPS, CAP_PROP_FRAME_TYPE, CAP_PROP_N_THREADS, CAP_PROP_PTS = 5, 69, 70, 71
#: the frame types (CAP_PROP_FRAME_TYPE, av_get_picture_type_char) that decode from no other frame
KEY_TYPES = (ord("I"), ord("i"))


class LiveSourceError(ValueError):
    """A live source that cannot be opened: one line naming it and what FFmpeg (or the OS) said."""


def _msec(seconds: float) -> int:
    """``seconds`` as OpenCV's capture properties take a timeout: whole milliseconds in a C int (a longer wait,
    such as ``--reconnect inf``'s, is held to about 24.8 days; a larger number fails the call)."""
    return min(int(seconds * 1000), 2**31 - 1)


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
    """One decoded frame: the camera's frame number, its host capture stamp, the image, the frames
    that never arrived just before it, and whether it was decoded from damaged data."""

    frame: int
    stamp_ns: int
    image: np.ndarray | None  # None for a skipped frame whose image was not kept
    missed: int = 0
    damaged: bool = False


@dataclass(frozen=True)
class LiveFrame:
    """A frame taken from a :class:`LiveCapture` and what happened since the previous one taken.

    skipped : frames decoded since the previous frame taken, and not taken (newest frame wins).
    skipped_frames : those frames, when the capture keeps them (``keep_skipped``).
    gap_s : seconds without frames while the stream was lost and reopened since then.
    events : ``(kind, message)`` reports: ``reconnected`` (with the gap), ``frames_missed`` (a gap
        in the stream's timestamps), ``damaged_input`` (FFmpeg reported damaged data), in order.
    missed : frames that never arrived since the previous frame taken.
    damaged : this frame was decoded from damaged data (see the module docstring).
    """

    frame: int
    stamp_ns: int
    image: np.ndarray
    skipped: int = 0
    skipped_frames: tuple[Captured, ...] = ()
    gap_s: float = 0.0
    events: tuple[tuple[str, str], ...] = ()
    missed: int = 0
    damaged: bool = False


@dataclass
class _Slot:
    held: Captured | None = None  # the first frame, kept until taken
    latest: Captured | None = None
    skipped: int = 0
    kept: list[Captured] = field(default_factory=list)
    gap_s: float = 0.0
    events: list[tuple[str, str]] = field(default_factory=list)
    missed: int = 0


class LiveCapture:
    """A live source read on its own thread; the newest frame wins (see the module docstring).

    Parameters
    ----------
    source : stream URL or V4L2 device path.
    fps : nominal frame rate, used to say how many frames a gap missed when the stream does not
        declare its own.
    open_timeout : seconds an open (and its first frame) may take.
    reconnect : seconds to keep trying after the stream is lost (0: end at once).
    read_timeout : seconds without a new frame before the stream is taken as lost.
    keep_skipped : keep the images of skipped frames (for the recording).
    stop : end after this many frames (None: when the stream ends).
    url : where to open ``source``'s stream instead, when it is relayed (:mod:`pipeline.io.udp_relay`);
        reports name ``source``.
    """

    def __init__(self, source: str, fps: float = 25.0, open_timeout: float = 10.0, reconnect: float = 5.0,
                 keep_skipped: bool = False, stop: int | None = None, url: str = "",
                 read_timeout: float = READ_TIMEOUT_S) -> None:
        self.source = source
        self.url, self._kept_since = kept_since(url or source)  # a relay's URL says since when it kept the stream
        self.fps = fps
        self.open_timeout = open_timeout
        self.reconnect = reconnect
        self.read_timeout = read_timeout
        self.keep_skipped = keep_skipped
        self.stop = stop
        self.captured = 0  # frames decoded since the open
        self.skipped = 0  # frames decoded and never taken
        self.missed = 0  # frames that never arrived (gaps in the stream's timestamps, reconnects)
        self.damaged = 0  # frames decoded from damaged data
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
        self._numbers: FrameNumbers | None = None  # made at the open, with the stream's declared rate
        self._damage_run = False  # the last frame decoded was damaged
        self._ahead = 0  # frames still suspect after FFmpeg reported damage (it decodes ahead)

    # -- opening -------------------------------------------------------------------------------
    def open(self) -> "LiveCapture":
        """Open the source and decode its first frame, then start reading. Raises :class:`LiveSourceError`."""
        if _DEVICE.match(self.source) and not os.path.exists(self.source):
            cams = sorted(glob.glob("/dev/video*"))
            raise LiveSourceError(f"no camera at {self.source}: the device does not exist (cameras here: "
                                  f"{', '.join(cams) or 'none'})")
        self._messages.start()
        self._listening = True
        opened_ns = time.time_ns()  # frames from here on may wait in buffers (a relay's: since it was bound)
        try:
            cap, first, stamp = self._open_once(self.open_timeout)
        except LiveSourceError:
            self._stop_listening()
            raise
        self._cap = cap
        self.shape = tuple(first.shape)
        fps = float(cap.get(CAP_PROP_FPS))
        self.declared_fps = fps if 0 < fps < 1000 else 0.0
        self._numbers = FrameNumbers(self.declared_fps or self.fps, since_ns=self._kept_since or opened_ns)
        self._decoded(cap, first, stamp, [])
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
                    cap = cv2.VideoCapture(self.url, cv2.CAP_FFMPEG,
                                           [cv2.CAP_PROP_OPEN_TIMEOUT_MSEC, _msec(max(timeout, 0.1)),
                                            cv2.CAP_PROP_READ_TIMEOUT_MSEC, _msec(self.read_timeout)])
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
    def _decoded(self, cap, img: np.ndarray, stamp: int, said: list[tuple[int, str]], gap_s: float = 0.0,
                 lost: str = "", attempt: int = 0) -> None:
        """Number a frame just decoded, judge its damage from what FFmpeg said while it was decoded
        (``said``) and its type, report a gap or the start of damage, and put it in the slot. After
        reconnect ``attempt``, ``gap_s`` is the time without frames and ``lost`` what the report says
        of the loss."""
        assert self._numbers is not None
        reopened = gap_s > 0 or bool(lost)
        bad_ahead = False
        n = self._numbers.number(float(cap.get(CAP_PROP_PTS)), stamp, reopened)
        bad = [text for level, text in said if is_damage(level, text)]
        kind = int(cap.get(CAP_PROP_FRAME_TYPE))
        if bad:  # FFmpeg decodes up to (threads - 1) frames ahead of the one handed over: those are suspect too
            self._ahead = max(0, int(cap.get(CAP_PROP_N_THREADS)) - 1)
        elif self._ahead and not reopened:
            self._ahead -= 1
            bad_ahead = True
        # a predicted frame decodes from the frames before it: their damage goes on to the next keyframe
        damaged = (bool(bad) or (self._damage_run and not reopened and (
            bad_ahead or (kind > 0 and kind not in KEY_TYPES))))
        events: list[tuple[str, str]] = []
        rate = self.declared_fps or self.fps
        counted = "by the stream's timestamps" if n.exact else f"about, at {rate:g} frames/s"
        if lost:
            events.append(("reconnected", (
                f"{lost}; back after {gap_s:.2f} s (attempt {attempt}), {n.missed} frames missed ({counted}"
                + (f"; {n.jump}" if n.jump else "") + f"); tracking resumes at "
                f"frame {n.frame} with the motion model's uncertainty grown for the {gap_s:.2f} s")))
        elif n.missed or n.jump:
            first_missed = n.frame - n.missed
            which = (f"frames {first_missed}-{n.frame - 1}" if n.missed > 1 else f"frame {first_missed}")
            events.append(("frames_missed", (
                f"{self.source}: " + (f"{n.jump}; " if n.jump else "")
                + (f"{which} never arrived ({n.missed} frames, {n.missed / rate:.2f} s, {counted}); "
                   if n.missed else "") + f"tracking resumes at frame {n.frame}")))
        if bad and not self._damage_run:
            events.append(("damaged_input", (
                f"{self.source}: frame {n.frame} decoded from damaged data (FFmpeg: {bad[0]}"
                + (f"; {len(bad) - 1} more message(s)" if len(bad) > 1 else "")
                + "); the frames decoded from it are damaged until the next keyframe")))
        self._damage_run = damaged
        self._put(Captured(n.frame, stamp, img, n.missed, damaged), gap_s, events)

    def _put(self, f: Captured, gap_s: float = 0.0, events: list[tuple[str, str]] | None = None) -> None:
        with self._cond:
            first = self.captured == 0
            self.captured += 1
            self.missed += f.missed
            self.damaged += f.damaged
            self._last_ns = f.stamp_ns
            s = self._slot
            s.missed += f.missed
            s.gap_s += gap_s
            s.events += events or []
            if first:
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
        while not self._closing.is_set() and cap is not None:
            try:
                ok, img = cap.read()
            except cv2.error:
                ok, img = False, None
            stamp = time.time_ns()
            if ok and img is not None:  # a frame of another size too: the source stage reports it
                self._decoded(cap, img, stamp, self._messages.collect_levels())  # what FFmpeg said decoding it
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
        last = self._numbers.last if self._numbers is not None else self.captured - 1
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
            self.reconnects += 1
            self._damage_run, self._ahead = False, 0  # a new connection starts decoding afresh
            self._decoded(cap, img, stamp, [], gap_s=gap, lost=f"{self.source}: lost after frame {last} ({why})",
                          attempt=attempts)
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
                return LiveFrame(first.frame, first.stamp_ns, first.image, damaged=first.damaged)
            f, s.latest = s.latest, None
            assert f is not None and f.image is not None  # the wait above ended with a latest frame, kept whole
            out = LiveFrame(f.frame, f.stamp_ns, f.image, s.skipped, tuple(s.kept), s.gap_s,
                            tuple(s.events), s.missed, f.damaged)
            s.skipped, s.kept, s.gap_s, s.events, s.missed = 0, [], 0.0, [], 0
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
            t.join(timeout=self.read_timeout + 1.0)
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

