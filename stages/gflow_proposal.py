"""G-flow proposal stage: the experts' pose opinions for frame t (Marks et al. 2004, sec. 3.2).

Inputs: ``features`` of frame t (the grey image is ``y_t``) and ``state``, the experts after frame
t - 1 (:class:`ExpertStates` from the filter; ``input_offsets = {"state": 1}`` joins it with frame
t). Output: ``proposals`` (:class:`PoseProposals`) of this stage's shard of experts for frame t.
The stage is an adapter of :meth:`gflow_core.gflow.GFlowTracker.propose` (for each expert: the peak
of its pose opinion by Gauss-Newton on eq. 14, the Laplace covariance, ``s`` samples and their
weights, eq. 16, and its likelihood estimate, eq. 19).

Sharding: with ``shards = K`` the experts are split into K contiguous blocks
(:func:`gflow_core.gflow.split.shard_indices`) and this stage proposes for block ``shard``. Expert
``i`` of frame ``t`` draws only from ``default_rng([seed, crc32(stream), t, i])``, so the filter's
concatenation of K shards is bit for bit the proposals of one stage with ``shards = 1``.

The background replica. With ``background: true`` the likelihood (eq. 13) needs each
expert's background texels (E, H, W), which never travel (see ``gflow_msgs/gflow.py``):
the stage keeps a :class:`gflow_core.gflow.split.BackgroundReplica` of all E of them (any
expert can be a parent), advanced from the state message and the previous frame it saw exactly
as the filter would (eq. 7-10), stored as distinct 16 x 16 tiles (a few MB, not 123 MB, for 100
experts at 320x240; the snapshot holds the tiles). A frame t - 1 not seen here only predicts it
(eq. 9, 10); a lost state message restarts it from frame t - 1, and the problem is reported.

Per-frame image work. What G-flow reads of frame t (the contrast-normalised grey levels) and the
pyramid with gradient images its Gauss-Newton reads depend on the frame alone: the stage makes
them in ``prepare`` (``prepare_ports``), which a stage process runs on its second thread as soon as
the features arrive, while it waits for the state of t - 1; ``step`` then only proposes. The same
arrays either way (``--inline`` makes them in ``step``).

The time step. The proposals of frame t are made for the periods since the state's frame
(:func:`stages.time_step.time_step` of the two frames' stamps: 1 for files, the real time for a
live source that skipped frames; :meth:`gflow_core.gflow.GFlowConfig.at_pace`), and carry it to
the filter (``PoseProposals.dt``), which predicts the texels over the same periods.

No usable frame t or no state t - 1: the stage publishes an *empty* proposal message
(no experts) for frame t and reports why, so the filter coasts instead of waiting.
"""

from __future__ import annotations

from typing import Any, Mapping


from gflow_core.gflow import GFlowObservation, GFlowParams, Proposals
from gflow_core.gflow.split import (BackgroundReplica, ProposalShard, proposal_observation, restored_setup,
                                   shard_indices)

from .base import Output, StageContext, StageInputError
from .gflow_common import GFlowStage, GFlowStageFields, unpack_states
from gflow_msgs.gflow import proposals_of
from gflow_msgs.messages import ExpertStates, Features, Message, MessageError, PoseProposals
from gflow_msgs.base import packed_fields, unpacked_fields
from gflow_msgs.snapshots import GFlowProposalSnapshot
from .time_step import time_step
from gflow_msgs.params import stage_params

__all__ = ["GFlowProposalStage", "GFlowProposalParams"]

class GFlowProposalFields(GFlowStageFields, frozen=True):
    """The G-flow parameters (:class:`gflow_core.gflow.GFlowParams`, equal to the filter's), the
    seed, the initial box, and which shard of the experts this stage proposes for.

    shard : index of this shard, ``0 <= shard < shards``.
    shards : number of proposal stages the experts are split across (``<= n_experts``).
    """

    shard: int = 0
    shards: int = 1


GFlowProposalParams = stage_params("GFlowProposalParams", GFlowParams, GFlowProposalFields, __name__)


