"""What the G-flow proposal and filter stages share: parameters, model placement, frames, message packing.

The two stages (``gflow.proposal``, ``gflow.filter``; Marks, Hershey, Roddey & Movellan, NIPS
2004) are adapters of :class:`gflow_core.gflow.GFlowTracker`, and what running it split across
processes needs beyond that (the configuration digest, the shards, the proposals' background
replica) is :mod:`gflow_core.gflow.split`. Both stages take every field of
:class:`gflow_core.gflow.GFlowParams` (:func:`stages.tracker_params.stage_params`), place the model
the same way on the first usable frame (:func:`prepare`: a user morphable model, resource
``model``, or the generic head fitted into the initial box, clipped to the frame) and compute the
same digest, which travels in every :class:`ExpertStates` and :class:`PoseProposals` message and is
checked once on receipt (:func:`unpack_states`, :func:`unpack_proposals`) and once on a restore
(:func:`gflow_core.gflow.split.restored_setup`). Random streams: :mod:`gflow_core.gflow.tracker` (expert ``i`` of frame
``t`` draws from ``[seed, crc32(stream), t, i]``, so shards concatenate to one process's result).
"""

from __future__ import annotations

import math
from typing import Any, Mapping

import numpy as np

from gflow_core.gflow import ExpertState, GFlowObservation, GFlowParams, ModelSetup, Proposals
from gflow_core.gflow.split import check_experts, check_frame_size, check_shard, placed
from gflow_core.gflow.tracker import TRACKER
from gflow_core.tracker import UnusableFrame

from .base import StageInputError
from gflow_msgs.base import ArrayTable, checked_arrays, packed_arrays
from gflow_msgs.gflow import EXPERT_ARRAYS, PROPOSAL_ARRAYS
from gflow_msgs.messages import ExpertStates, Features, Header, MessageError, NDArray, PoseProposals
from .time_step import MAX_TIME_STEP
from .tracker_params import SeedBoxFields

__all__ = ["GFlowStageFields", "initial_box", "prepare", "frame_of", "check_size", "states_msg", "unpack_states",
           "proposals_msg", "unpack_proposals"]


class GFlowStageFields(SeedBoxFields, frozen=True):
    """What every G-flow stage takes besides the tracker's parameters (``gflow info gflow``).

    seed : random seed (expert ``i`` of frame ``t`` draws from ``[seed, crc32(stream), t, i]``).
    init : (x, y, w, h) initial box of the face in the first usable frame, 0-based pixels.
    """

    def check(self, tracker: Any) -> None:
        super().check(tracker)
        # the number of proposal stages and this one's shard (the filter has none): each stage's own fields
        check_shard(tracker.n_experts, getattr(self, "shard", 0), getattr(self, "shards"))


def initial_box(fields: GFlowStageFields) -> tuple[float, float, float, float]:
    """The stage's initial box. Raises StageInputError when it has none."""
    if fields.init is None:
        raise StageInputError("G-flow needs an initial box: set init: [x, y, w, h] on the proposal and filter stages")
    return fields.init


def prepare(fields: GFlowStageFields, tracker: GFlowParams, resources: Mapping[str, Any],
            shape: tuple[int, int]) -> tuple[ModelSetup, str]:
    """The model placed in the initial box on frames of ``shape``, and its digest
    (:func:`gflow_core.gflow.split.placed`; identically in both stages).

    Raises
    ------
    StageInputError
        No initial box, a box outside the frame, a ``model`` resource that is not a morphable
        model, or a model that cannot be placed in the box.
    """
    try:
        return placed(tracker, initial_box(fields), fields.seed, shape, resources.get("model"))
    except ValueError as e:
        raise StageInputError(str(e)) from None


def frame_of(feat: Features, seq: int, tracker: GFlowParams) -> GFlowObservation:
    """What G-flow reads of a Features message (:meth:`GFlowTracker.observe_grey` of its grey image;
    both stages read frames with it, so they see bit-identical frames).

    Raises StageInputError for an undecodable array, not a 2-D uint8 image of at least 2 x 2
    pixels, or a uniform image (all black, saturated or any single grey level).
    """
    try:
        grey = feat.grey.array()
    except MessageError as e:
        raise StageInputError(f"frame {seq}: grey image: {e}") from None
    try:
        obs = TRACKER.observe_grey(tracker, grey)
    except UnusableFrame as e:
        raise StageInputError(f"frame {seq}: {e}; frame skipped") from None
    except ValueError as e:
        raise StageInputError(f"frame {seq}: {e}") from None
    return obs


def check_size(obs: GFlowObservation, seq: int, shape: tuple[int, int] | None) -> GFlowObservation:
    """:func:`gflow_core.gflow.split.check_frame_size` of frame ``seq``, its ValueError a
    StageInputError: the frame is skipped."""
    try:
        return check_frame_size(obs, shape)
    except ValueError as e:
        raise StageInputError(f"frame {seq}: {e}; frame skipped") from None


# -- messages <-> gflow_core --------------------------------------------------------------


def states_msg(header: Header, experts: ExpertState, parents: np.ndarray, image_shape: tuple[int, int], digest: str,
               first: bool = False) -> ExpertStates:
    """Pack the experts after frame ``header.seq`` (never their backgrounds: the proposal stages keep them)."""
    arrays = packed_arrays({k: getattr(experts, k) for k in EXPERT_ARRAYS if k != "parents"} | {"parents": parents},
                           EXPERT_ARRAYS)
    anchor = experts.tex_anchor
    return ExpertStates(header=header, **arrays, image_shape=(int(image_shape[0]), int(image_shape[1])),
                        config_digest=digest, first=bool(first),
                        tex_anchor=None if anchor is None else NDArray.of(np.asarray(anchor, np.float64)))


