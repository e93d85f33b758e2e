"""G-flow filter stage: credibilities, resampling and texture update (Marks et al. 2004, sec. 3.1, 3.3, 3.4).

Inputs: ``features`` of frame t and ``proposals0 .. proposals{K-1}``, the pose opinions of the K
proposal shards for frame t. Outputs: ``state`` (:class:`ExpertStates`, the experts after frame t,
which the proposal stages turn into the proposals of t + 1) and ``estimate`` (:class:`PoseEstimate`).

The stage is an adapter of :class:`gflow_core.gflow.GFlowTracker`: the first usable frame is its
``init`` (the model placed in ``init``, or a user morphable model, resource ``model``), every other
frame its ``update_or_coast`` of the shards' proposals, concatenated; the mathematics, the
estimate's fields and the lost guard's verdicts are documented there and in
:class:`gflow_msgs.gflow.PoseEstimate`. The filter never holds the background textures: the
proposal stages do (``stages/gflow_proposal.py``), and ``init`` runs with ``backgrounds=False``.
What G-flow reads of frame t, with its colour bins (the preprocess stage's ``colour``; bins that do
not fit are reported as ``bad_features`` and that frame is judged on edges alone) and the guard's
orientation channels, depends on the frame alone: the stage makes it in ``prepare``
(``prepare_ports``), on a stage process's second thread while it waits for the proposals.

Coasting. A missing or unusable frame, missing or bad proposals (another configuration's digest,
another shard's experts, wrong shapes), or an update that fails make the filter coast (the experts
keep their poses and credibilities, their texels are only predicted, eq. 9, 10; ``state =
"coast"``; the rule is the tracker's, :meth:`gflow_core.gflow.GFlowTracker.update_or_coast`), and
the problem is reported. The state message is published on every frame, so the
proposal -> filter cycle never stalls.

The snapshot (version 3) holds the experts, the guard's anchor and distributions and the online
guard's model of the face; without that model it is written as version 2, byte for byte as before
version 3, so older recordings re-run bit for bit. A version-2 snapshot restores with the model
started afresh on the next frame, a version-1 snapshot with the guard off.
"""

from __future__ import annotations

from typing import Any, Mapping

import msgspec
import numpy as np

from gflow_core.gflow import GFlowObservation, GFlowParams, GFlowState, Proposals
from gflow_core.gflow.split import (filter_observation, joined_proposals, message_dims, restored_state, shard_indices,
                                   start_filter)
from gflow_core.gflow.state_fields import STATE_FIELDS, state_fields
from gflow_core.gflow.tracker import TRACKER
from gflow_core.tracker import Estimate, unseen

from .base import Output, StageContext, StageInputError
from .gflow_common import GFlowStage, GFlowStageFields, unpack_states
from gflow_msgs.gflow import pose_estimate_of, read_shards, states_of
from gflow_msgs.messages import ExpertStates, Features, Header, Message, PoseEstimate, PoseProposals, bins_of
from gflow_msgs.base import packed_fields, unpacked_fields
from gflow_msgs.snapshots import GFlowFilterSnapshot, GFlowFilterSnapshotV2
from .time_step import MAX_TIME_STEP
from gflow_msgs.params import stage_params

__all__ = ["GFlowFilterStage", "GFlowFilterParams"]

class GFlowFilterFields(GFlowStageFields, frozen=True):
    """The G-flow parameters (:class:`gflow_core.gflow.GFlowParams`, equal to the proposal stages'),
    the seed, the initial box and the number of proposal shards.

    shards : number of proposal stages; the filter has input ports ``proposals0 .. proposals{shards-1}``.
    """

    shards: int = 1


GFlowFilterParams = stage_params("GFlowFilterParams", GFlowParams, GFlowFilterFields, __name__)


