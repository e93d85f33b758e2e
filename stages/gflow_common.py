"""What the G-flow proposal and filter stages share: parameters, model placement, frames, messages read.

The two stages (``gflow.proposal``, ``gflow.filter``; Marks, Hershey, Roddey & Movellan, NIPS
2004) are adapters of :class:`gflow_core.gflow.GFlowTracker`, and what running it split across
processes needs beyond that (the configuration digest, the shards, what a proposal process keeps
and does with a frame, the filter process's start and restore) is :mod:`gflow_core.gflow.split`.
Both stages take every field of :class:`gflow_core.gflow.GFlowParams`
(:func:`gflow_msgs.params.stage_params`), place the model the same way on the first usable
frame (:meth:`gflow_core.gflow.split.ProposalShard.started`, :func:`gflow_core.gflow.split.start_filter`:
a user morphable model, resource ``model``, or the generic head fitted into the initial box, clipped
to the frame) and compute the same digest, which travels in every :class:`ExpertStates` and
:class:`PoseProposals` message and is checked once on receipt (:func:`unpack_states`,
:func:`gflow_msgs.gflow.read_shards`: the packing and checking of the messages is :mod:`gflow_msgs.gflow`'s)
and once on a restore (:func:`gflow_core.gflow.split.restored_setup`,
:func:`gflow_core.gflow.split.restored_state`). The digest stays although a graph's tracker block now
hands every stage one parameter block: the messages of every G-flow recording carry it (a
recording re-runs bit for bit only if it is made the same way), and a graph file without a tracker
block still names the parameters per stage, which it guards. Random streams:
:mod:`gflow_core.gflow.tracker` (expert ``i`` of frame ``t`` draws from ``[seed, crc32(stream), t,
i]``, so shards concatenate to one process's result).

They are not registrations of the generic box stages (:mod:`stages.box_tracker`): what travels is
not a particle cloud but the experts (:class:`ExpertStates`, whose backgrounds stay in the proposal
processes) and sharded pose opinions (one port a shard, each checked against the digest), the
proposal stage keeps state (the background replica) and reads the frames as well as the posterior,
the time step travels with the proposals, a first frame the model cannot be placed on is waited
past rather than refused, and an update that fails coasts. Each of these is a step the box stages
would have to hand over, which would leave them nothing of their own. What every tracker's stages
do alike is :class:`stages.base.Stage`'s: a frame's features read into the prepared observation or
reported missing or bad with what the stage does without it (``observed``), the frame's size
(``same_size``), the frame's draws (``rng``), the snapshot (``snapshot_struct``,
``snapshot_fields``, ``restore_fields``). What the two G-flow stages do alike besides is
:class:`GFlowStage`'s: the tracker's parameters, the colour bins' problems, and a first frame the
model cannot be placed on reported once and waited past. The rules themselves are the tracker's
(:meth:`gflow_core.gflow.GFlowTracker.update_or_coast`, ``with_bins``) and
:mod:`gflow_core.gflow.split`'s (the digest, the shards, the arrays' dimensions,
:func:`gflow_core.gflow.split.message_dims`).
"""

from __future__ import annotations

from typing import Any, TypeVar

from gflow_core.gflow import GFlowObservation, GFlowParams, ModelSetup
from gflow_core.gflow.split import check_experts, check_shard, message_dims

from .base import Stage, StageContext, StageInputError
from gflow_msgs.gflow import read_states
from gflow_msgs.messages import ExpertStates, Features, Message
from gflow_msgs.params import SeedBoxFields, tracker_params

__all__ = ["GFlowStageFields", "GFlowStage", "unpack_states"]


class GFlowStageFields(SeedBoxFields, frozen=True):
    """What every G-flow stage takes besides the tracker's parameters (``gflow info gflow``).

    seed : random seed (expert ``i`` of frame ``t`` draws from ``[seed, crc32(stream), t, i]``).
    init : (x, y, w, h) initial box of the face in the first usable frame, 0-based pixels.
    """

    def check(self, tracker: Any) -> None:
        super().check(tracker)
        # the number of proposal stages and this one's shard (the filter has none): each stage's own fields
        check_shard(tracker.n_experts, getattr(self, "shard", 0), getattr(self, "shards"))


F = TypeVar("F", bound=GFlowStageFields)


class GFlowStage(Stage[F]):
    """What both G-flow stages do alike (module docstring). A subclass sets ``kind``, ``Params``,
    ``inputs`` and ``outputs`` and gives :meth:`prepare`: (the frame's observation as the stage reads it,
    what was wrong with its colour bins or "")."""

    drivers = frozenset({"features"})
    prepare_ports = frozenset({"features"})

    def __init__(self, params: F, ctx: StageContext) -> None:
        super().__init__(params, ctx)
        self.tracker: GFlowParams = tracker_params(params, GFlowParams)
        self.digest = ""
        self.steps = 0
        self.init_error = ""
        self.last: dict[str, Any] = {}

    def _frame(self, feat: Message | None, seq: int, shape: tuple[int, int] | None, then: str,
               missing: bool = True) -> GFlowObservation | None:
        """:meth:`prepare`'s observation of frame ``seq``'s features (:meth:`~stages.base.Stage.observed`), of
        a frame of ``shape`` (H, W) (None: any size, :meth:`~stages.base.Stage.same_size`), or None when there
        is none, reported (``missing_features`` only when ``missing``) with ``then``, what the stage does
        without it. Bad colour bins are reported too: the lost guard weighs the edges alone on that frame."""
        got = self.observed("features", feat if isinstance(feat, Features) else None, seq, then, missing)
        if got is None:
            return None
        obs, problem = got
        if problem:
            self.report("bad_features", f"frame {seq}: {problem}; the lost guard weighs edges only", seq)
        return obs if self.same_size("features", seq, obs.grey.shape, shape, then) else None

    def initial_box(self) -> tuple[float, float, float, float]:
        """The stage's initial box; ValueError when it has none."""
        return self.params.initial_box("G-flow", " (on the proposal and filter stages)")

    def _init_failed(self, seq: int, error: str, then: str = "") -> None:
        """Report that the model cannot be placed on frame ``seq`` (``error``; ``then``: what the stage does
        meanwhile), once for each distinct reason rather than on every frame it waits past."""
        if error != self.init_error:
            self.init_error = error
            self.report("init_failed", f"frame {seq}: {error}" + (f"; {then}" if then else ""), seq)


# -- messages -> gflow_core ---------------------------------------------------------------


def unpack_states(msg: ExpertStates, setup: ModelSetup, digest: str | None, where: str) -> dict[str, Any]:
    """:func:`gflow_msgs.gflow.read_states` of a message made for ``setup`` (whose digest is ``digest``;
    None: not checked, in a snapshot whose own digest was), then
    :func:`gflow_core.gflow.split.check_experts` (another frame size, bad parents, a texture anchor
    missing or unexpected); either's error a StageInputError prefixed with ``where``."""
    try:
        out = read_states(msg, message_dims(setup), digest)
        check_experts(setup, msg.image_shape, out["parents"], msg.tex_anchor is not None)
    except ValueError as e:  # MessageError too
        raise StageInputError(f"{where}: {e}") from None
    return out
