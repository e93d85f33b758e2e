"""Proposal stage of the contour particle filter: samples p(X_t | X_{t-1}) (M2 sec. 4.3).

A registration of :class:`stages.box_tracker.BoxProposalStage` (the stage logic every tracker's
proposal shares) whose proposal of whole clouds is :class:`gflow_core.contour.dynamics.ContourProposal`
(:func:`~gflow_core.contour.dynamics.proposal_dynamics`), the proposal of the contour trackers' protocol
(:class:`~gflow_core.contour.protocol.ContourTracker`).

Input ``particles`` is the resampled posterior of frame t-1 (from the filter stage); the
output ``proposals`` are the particles for frame t, drawn from the dynamics with the
random stream ``FrameRng(seed, crc32(stream), t).stream(PURPOSE)`` (``PURPOSE_PROPOSAL``).

With no learned model (the chamfer tracker, K = 1) the dynamics are a random walk on
beta = (ux, uy, theta, log s) with the given standard deviations; with a learned M2
model (resource ``model``) they are its Markov matrix and AR(1) process. A model with
patch exemplars (the mouth tracker, sec. 5.2) is tracked "with no alpha transformations":
k follows the Markov matrix and alpha is passed through unchanged.

Departure from the paper (sec. 4.3): with ``init`` set (``gflow track --tracker m2`` sets it
to the start box), the AR(1) process on log s reverts to the initial box's scale, not to
the learned mean. The learned mean is the training person's distance from the training
camera: a model learned on caviar1 (people about 28x73 px) pulled a 17x50 px pedestrian of
crossing to 28x73 within three frames. Translation is a random walk, theta's mean is ~0.

With ``timed`` (set for live sources by ``pipeline/runtime/live_plan.py``) the stage also reads
the frames and joins frame t + 1 with the posterior of t, so the noise grows with the time
between the two frames' capture stamps (:mod:`stages.time_step`).

The stage keeps no state that its outputs depend on; its snapshot holds the step counter.
"""

from __future__ import annotations

from typing import Any, ClassVar

from gflow_core.contour.dynamics import PURPOSE_PROPOSAL, ContourProposal, proposal_dynamics
from gflow_core.builtin_trackers import CHAMFER, M2
from gflow_core.contour.params import ChamferParams
from gflow_core.m2.model import M2Model

from .base import Params, StageContext
from .box_tracker import BoxProposalStage, CloudProposal
from gflow_msgs.params import SeedBoxFields, stage_params
from .spec_box import tracker_stage

__all__ = ["ProposalStage", "ProposalParams", "ProposalFields", "ChamferProposalStage", "ChamferProposalParams",
           "M2ProposalStage", "M2ProposalParams"]

PURPOSE = PURPOSE_PROPOSAL  # 0x9209

class ProposalFields(SeedBoxFields, frozen=True):
    """What the chamfer and m2 proposal stages take besides their tracker's parameters: ``seed``,
    ``init`` (:class:`~gflow_msgs.params.SeedBoxFields`; the AR(1) process on log s reverts to the
    initial box's scale), ``model`` (a learned M2 model's path) and ``timed`` (also read the frames:
    the noise grows with the time to the next frame)."""

    model: str = ""
    timed: bool = False


#: the generic proposal (graphs of your own, ``gflow demo``): the random walk is ChamferParams' (declared,
#: defaulted and checked there), not a copy
ProposalParams = stage_params("ProposalParams", ChamferParams, ProposalFields, __name__,
                              "Dynamics of the generic proposal: ``seed``, ``init`` (with a learned contour model "
                              "the AR(1) process on log s reverts to this box's scale), ``model`` (a learned M2 "
                              "model's path; empty: the random walk), ``timed`` and the random walk's ``std_xy``, "
                              "``std_theta``, ``std_log_s`` (:class:`gflow_core.contour.params.ChamferParams`).",
                              only=("std_xy", "std_theta", "std_log_s"))


class ProposalStage(BoxProposalStage):
    kind = "particle.proposal"
    Params: ClassVar[type[Params]] = ProposalParams
    #: whether the stage needs a learned model (the ``model`` resource): its dynamics
    needs_model: ClassVar[bool] = False

    def _clouds(self, params: Any, ctx: StageContext) -> CloudProposal:
        """The contour proposal the stage's parameters and its ``model`` resource make
        (:func:`proposal_dynamics`)."""
        model = self.learned_model(self.needs_model)
        if model is not None and not isinstance(model, M2Model):
            raise ValueError(f"stage {ctx.name!r}: model {params.model!r} is a {type(model).__name__}, "
                             "not an M2 model")
        # patch exemplars are tracked with no alpha transformations (sec. 5.2)
        walk = None if model is not None else (params.std_xy, params.std_theta, params.std_log_s)
        return ContourProposal(*proposal_dynamics(model, params.init, walk))

    @property
    def purpose(self) -> int:
        return PURPOSE


#: the chamfer and m2 trackers' proposals, made from their specs (a learned model, its dynamics, required where
#: the spec's is)
ChamferProposalStage, M2ProposalStage = (tracker_stage(ProposalStage, s, "Proposal", ProposalFields, __name__,
                                                       needs_model=s.model_required) for s in (CHAMFER, M2))
ChamferProposalParams, M2ProposalParams = ChamferProposalStage.Params, M2ProposalStage.Params
