"""G-flow proposal stage: the experts' pose opinions for frame t (Marks et al. 2004, sec. 3.2).

Inputs: ``features`` of frame t (the grey image is ``y_t``) and ``state``, the experts
after frame t - 1 (:class:`ExpertStates` from the filter; ``input_offsets = {"state": 1}``
joins it with frame t). Output: ``proposals`` (:class:`PoseProposals`) of this stage's
shard of experts for frame t. The stage is an adapter of
:meth:`gflow_core.gflow.GFlowTracker.propose`; for each expert ``d`` of the shard
(:func:`gflow_core.gflow.propose`):

* the peak ``u_hat`` of its pose opinion by Gauss-Newton on eq. 14 and the Laplace
  covariance ``Sigma_hat`` (inverse Hessian);
* ``s`` samples from ``N(u_hat, alpha Sigma_hat)``;
* their importance weights (eq. 16) with the full likelihood of eq. 13;
* the expert's likelihood estimate (eq. 19).

Sharding: with ``shards = K`` the experts are split into K contiguous blocks and this
stage proposes for block ``shard``. Expert ``i`` of frame ``t`` draws only from
``default_rng([seed, crc32(stream), t, i])``, so the filter's concatenation of K shards is
bit for bit the proposals of one stage with ``shards = 1``.

The background replica. With ``background: true`` the likelihood (eq. 13) needs each
expert's background texels (E, H, W), which never travel (see ``stages/messages_gflow.py``).
The stage keeps its own copy of all E backgrounds (every shard needs all of them, since
any expert can be a parent) and advances it from the state message (new poses and
parents) and the previous frame it saw, with
:func:`gflow_core.gflow.filter.advance_background` (eq. 7-10), exactly as the filter
would. The copy stores each distinct 16 x 16 tile once (:mod:`gflow_core.gflow.background`;
bit for bit the dense arrays' values): 100 experts at 320x240 hold a few MB instead of
123 MB of float64 (and its second copy while a frame is advanced), which also keeps the
snapshot, taken after every frame for a restart, small. If frame t - 1 was missing or unusable here, the replica is only predicted
(eq. 9, 10: means kept, variances + Psi_b). If the replica does not describe frame t - 2
when state t - 1 arrives (a lost state message), it restarts from frame t - 1 and the
problem is reported.

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

import msgspec
import numpy as np

from gflow_core.gflow import ExpertState, GFlowObservation, GFlowParams, GFlowState, ModelSetup, Proposals
from gflow_core.gflow.background import TileLayout, TiledBackground
from gflow_core.gflow.filter import advance_background, initial_background, predict_background
from gflow_core.gflow.tracker import TRACKER

from .base import Output, Stage, StageContext, StageInputError
from .gflow_common import (GFlowStageFields, check_size, frame_of, prepare, proposals_msg, shard_indices,
                           unpack_states)
from .messages import ExpertStates, Features, Message, MessageError, NDArray, PoseProposals
from .rng import tracker_rng
from .time_step import time_step
from .tracker_params import stage_params, tracker_params

__all__ = ["GFlowProposalStage", "GFlowProposalParams"]

SNAPSHOT_VERSION = 2  # 2: the background replica as distinct tiles (1: dense (E, H, W) arrays)


class GFlowProposalFields(GFlowStageFields, frozen=True):
    """The G-flow parameters (:class:`gflow_core.gflow.GFlowParams`, equal to the filter's), the
    seed, the initial box, and which shard of the experts this stage proposes for.

    shard : index of this shard, ``0 <= shard < shards``.
    shards : number of proposal stages the experts are split across (``<= n_experts``).
    """

    shard: int = 0
    shards: int = 1

    def check(self, tracker: Any) -> None:
        super().check(tracker)
        if not 1 <= self.shards <= tracker.n_experts:
            raise ValueError(f"shards must be in [1, n_experts={tracker.n_experts}], got {self.shards}")
        if not 0 <= self.shard < self.shards:
            raise ValueError(f"shard must be in [0, shards={self.shards}), got {self.shard}")


GFlowProposalParams = stage_params("GFlowProposalParams", GFlowParams, GFlowProposalFields, __name__)


class _Snapshot(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Everything a proposal stage keeps between frames (msgpack; arrays as NDArray)."""

    version: int
    image_shape: tuple[int, int] | None
    digest: str
    init_seq: int  # -1: not initialised
    prev_seq: int  # -1: no previous frame
    prev_grey: NDArray | None
    bg_seq: int  # frame the background replica describes; -1: none
    bg_tile: int  # tile side of the replica (gflow_core.gflow.background)
    bg_table: NDArray | None  # (E, K) int32 tile ids
    bg_mean: NDArray | None  # (U, T*T) float64 distinct tiles
    bg_var: NDArray | None
    steps: int
    init_error: str


class GFlowProposalStage(Stage[GFlowProposalFields]):
    kind = "gflow.proposal"
    Params = GFlowProposalParams
    inputs = {"features": Features, "state": ExpertStates}
    outputs = {"proposals": PoseProposals}
    drivers = frozenset({"features"})
    input_offsets = {"state": 1}
    prepare_ports = frozenset({"features"})

    def __init__(self, params: GFlowProposalFields, ctx: StageContext) -> None:
        super().__init__(params, ctx)
        self.tracker: GFlowParams = tracker_params(params, GFlowParams)
        self.indices = shard_indices(self.tracker.n_experts, params.shard, params.shards)
        self.setup: ModelSetup | None = None
        self.digest = ""
        self.init_seq: int | None = None
        self.prev: tuple[int, np.ndarray] | None = None  # (seq, grey uint8) of the last usable frame
        self.bg: tuple[Any, Any] | None = None
        self.bg_seq = -1
        self.steps = 0
        self.init_error = ""
        self.last: dict[str, Any] = {}

    def required(self, seq: int) -> frozenset[str]:
        # before (and at) the frame the filter starts from there is no state to wait for
        if self.init_seq is None or seq <= self.init_seq:
            return frozenset({"features"})
        return frozenset({"features", "state"})

    # -- one frame ---------------------------------------------------------------------------
    def prepare(self, port: str, msg: Message) -> GFlowObservation:
        """What G-flow reads of a frame and the pyramid its proposals need (:meth:`GFlowTracker.with_pyramid`),
        which depend on the frame alone: made as soon as it arrives, while the stage waits for the
        experts. Raises StageInputError for a frame that cannot be used."""
        assert isinstance(msg, Features)
        return TRACKER.with_pyramid(self.tracker, frame_of(msg, msg.header.seq, self.tracker))

    def step(self, seq: int, inputs: Mapping[str, Message | None]) -> list[Output]:
        feat = inputs.get("features")
        obs = None
        if isinstance(feat, Features):
            try:
                obs = check_size(self.prepared("features", feat), seq, self.setup.image_shape if self.setup else None)
            except StageInputError as e:
                self.report("bad_features", f"{e}; no proposals for this frame", seq)
        elif self.init_seq is not None:
            self.report("missing_features", f"frame {seq}: no features arrived; no proposals for this frame", seq)
        if self.init_seq is None:
            self._initialise(seq, obs)
            return []
        assert self.setup is not None
        header = feat.header if isinstance(feat, Features) else self.header(seq, 0)
        out = self._propose(seq, obs, inputs.get("state"), header.stamp_ns)
        if obs is not None:
            self.prev = (seq, obs.grey)
        self.steps += 1
        msg = proposals_msg(header, out, self.params.shard, self.params.shards, self.digest)
        self.last = {"seq": seq, "experts": int(self.indices.size) if out is not None else 0}
        return [("proposals", msg)]

    def _initialise(self, seq: int, obs: GFlowObservation | None) -> None:
        """Place the model on the first usable frame, as the filter does on the same frame."""
        if obs is None:
            return
        try:
            self.setup, self.digest = prepare(self.params, self.tracker, self.ctx.resources, obs.grey.shape)
        except StageInputError as e:
            if str(e) != self.init_error:  # say it once, not on every frame
                self.init_error = str(e)
                self.report("init_failed", f"frame {seq}: {e}", seq)
            return
        self.init_seq = seq
        self.prev = (seq, obs.grey)

    def _propose(self, seq: int, obs: GFlowObservation | None, state_msg: Message | None,
                 stamp_ns: int = 0) -> Proposals | None:
        """Advance the background replica to t - 1, then propose for frame t (None: no proposals)."""
        s = self.setup
        assert s is not None
        if not isinstance(state_msg, ExpertStates):
            self.report("missing_state", f"frame {seq}: the expert state of frame {seq - 1} did not arrive; "
                                         f"no proposals for this frame", seq)
            return None
        try:
            st = unpack_states(state_msg, s, self.digest, f"expert state {seq - 1}")
        except StageInputError as e:
            self.report("bad_state", f"{e}; no proposals for frame {seq}", seq)
            return None
        bg_mean = bg_var = None
        if s.cfg.background:
            if not self._advance_background(seq, st, state_msg.first):
                return None
            assert self.bg is not None
            bg_mean, bg_var = self.bg
        if obs is None:
            return None
        experts = ExpertState(poses=st["poses"], tex_mean=st["tex_mean"], tex_var=st["tex_var"], bg_mean=bg_mean,
                              bg_var=bg_var, log_credibility=st["log_credibility"], image_shape=s.image_shape,
                              tex_anchor=st["tex_anchor"])
        try:
            dt = time_step(self.ctx, stamp_ns, state_msg.header.stamp_ns)  # periods since the state's frame
            return TRACKER.propose(self.tracker, GFlowState(s, experts), obs,
                                   tracker_rng(self.params.seed, self.ctx.stream, seq), dt, self.indices)
        except (ValueError, np.linalg.LinAlgError) as e:
            self.report("propose_failed", f"frame {seq}: {type(e).__name__}: {e}; no proposals", seq)
            return None

    def _advance_background(self, seq: int, st: dict[str, Any], first: bool) -> bool:
        """Bring the replica from frame t - 2 to t - 1 (eq. 7-10). False if it cannot be had."""
        s = self.setup
        assert s is not None
        t1 = seq - 1
        prev = s.observation(self.prev[1]) if self.prev is not None and self.prev[0] == t1 else None
        poses, parents = st["poses"], st["parents"]
        if first or self.bg is None or self.bg_seq != t1 - 1:
            if prev is None:
                self.report("no_background", f"frame {seq}: the background model cannot start without frame "
                                             f"{t1}; no proposals for this frame", seq)
                self.bg, self.bg_seq = None, -1
                return False
            if not first:
                self.report("background_reset", f"frame {seq}: the background replica was at frame {self.bg_seq}, "
                                                f"not {t1 - 1}; restarted from frame {t1}", seq)
            # B_1 = the frame, unknown under each expert's object
            self.bg = initial_background(s.model, poses, prev, s.cfg)
        elif prev is not None:
            # each child: its parent's background predicted (eq. 9, 10) and updated with y_{t-1} (eq. 7, 8)
            self.bg = advance_background(self.bg[0], self.bg[1], poses, parents, prev, s.model, s.cfg)
        else:
            # frame t - 1 was not seen here: prediction only, mu unchanged (eq. 9), sigma + Psi_b (eq. 10)
            self.bg = predict_background(self.bg[0], self.bg[1], parents, s.cfg)
        self.bg_seq = t1
        return True

    # -- state ------------------------------------------------------------------------------------
    def summary(self) -> dict[str, Any]:
        return dict(self.last, steps=self.steps, shard=f"{self.params.shard}/{self.params.shards}",
                    background_at=self.bg_seq)

    def snapshot(self) -> bytes:
        bank = None if self.bg is None else self.bg[0].bank
        snap = _Snapshot(
            version=SNAPSHOT_VERSION,
            image_shape=None if self.setup is None else self.setup.image_shape,
            digest=self.digest,
            init_seq=-1 if self.init_seq is None else self.init_seq,
            prev_seq=-1 if self.prev is None else self.prev[0],
            prev_grey=None if self.prev is None else NDArray.of(self.prev[1]),
            bg_seq=self.bg_seq if bank is not None else -1,
            bg_tile=0 if bank is None else bank.layout.tile,
            bg_table=None if bank is None else NDArray.of(bank.table),
            bg_mean=None if bank is None else NDArray.of(bank.pool_mean),
            bg_var=None if bank is None else NDArray.of(bank.pool_var),
            steps=self.steps, init_error=self.init_error)
        return msgspec.msgpack.encode(snap)

    def restore(self, data: bytes) -> None:
        try:
            snap = msgspec.msgpack.decode(data, type=_Snapshot)
        except msgspec.DecodeError as e:
            raise ValueError(f"not a gflow.proposal snapshot: {e}") from None
        if snap.version != SNAPSHOT_VERSION:
            raise ValueError(f"gflow.proposal snapshot version {snap.version}, this code reads {SNAPSHOT_VERSION}")
        self.setup, self.digest = None, ""
        if snap.image_shape is not None:
            try:
                self.setup, self.digest = prepare(self.params, self.tracker, self.ctx.resources, snap.image_shape)
            except StageInputError as e:
                raise ValueError(str(e)) from None
            if self.digest != snap.digest:
                raise ValueError(f"the snapshot was made with another G-flow configuration, model or seed (digest "
                                 f"{snap.digest}, this stage has {self.digest})")
        try:
            self.prev = None if snap.prev_grey is None else (snap.prev_seq, snap.prev_grey.array().copy())
            self.bg = None
            if snap.bg_table is not None and snap.bg_mean is not None and snap.bg_var is not None:
                if self.setup is None:
                    raise ValueError("corrupt gflow.proposal snapshot: a background replica without a frame size")
                bank = TiledBackground(TileLayout(self.setup.image_shape, snap.bg_tile),
                                       snap.bg_table.array().astype(np.int32), snap.bg_mean.array().copy(),
                                       snap.bg_var.array().copy())
                if bank.n_experts != self.setup.cfg.n_experts:
                    raise ValueError(f"corrupt gflow.proposal snapshot: a background replica of {bank.n_experts} "
                                     f"experts, this stage has {self.setup.cfg.n_experts}")
                self.bg = (bank.mean, bank.var)
        except MessageError as e:
            raise ValueError(f"corrupt gflow.proposal snapshot: {e}") from None
        self.init_seq = None if snap.init_seq < 0 else snap.init_seq
        self.bg_seq = snap.bg_seq
        self.steps = snap.steps
        self.init_error = snap.init_error