class GFlowProposalStage(GFlowStage[GFlowProposalFields]):
    kind = "gflow.proposal"
    Params = GFlowProposalParams
    inputs = {"features": Features, "state": ExpertStates}
    outputs = {"proposals": PoseProposals}
    input_offsets = {"state": 1}

    def __init__(self, params: GFlowProposalFields, ctx: StageContext) -> None:
        super().__init__(params, ctx)
        self.indices = shard_indices(self.tracker.n_experts, params.shard, params.shards)
        self.shard = ProposalShard()  # the model placed, the background replica and the last usable frame

    def required(self, seq: int) -> frozenset[str]:
        # before (and at) the frame the filter starts from there is no state to wait for
        if self.shard.init_seq is None or seq <= self.shard.init_seq:
            return frozenset({"features"})
        return frozenset({"features", "state"})

    # -- one frame ---------------------------------------------------------------------------
    def prepare(self, port: str, msg: Message) -> tuple[GFlowObservation, str]:
        """What G-flow reads of a frame and the pyramid its proposals need
        (:func:`gflow_core.gflow.split.proposal_observation`), which depend on the frame alone: made as
        soon as it arrives, while the stage waits for the experts; and "" (the proposals read no colour
        bins). Raises ValueError for a frame that cannot be used."""
        assert isinstance(msg, Features)
        return proposal_observation(self.tracker, msg.grey.array), ""

    def step(self, seq: int, inputs: Mapping[str, Message | None]) -> list[Output]:
        feat, setup = inputs.get("features"), self.shard.setup
        obs = self._frame(feat, seq, setup.image_shape if setup else None, "no proposals for this frame",
                          missing=self.shard.init_seq is not None)
        if self.shard.init_seq is None:
            if obs is not None:  # the model placed on the first usable frame, as the filter does on the same frame
                try:  # no initial box, a box outside the frame, a model resource that cannot be placed in it
                    self.shard = self.shard.started(self.tracker, self.initial_box(), self.params.seed, seq, obs.grey,
                                                    self.learned_model(False))
                except ValueError as e:
                    self._init_failed(seq, str(e))
            return []
        header = self.header_of(feat if isinstance(feat, Features) else None, seq)
        out = self._propose(seq, obs, inputs.get("state"), header.stamp_ns)
        if obs is not None:
            self.shard = self.shard.seen(seq, obs.grey)
        self.steps += 1
        msg = proposals_of(header, out, self.params.shard, self.params.shards, self.shard.digest)
        self.last = {"seq": seq, "experts": int(self.indices.size) if out is not None else 0}
        return [("proposals", msg)]

    def _propose(self, seq: int, obs: GFlowObservation | None, state_msg: Message | None,
                 stamp_ns: int = 0) -> Proposals | None:
        """Advance the background replica to t - 1, then propose for frame t (None: no proposals)."""
        s = self.shard.setup
        assert s is not None
        if not isinstance(state_msg, ExpertStates):
            self.report("missing_state", f"frame {seq}: the expert state of frame {seq - 1} did not arrive; "
                                         f"no proposals for this frame", seq)
            return None
        try:
            st = unpack_states(state_msg, s, self.shard.digest, f"expert state {seq - 1}")
        except StageInputError as e:
            self.report("bad_state", f"{e}; no proposals for frame {seq}", seq)
            return None
        dt = time_step(self.ctx, stamp_ns, state_msg.header.stamp_ns)  # periods since the state's frame
        self.shard, out, problems = self.shard.propose(self.tracker, seq, st, state_msg.first, obs, self.rng(seq), dt,
                                                       self.indices)
        for kind, text in problems:
            self.report(kind, text, seq)
        return out

    # -- state ------------------------------------------------------------------------------------
    def summary(self) -> dict[str, Any]:
        return dict(self.last, steps=self.steps, shard=f"{self.params.shard}/{self.params.shards}",
                    background_at=self.shard.replica.seq)

    # -- snapshot / restore: the model's placement and the background replica (as distinct tiles) ---------
    snapshot_struct = GFlowProposalSnapshot
    snapshot_versions = (2,)  # 2: the background replica as distinct tiles (1: dense (E, H, W) arrays)

    def snapshot_fields(self) -> dict[str, Any]:
        return dict(steps=self.steps, init_error=self.init_error, **packed_fields(self.shard.fields()))

    def restore_fields(self, snap: GFlowProposalSnapshot) -> None:
        setup = None
        if snap.image_shape is not None:
            setup, _ = restored_setup(self.tracker, self.initial_box(), self.params.seed, snap.image_shape,
                                      self.learned_model(False), snap.digest)
        try:
            replica = unpacked_fields({k: getattr(snap, k) for k in BackgroundReplica().fields()})
            self.shard = ProposalShard.of_fields(setup, snap.init_seq, snap.digest, replica)
        except (MessageError, ValueError) as e:
            raise ValueError(f"corrupt gflow.proposal snapshot: {e}") from None
        self.steps = snap.steps
        self.init_error = snap.init_error
