"""The time between two frames a stage sees, in nominal frame periods: :func:`gflow_core.tracker.time_step`
(where the rule and its bounds live) in the frame period of the stage's source.

The stage computes the step from the capture stamps of the two frames' headers and hands it to the
tracker as a parameter. Files keep their bits: their stamps are media time, the stage context's
period is 0, and the step is exactly 1.0.
"""

from __future__ import annotations

from gflow_core.tracker import MAX_TIME_STEP, time_step as periods

from .base import StageContext

__all__ = ["time_step", "MAX_TIME_STEP"]


def time_step(ctx: StageContext, stamp_ns: int, prev_stamp_ns: int) -> float:
    """:func:`gflow_core.tracker.time_step` in ``ctx.frame_period_ns`` (0: media time, a step of 1.0)."""
    return periods(ctx.frame_period_ns, stamp_ns, prev_stamp_ns)