def _arr(nd: NDArray, name: str, shape: tuple[int, ...], dtype: str, where: str) -> np.ndarray:
    """:meth:`NDArray.checked`, its MessageError a StageInputError prefixed with ``where``."""
    try:
        return nd.checked(name, shape, dtype)
    except MessageError as e:
        raise StageInputError(f"{where}: {e}") from None


def _arrays(msg: Any, table: ArrayTable, dims: Mapping[str, int], where: str) -> dict[str, np.ndarray]:
    """:func:`~gflow_msgs.base.checked_arrays`, its MessageError a StageInputError prefixed with ``where``."""
    try:
        return checked_arrays(msg, table, dims)
    except MessageError as e:
        raise StageInputError(f"{where}: {e}") from None


def unpack_states(msg: ExpertStates, setup: ModelSetup, digest: str | None, where: str) -> dict[str, Any]:
    """Validate and unpack an ExpertStates message made for ``setup`` (whose digest is ``digest``;
    None: not checked, in a snapshot whose own digest was).

    Returns
    -------
    dict with poses (E, P), tex_mean (E, n), tex_var (E, n), log_credibility (E,), parents (E,), tex_anchor
    (n,) or None (``bg_mean`` / ``bg_var`` are never read: the proposal stages keep their own).

    Raises
    ------
    StageInputError
        Another configuration or model (digest), arrays of the wrong shape, dtype or with
        non-finite values, or experts that are not the setup's
        (:func:`gflow_core.gflow.split.check_experts`: another frame size, bad parents, a texture
        anchor missing or unexpected).
    """
    if digest is not None and msg.config_digest != digest:
        raise StageInputError(f"{where}: the expert states were made with another G-flow configuration, model or "
                              f"seed (digest {msg.config_digest}, this stage has {digest}); give the proposal "
                              f"and filter stages the same parameters")
    n = setup.model.n_vertices
    out: dict[str, Any] = _arrays(msg, EXPERT_ARRAYS, {"E": setup.cfg.n_experts, "P": setup.model.pose_size, "n": n},
                                  where)
    try:
        check_experts(setup, msg.image_shape, out["parents"], msg.tex_anchor is not None)
    except ValueError as e:
        raise StageInputError(f"{where}: {e}") from None
    out["tex_anchor"] = None if msg.tex_anchor is None else _arr(msg.tex_anchor, "tex_anchor", (n,), "float64", where)
    return out


def proposals_msg(header: Header, props: Proposals | None, shard: int, shards: int, digest: str) -> PoseProposals:
    """Pack :class:`gflow_core.gflow.Proposals` (or an empty shard when ``props`` is None)."""
    if props is None:  # every array without experts
        empty: dict[str, Any] = packed_arrays({f: np.zeros((0,) * len(shape)) for f, (shape, _) in
                                               PROPOSAL_ARRAYS.items()}, PROPOSAL_ARRAYS)
        return PoseProposals(header=header, **empty, shard=shard, shards=shards, config_digest=digest)
    return PoseProposals(header=header, **packed_arrays({f: getattr(props, f) for f in PROPOSAL_ARRAYS},
                                                        PROPOSAL_ARRAYS),
                         shard=shard, shards=shards, config_digest=digest,
                         reset=NDArray.of(np.asarray(props.reset, dtype=bool)) if props.reset.any() else None,
                         dt=float(props.dt))


def unpack_proposals(msg: PoseProposals, setup: ModelSetup, digest: str, shard: int, shards: int,
                     expected: np.ndarray, where: str) -> Proposals:
    """Validate a shard's PoseProposals and return :class:`gflow_core.gflow.Proposals`.

    An empty shard (the proposal stage had no usable frame or state) raises
    StageInputError saying so.
    """
    if msg.config_digest != digest:
        raise StageInputError(f"{where}: proposals made with another G-flow configuration, model or seed (digest "
                              f"{msg.config_digest}, the filter has {digest}); give every proposal stage and "
                              f"the filter the same parameters")
    if (msg.shard, msg.shards) != (shard, shards):
        raise StageInputError(f"{where}: expected shard {shard} of {shards}, got shard {msg.shard} of {msg.shards}; "
                              f"check the proposal stages' shard / shards parameters and the filter's wiring")
    Ep = expected.size
    if Ep and msg.expert_indices.shape == (0,):
        raise StageInputError(f"{where}: the proposal stage had no usable frame or expert state for this frame")
    if not (math.isfinite(msg.dt) and 1.0 <= msg.dt <= MAX_TIME_STEP):
        raise StageInputError(f"{where}: dt must be in [1, {MAX_TIME_STEP:g}] frame periods, got {msg.dt!r}")
    idx = _arr(msg.expert_indices, "expert_indices", (Ep,), "int64", where)
    if not np.array_equal(idx, expected):
        raise StageInputError(f"{where}: expert indices {idx.tolist()} are not this shard's {expected.tolist()}")
    dims = {"E'": Ep, "P": setup.model.pose_size, "s": setup.cfg.n_samples}
    arrays = _arrays(msg, {k: v for k, v in PROPOSAL_ARRAYS.items() if k != "expert_indices"}, dims, where)
    reset = np.zeros(Ep, dtype=bool) if msg.reset is None else _arr(msg.reset, "reset", (Ep,), "bool", where)
    return Proposals(expert_indices=idx, reset=reset, dt=float(msg.dt), **arrays)
