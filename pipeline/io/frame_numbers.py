"""The camera's frame number of each frame a live stream delivers, from the stream's own timestamps.

A frame's number is what a user joins a CSV row to their video by, so it must not depend on
how many frames happened to arrive. Most streams carry presentation timestamps (MPEG-TS over
TCP, UDP, RTSP, RTMP, SRT); OpenCV gives them in the stream's frame periods
(``CAP_PROP_PTS``, the "FPS time base"), so frame ``n`` of the stream is ``pts - pts_0`` where
``pts_0`` is the first frame received (each frame's number is the last one's plus the step of
the timestamps). Frames that never arrived (a network outage, packets a demuxer dropped, a
reconnect to a sender that went on sending) then leave a gap in the numbers, and the gap's
length is counted exactly. A stream without timestamps (MJPEG over HTTP) is
numbered by counting the frames decoded, and a reconnect by the host clock's estimate of the
frames missed.

The stream's clock is trusted only where the host clock agrees with it. A frame is never received
before it was sent, so ``stamp - pts / rate`` (when it arrived, less when the stream says it was
taken) is the sender's clock offset plus the frame's delay, at least the offset: a frame whose
value falls more than :data:`SLACK_S` below the lowest the offset can be claims a time later
than it can have been sent. That, or a step backwards (a sender that restarted and starts its
clock again, a camera that resets), is a discontinuity: the numbers go on from the host clock's
estimate of the frames missed, and the stream's timestamps count from there again. A repeated
timestamp (a camera's clock jitter rounded to its frame period) takes the next number, and a
step of one frame period is never a discontinuity.

The lowest the offset can be is the smallest value seen, or less: the first frame may have
waited. In a backlog that built up while the source opened (a sender that began first, a relay
that kept its datagrams from before the pipeline started, a server that sends what it encoded
before the client came) every frame comes late, the first the latest, and the frames after an
outage inside it would seem to come from the future. So the first frame is taken to have been
sent, at the earliest, when the host began to keep the stream (``since_ns``: the open, or the
relay's binding): a jump is judged against the host time since the stream could first have
arrived, and a clock that jumps further ahead than that (plus :data:`SLACK_S`) is still a
discontinuity. After a discontinuity the frame that retook the clock is the bound.

The host time since the previous frame was read would not do as the judge, nor alone as the
estimate: a demuxer hands over the last frame before a pause only when data comes again. The
estimate counts from when the previous frame came by its timestamp at the smallest delay seen,
when that is sooner than when it was read.

Whichever way a frame is numbered, its number is the last one's plus one plus the frames missed
before it, so the frames numbered and the frames missed add up to the camera's span.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["FrameNumbers", "Numbered", "SLACK_S", "NO_PTS"]

#: seconds by which a frame may seem to come sooner after it was taken than any frame before it
#: (the jitter of the host's stamps, taken after a decode; a sender's clock running a little fast)
SLACK_S = 2.0
#: what OpenCV gives for a frame with no timestamp (AV_NOPTS_VALUE as a double); anything below
#: this is taken as none
NO_PTS = -1e18


@dataclass(frozen=True)
class Numbered:
    """A frame's number and what came before it.

    frame : the camera's frame number (0 for the first frame received).
    missed : frames that never arrived just before it.
    exact : the number comes from the stream's timestamps (False: counted, or estimated by the
        host clock).
    jump : "" or why the stream's clock was not followed (a discontinuity, said in words).
    """

    frame: int
    missed: int = 0
    exact: bool = True
    jump: str = ""


class FrameNumbers:
    """Numbers frames in the order they are decoded (see the module docstring).

    Parameters
    ----------
    rate : frames per second to estimate the frames a host-clock gap held (the stream's
        declared rate, else the nominal ``--fps``).
    since_ns : host clock (ns) from which the stream's data may have been kept for the first frame
        (the open's start; a relay's binding); 0: the first frame's own stamp.
    """

    def __init__(self, rate: float, since_ns: int = 0) -> None:
        self.rate = rate
        self.since_ns = since_ns
        self.last = -1  # the last frame's number
        self._last_pts: float | None = None  # the last frame's timestamp (None: it had none)
        self._last_ns = 0
        self._offset = 0.0  # the smallest (arrival - stream time) in seconds since the stream's clock was (re)taken
        self._floor = 0.0  # the smallest it can be: the first frame's, had it been sent at since_ns (else _offset's)

    def _estimate(self, stamp_ns: int) -> int:
        """Frames missed by the host clock: the periods since the last frame, less the one it took.
        The last frame counts from when it was read or, sooner, when it came by its timestamp at the
        smallest delay seen (a demuxer hands the frame before a pause over when data comes again)."""
        if not self._last_ns:
            return 0
        last_ns = float(self._last_ns)
        if self._last_pts is not None:
            last_ns = min(last_ns, (self._offset + self._last_pts / self.rate) * 1e9)
        return max(0, int(round((stamp_ns - last_ns) / 1e9 * self.rate)) - 1)

    def number(self, pts: float, stamp_ns: int, reopened: bool = False) -> Numbered:
        """The number of the next frame decoded: its timestamp ``pts`` in the stream's frame periods
        (below :data:`NO_PTS`: none), the host clock ``stamp_ns`` when it was read, and whether the
        stream was reopened since the last frame (a reconnect)."""
        has_pts = pts > NO_PTS
        offset = stamp_ns / 1e9 - pts / self.rate if has_pts else 0.0
        retake = True  # the stream's clock is taken afresh from this frame
        if self.last < 0:  # the first frame received is frame 0
            out = Numbered(0, 0, has_pts)
        elif not has_pts or self._last_pts is None:  # counted (a reconnect: estimated by the host clock)
            missed = self._estimate(stamp_ns) if reopened else 0
            out = Numbered(self.last + 1 + missed, missed, False)
        else:
            step = int(round(pts - self._last_pts))
            lowest = min(self._offset, self._floor)  # the lowest the sender's clock offset can be
            if step == 1 or (step > 1 and offset >= lowest - SLACK_S):
                out, retake = Numbered(self.last + step, step - 1, True), False
            elif step == 0 and not reopened:  # a repeated timestamp: the next number (and the next period)
                out, retake = Numbered(self.last + 1, 0, True), False
                pts += 1.0
            else:
                missed = self._estimate(stamp_ns)
                why = (f"the stream's clock went back {-step} frame periods" if step < 0 else
                       f"the stream's clock jumped {step} frame periods, {lowest - offset:.1f} s further than "
                       f"the time that passed here")
                out = Numbered(self.last + 1 + missed, missed, False, why)
        self._offset = offset if retake else min(self._offset, offset)
        if retake:  # the first frame: sent, at the earliest, when the host began to keep the stream
            first = self.last < 0 and has_pts and self.since_ns
            self._floor = min(offset, self.since_ns / 1e9 - pts / self.rate) if first else offset
        self.last = out.frame
        self._last_pts = pts if has_pts else None
        self._last_ns = stamp_ns
        return out