class GFlowFilterStage(GFlowStage[GFlowFilterFields]):
    kind = "gflow.filter"
    Params = GFlowFilterParams
    inputs = {"features": Features, "proposals0": PoseProposals}
    outputs = {"state": ExpertStates, "estimate": PoseEstimate}

    @classmethod
    def ports(cls, params: GFlowFilterFields) -> tuple[Mapping[str, type], Mapping[str, type]]:
        ins: dict[str, type] = {"features": Features}
        ins.update({f"proposals{i}": PoseProposals for i in range(params.shards)})
        return ins, cls.outputs

    def __init__(self, params: GFlowFilterFields, ctx: StageContext) -> None:
        super().__init__(params, ctx)
        self.state: GFlowState | None = None
        self.shard_idx = [shard_indices(self.tracker.n_experts, k, params.shards) for k in range(params.shards)]
        self.coasted = 0

    # the first frame only needs features; afterwards the proposals of every shard too
    def required(self, seq: int) -> frozenset[str]:
        return frozenset({"features"}) if self.state is None else frozenset(self.inputs)

    # -- one frame ---------------------------------------------------------------------------
    def step(self, seq: int, inputs: Mapping[str, Message | None]) -> list[Output]:
        feat = inputs.get("features")
        if self.state is None:
            return self._initialise(seq, feat)
        obs = self._frame(feat, seq, self.state.setup.image_shape, "coasting")
        props = self._proposals(seq, inputs) if obs is not None else None
        header = self.header_of(feat if isinstance(feat, Features) else None, seq)
        # the update of the shards' proposals, or coasting without them, without the frame or when it fails
        new, est, failure = TRACKER.update_or_coast(self.tracker, self.state, props, obs, self.rng(seq))
        if failure is not None:
            self.report("update_failed", f"frame {seq}: {failure}; coasting", seq)
        self.state = new
        coasted = obs is None or props is None or failure is not None
        self.coasted += int(coasted)
        self.steps += 1
        return self._outputs(header, new, unseen(est) if coasted else est)  # coasted: the target was not seen

    def _outputs(self, header: Header, state: GFlowState, est: Estimate, first: bool = False) -> list[Output]:
        """The experts after the frame (the proposal stages' input: their parents are the estimate's,
        every expert its own on the first frame and when coasting) and the estimate."""
        out_state = states_of(header, state.experts, est.extras["parents"], state.setup.image_shape, self.digest,
                               first)
        x = est.extras
        self.last = {"seq": header.seq, "state": est.phase, "box": [round(v, 1) for v in est.box],
                     "ess": round(x["ess"], 1), "spread_px": round(x["spread_px"], 2),
                     "confidence": round(est.confidence, 3)}
        return [("state", out_state), ("estimate", pose_estimate_of(header, est))]

    def prepare(self, port: str, msg: Message) -> tuple[GFlowObservation, str]:
        """What G-flow reads of a frame, with the colour bins and the orientation channels the lost guard
        reads (:func:`gflow_core.gflow.split.filter_observation`), which depend on the frame alone: made
        as soon as it arrives, while the stage waits for the proposals. Returns the observation and what
        was wrong with the bins ("" when nothing was). Raises ValueError for a frame that cannot be used."""
        assert isinstance(msg, Features)
        return filter_observation(self.tracker, msg.grey.array, lambda shape: bins_of(msg, shape))

    def _proposals(self, seq: int, inputs: Mapping[str, Message | None]) -> Proposals | None:
        """Every shard's proposals for ``seq`` (:func:`gflow_msgs.gflow.read_shards`), concatenated; None
        (reported) if any is missing or bad."""
        assert self.state is not None
        msgs = [inputs.get(f"proposals{k}") for k in range(self.params.shards)]
        parts, problem = read_shards(msgs, self.digest, self.shard_idx, message_dims(self.state.setup), MAX_TIME_STEP)
        if parts is None:
            assert problem is not None
            self.report(problem[0], f"frame {seq}: {problem[1]}; coasting", seq)
            return None
        return joined_proposals(parts)

    def _initialise(self, seq: int, feat: Message | None) -> list[Output]:
        obs = self._frame(feat, seq, None, "waiting for a usable first frame", missing=False)
        if obs is None:
            return []
        assert isinstance(feat, Features)
        try:
            box = self.initial_box()
            # the filter keeps no backgrounds: the proposal stages start them from this frame
            state, est, self.digest = start_filter(self.tracker, obs, box, self.params.seed, self.rng(seq),
                                                   self.learned_model(False))
        except ValueError as e:
            self._init_failed(seq, str(e), "not tracking")
            return []
        setup = state.setup
        if setup.clipped:
            H, W = obs.grey.shape
            self.report("init_box_clipped", f"frame {seq}: initial box {box} reaches outside the {W}x{H} frame; "
                                            f"using {tuple(setup.box.round(2))}", seq)
        self.state = state
        return self._outputs(feat.header, state, est, first=True)

    # -- state ------------------------------------------------------------------------------------
    def summary(self) -> dict[str, Any]:
        return dict(self.last, steps=self.steps, coasted=self.coasted)

    # -- snapshot / restore: the experts as they travel, the rest of the posterior as its fields ----------
    snapshot_struct = GFlowFilterSnapshot
    # 2: the lost guard's anchor and distributions (1: none; restores without the guard); 3: the online guard's
    # model of the face (2: none; restores with the model started afresh)
    snapshot_versions = (1, 2, 3)

    def snapshot(self) -> bytes | None:
        """Version 3 where the online guard keeps a model of the face; version 2 (without its two fields)
        otherwise, byte for byte the snapshot the runs recorded before version 3 hold, so that they re-run
        bit for bit."""
        fields = self.snapshot_fields()
        if fields.get("online") is None and fields.get("online_values") is None:
            fields.pop("online", None), fields.pop("online_values", None)
            return msgspec.msgpack.encode(GFlowFilterSnapshotV2(version=2, **fields))
        return msgspec.msgpack.encode(GFlowFilterSnapshot(version=3, **fields))

    def snapshot_fields(self) -> dict[str, Any]:
        st = None
        if self.state is not None:
            s = self.state.experts
            st = states_of(self.header(int(self.last.get("seq", 0)), 0), s, np.arange(s.n_experts, dtype=np.int64),
                           self.state.setup.image_shape, self.digest)
        return dict(image_shape=None if self.state is None else self.state.setup.image_shape, digest=self.digest,
                    state=st, steps=self.steps, coasted=self.coasted, init_error=self.init_error,
                    **packed_fields(state_fields(self.state)))

    def restore_fields(self, snap: GFlowFilterSnapshot) -> None:
        self.state, self.digest = None, ""
        if snap.image_shape is not None and snap.state is not None:
            experts = snap.state
            try:
                self.state = restored_state(
                    self.tracker, self.initial_box(), self.params.seed, snap.image_shape,
                    self.learned_model(False), snap.digest,
                    lambda setup: unpack_states(experts, setup, None, "expert states"),
                    unpacked_fields({k: getattr(snap, k) for k in STATE_FIELDS}))
            except ValueError as e:  # MessageError and StageInputError too
                raise ValueError(f"bad gflow.filter snapshot: {e}") from None
            self.digest = snap.digest
        self.steps, self.coasted, self.init_error = snap.steps, snap.coasted, snap.init_error
