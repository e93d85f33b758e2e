"""Proposal stage of the appearance tracker: the dynamics' random walk about the posterior of t-1.

An adapter of :func:`gflow_core.appearance.dynamics.walk`, the proposal of
:class:`~gflow_core.appearance.tracker.AppearanceTracker`: input ``particles`` is the resampled
posterior of frame t-1 (from ``appearance.filter``), output ``proposals`` the particles for frame
t, drawn with ``FrameRng(seed, crc32(stream), t).stream(PURPOSE_WALK)``. The walk's std for the
centre is ``std_xy_rel sqrt(w h)`` of the initial box ``init``, so this stage needs it as the
filter does. Its parameters are every field of
:class:`gflow_core.appearance.params.AppearanceParams` (the same values as the filter's: ``gflow
track`` sets both), ``seed``, ``init`` and ``timed``.

With ``timed`` (set for live sources by ``pipeline/runtime/live_plan.py``) the stage also reads
the frames and joins frame t + 1 with the posterior of t, so the noise grows with the time
between the two frames' capture stamps (:mod:`stages.time_step`).

The stage keeps no state that its outputs depend on; its snapshot holds the step counter. It is a
registration of :class:`stages.box_tracker.BoxProposalStage` (the stage logic it shares with the
correlation-filter tracker's).
"""

from __future__ import annotations

from gflow_core.appearance.params import AppearanceParams
from gflow_core.appearance.spec import SPEC

from .box_tracker import BoxProposalStage
from .spec_box import box_proposal_spec
from .tracker_params import SeedBoxFields, stage_params

__all__ = ["AppearanceProposalStage", "AppearanceProposalParams", "AppearanceProposalFields", "AppearanceStageFields"]


class AppearanceStageFields(SeedBoxFields, frozen=True):
    """What every appearance stage takes besides the tracker's parameters (``gflow info appearance``):
    ``seed`` (frame ``t`` draws from ``[seed, crc32(stream), t, purpose]``) and ``init``, the
    (x, y, w, h) initial box of the target in the first frame, 0-based pixels."""


class AppearanceProposalFields(AppearanceStageFields, frozen=True):
    """The appearance stages' own fields and ``timed`` (also read the frames: the noise grows with the
    time to the next frame)."""

    timed: bool = False


AppearanceProposalParams = stage_params(
    "AppearanceProposalParams", AppearanceParams, AppearanceProposalFields, __name__,
    "Appearance proposal settings: every field of :class:`gflow_core.appearance.params.AppearanceParams` "
    "(the filter's values), ``seed``, ``init`` and ``timed``.")


class AppearanceProposalStage(BoxProposalStage):
    kind = "appearance.proposal"
    Params = AppearanceProposalParams
    box = box_proposal_spec(SPEC)
