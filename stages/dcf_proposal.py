"""Proposal stage of the correlation-filter tracker: the random walk about the posterior of t-1.

An adapter of :meth:`gflow_core.dcf.tracker.DCFTracker.propose` (:func:`gflow_core.dcf.dynamics.walk`):
input ``particles`` is the resampled posterior of frame t-1 (from ``dcf.filter``), output
``proposals`` the particles for frame t, drawn with ``FrameRng(seed, crc32(stream), t).stream(PURPOSE_WALK)``.
The walk's std is ``std_xy_rel sqrt(w h)`` of the initial box ``init``; the velocity and the noise
that grows with the target's speed are added by the filter, which holds them. Its parameters are
every field of :class:`gflow_core.dcf.params.DCFParams` (the filter's values: ``gflow track`` sets
both), ``seed``, ``init`` and ``timed`` (also read the frames: the noise grows with the time to
the next frame, :mod:`stages.time_step`).

The stage keeps no state that its outputs depend on; its snapshot holds the step counter. It is a
registration of :class:`stages.box_tracker.BoxProposalStage` (the stage logic it shares with the
appearance tracker's).
"""

from __future__ import annotations

from gflow_core.dcf.params import DCFParams
from gflow_core.dcf.spec import SPEC

from .box_tracker import BoxProposalStage
from .spec_box import box_proposal_spec
from .tracker_params import SeedBoxFields, stage_params

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


class DCFProposalStage(BoxProposalStage):
    kind = "dcf.proposal"
    Params = DCFProposalParams
    box = box_proposal_spec(SPEC)
