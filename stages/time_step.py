"""The time between two frames a stage sees, in nominal frame periods.

A tracker's motion model is tuned per frame. A live source skips frames when the tracker is
slower than the camera (the newest frame wins) and loses some while it reconnects, so the
frames a stage sees are not one period apart: its motion noise and proposal widths must grow
with the time that passed. The stage computes the step from the capture stamps of the two
frames' headers and hands it to the mathematics as a parameter.

Files keep their bits: their stamps are media time, the stage context's period is 0, and the
step is exactly 1.0 (multiplying by 1.0 and taking sqrt(1.0) are exact).
"""

from __future__ import annotations

from .base import StageContext

__all__ = ["time_step", "MAX_TIME_STEP"]

#: the longest step a stage is told (25 periods: one second at 25 frames/s). After a longer gap
#: (a reconnect) the motion models' spread already covers any motion a tracker could follow,
#: and the search windows that grow with it stay affordable.
MAX_TIME_STEP = 25.0


def time_step(ctx: StageContext, stamp_ns: int, prev_stamp_ns: int) -> float:
    """Elapsed time from the frame stamped ``prev_stamp_ns`` to the one stamped ``stamp_ns``,
    in nominal frame periods, within [1, :data:`MAX_TIME_STEP`].

    1.0 when the source stamps media time (``ctx.frame_period_ns`` is 0) or either stamp is
    missing (0: a message made without a frame). Never below 1: a live source delivers at most
    one frame a period, and the host stamps of frames decoded in a burst are closer together
    than the camera took them.
    """
    period = ctx.frame_period_ns
    if period <= 0 or stamp_ns <= 0 or prev_stamp_ns <= 0:
        return 1.0
    return min(MAX_TIME_STEP, max(1.0, (stamp_ns - prev_stamp_ns) / period))
