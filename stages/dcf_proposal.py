"""Proposal stage of the correlation-filter tracker: the random walk about the posterior of t-1.

An adapter of :meth:`gflow_core.dcf.tracker.DCFTracker.propose` (:func:`gflow_core.dcf.dynamics.walk`):
input ``particles`` is the resampled posterior of frame t-1 (from ``dcf.filter``), output
``proposals`` the particles for frame t, drawn with ``FrameRng(seed, crc32(stream), t).stream(PURPOSE_WALK)``.
The walk's std is ``std_xy_rel sqrt(w h)`` of the initial box ``init``; the velocity and the noise
that grows with the target's speed are added by the filter, which holds them. Its parameters are
every field of :class:`gflow_core.dcf.params.DCFParams` (the filter's values: ``gflow track`` sets
both), ``seed``, ``init`` and ``timed`` (also read the frames: the noise grows with the time to
the next frame, :mod:`stages.time_step`).

The stage keeps no state that its outputs depend on; its snapshot holds the step counter.
"""

from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from gflow_core.dcf.dynamics import PURPOSE_WALK, walk
from gflow_core.dcf.params import DCFParams
from gflow_core.m2.tracking import ParticleCloud

from .base import Output, Stage, StageContext
from .messages import Frame, Message, Particles
from .particle_proposal import cloud_of, counter_snapshot, particles_msg, restored_counter
from .rng import tracker_rng
from .time_step import time_step
from .tracker_params import SeedBoxFields, stage_params, tracker_params

__all__ = ["DCFProposalStage", "DCFProposalParams", "DCFProposalFields", "DCFStageFields"]


class DCFStageFields(SeedBoxFields, frozen=True):
    """What every correlation-filter stage takes besides the tracker's parameters (``gflow info dcf``):
    ``seed`` (frame ``t`` draws from ``[seed, crc32(stream), t, purpose]``) and ``init``, the (x, y, w, h)
    initial box of the target in the first frame, 0-based pixels."""


class DCFProposalFields(DCFStageFields, frozen=True):
    """The stages' own fields and ``timed`` (also read the frames: the noise grows with the time to the
    next frame)."""

    timed: bool = False


DCFProposalParams = stage_params(
    "DCFProposalParams", DCFParams, DCFProposalFields, __name__,
    "Correlation-filter proposal settings: every field of :class:`gflow_core.dcf.params.DCFParams` (the "
    "filter's values), ``seed``, ``init`` and ``timed``.")


class DCFProposalStage(Stage[DCFProposalFields]):
    kind = "dcf.proposal"
    Params = DCFProposalParams
    inputs = {"particles": Particles}
    outputs = {"proposals": Particles}
    input_offsets = {"frames": -1}  # timed: frame t + 1 joins the posterior of t

    @classmethod
    def ports(cls, params: DCFProposalFields) -> tuple[Mapping[str, type], Mapping[str, type]]:
        return ({"particles": Particles, "frames": Frame} if params.timed else cls.inputs), cls.outputs

    def __init__(self, params: DCFProposalFields, ctx: StageContext) -> None:
        super().__init__(params, ctx)
        if params.init is None:
            raise ValueError("the dcf proposal needs the initial box (its random walk is relative to the box's "
                             "size): set init: [x, y, w, h]")
        self.core = tracker_params(params, DCFParams)
        self.size0 = (float(params.init[2]), float(params.init[3]))
        self.done = 0

    def step(self, seq: int, inputs: Mapping[str, Message | None]) -> list[Output]:
        msg = inputs["particles"]
        assert isinstance(msg, Particles)
        cloud = cloud_of(msg)
        t = seq + 1
        frame = inputs.get("frames")
        dt = time_step(self.ctx, frame.header.stamp_ns, msg.header.stamp_ns) if isinstance(frame, Frame) else 1.0
        alpha = walk(self.core, cloud.alpha, self.size0, tracker_rng(self.params.seed, self.ctx.stream, t)
                     .stream(PURPOSE_WALK), dt)
        out = ParticleCloud(alpha=alpha, k=np.zeros(cloud.n, np.int64), log_w=np.zeros(cloud.n))
        self.done += 1
        return [("proposals", particles_msg(self.header(t, msg.header.stamp_ns), "proposal", out))]

    def summary(self) -> dict[str, Any]:
        return {"proposed": self.done}

    def snapshot(self) -> bytes:
        return counter_snapshot(self.done)

    def restore(self, data: bytes) -> None:
        self.done = restored_counter(self.ctx.name, data)
