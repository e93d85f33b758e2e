"""G-flow filter stage: credibilities, resampling and texture update (Marks et al. 2004, sec. 3.1, 3.3, 3.4).

Inputs: ``features`` of frame t and ``proposals0 .. proposals{K-1}``, the pose opinions
of the K proposal shards for frame t. Outputs: ``state`` (:class:`ExpertStates`, the
experts after frame t, which the proposal stages turn into the proposals of t + 1) and
``estimate`` (:class:`PoseEstimate`).

Per frame (:func:`gflow_core.gflow.update`): the credibility of each expert (eq. 17 with
the likelihood estimate of eq. 19), normalised over experts; children drawn from parents
in proportion to credibility, each taking a pose from its parent's weighted samples
(sec. 3.4, eq. 15); the Kalman update of the children's object texels (eq. 7-10). The
filter never holds the background textures: with the background model on, they live in
the proposal stages (see ``stages/gflow_proposal.py``), and ``update`` runs with
``bg_mean = None``, which changes nothing else.

The estimate: ``box`` is, for a learned face (a model with a reference box), the initial box
moved and scaled with the face (``gflow_core.gflow.face_pose.following_box``), otherwise the
bounding box of the projected vertices of the posterior mean pose; ``expert_points`` are every
expert's projected vertices (the paper's figure 2), ``mean_points`` the mean's, ``landmarks`` the
reference landmark of each vertex; ``pose``, ``pose_std``, ``rotation``, ``spread_px`` and ``ess``
summarise the posterior, ``yaw_pitch_roll`` and ``expression`` read it as a face. ``confidence`` is
the fraction of vertices the frame explains as the object (``Estimate.inlier_fraction``: in the
image and within the outlier process's standard deviations of their texel), and ``target_state``
is ``occluded`` below ``occluded_below``, ``lost`` below ``lost_below``, else ``tracked``; a
coasting frame repeats the last observed frame's.

First frame: the model is fitted into ``init`` (generic head) or a user morphable model
(resource ``model``) is placed in it, and the experts start at that pose (optionally
jittered by ``init_jitter``, "initialised randomly near the correct pose", sec. 5), with
object texels read from the frame (``Var(V_1) = v_init_var``).

Coasting. A missing or unusable frame, missing or bad proposals, or an update that fails
make the filter *coast*: the experts keep their poses and credibilities, their texels are
only predicted (eq. 9, 10), the estimate says ``state = "coast"``, and the problem is
reported. The state message is published on every frame, so the proposal -> filter
cycle never stalls. Nothing is ever NaN.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Mapping

import msgspec
import numpy as np

from gflow_core.gflow import ExpertState, init_state, update
from gflow_core.gflow.filter import predict_texels
from gflow_core.gflow.credibility import ess, posterior_mean_pose, pose_spread
from gflow_core.gflow.geometry import COEF, project, rotation_matrices
from gflow_core.gflow.head_model import bounding_box
from gflow_core.gflow.face_pose import expression, following_box, yaw_pitch_roll
from gflow_core.gflow.filter import concatenate_proposals

from .base import Output, Stage, StageInputError
from .gflow_common import (
    PURPOSE_INIT,
    GFlowParams,
    ModelSetup,
    frame_of,
    prepare_model,
    shard_indices,
    states_msg,
    unpack_proposals,
    unpack_states,
    update_rng,
)
from .messages import ExpertStates, Features, Header, Message, NDArray, PoseEstimate, PoseProposals
from .rng import frame_rng

__all__ = ["GFlowFilterStage", "GFlowFilterParams"]

SNAPSHOT_VERSION = 1


class GFlowFilterParams(GFlowParams):
    """The G-flow parameters (:class:`~stages.gflow_common.GFlowParams`, equal to the
    proposal stages'), the number of proposal shards, and the initial spread.

    shards : number of proposal stages; the filter has input ports ``proposals0 ..
        proposals{shards-1}``.
    init_jitter : standard deviations of the experts' initial poses about the initial box's
        pose: (rotation in radians, translation in pixels, morph coefficients as a fraction
        of their initial value). ``(0, 0, 0)``: every expert starts at the same pose.
    occluded_below, lost_below : the estimate's ``confidence`` is the fraction of the model's vertices
        the frame explains as the object (``Estimate.inlier_fraction`` of ``gflow_core.gflow.update``);
        below ``occluded_below`` the target is ``occluded``, below ``lost_below`` ``lost``.
    """

    shards: int = 1
    init_jitter: tuple[float, float, float] = (0.0, 0.0, 0.0)
    occluded_below: float = 0.6
    lost_below: float = 0.3

    def __post_init__(self) -> None:
        super().__post_init__()
        if not 1 <= self.shards <= self.n_experts:
            raise ValueError(f"shards must be in [1, n_experts={self.n_experts}], got {self.shards}")
        if not all(np.isfinite(v) and v >= 0 for v in self.init_jitter):
            raise ValueError(f"init_jitter must be three finite numbers >= 0, got {self.init_jitter}")
        if not 0.0 <= self.lost_below <= self.occluded_below <= 1.0:
            raise ValueError(f"need 0 <= lost_below <= occluded_below <= 1, got {self.lost_below}, "
                             f"{self.occluded_below}")


class _Snapshot(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Everything the filter keeps between frames (msgpack). ``state`` has no backgrounds."""

    version: int
    image_shape: tuple[int, int] | None
    digest: str
    state: ExpertStates | None
    steps: int
    coasted: int
    init_error: str
    confidence: float = 1.0  # of the last observed frame
    target_state: str = "tracked"


class GFlowFilterStage(Stage):
    kind = "gflow.filter"
    Params = GFlowFilterParams
    inputs = {"features": Features, "proposals0": PoseProposals}
    outputs = {"state": ExpertStates, "estimate": PoseEstimate}
    drivers = frozenset({"features"})

    @classmethod
    def ports(cls, params: GFlowFilterParams) -> tuple[Mapping[str, type], Mapping[str, type]]:  # type: ignore[override]
        ins: dict[str, type] = {"features": Features}
        ins.update({f"proposals{i}": PoseProposals for i in range(params.shards)})
        return ins, cls.outputs

    def __init__(self, params: GFlowFilterParams, ctx) -> None:
        super().__init__(params, ctx)
        self.setup: ModelSetup | None = None
        self.state: ExpertState | None = None
        self.shard_idx = [shard_indices(params.n_experts, k, params.shards) for k in range(params.shards)]
        self.steps = 0
        self.coasted = 0
        self.init_error = ""
        self.last: dict = {}
        self.confidence: tuple[float, str] = (1.0, "tracked")  # of the last observed frame

    # the first frame only needs features; afterwards the proposals of every shard too
    def required(self, seq: int) -> frozenset[str]:
        return frozenset({"features"}) if self.state is None else frozenset(self.inputs)

    # -- one frame ---------------------------------------------------------------------------
    def step(self, seq: int, inputs: Mapping[str, Message | None]) -> list[Output]:
        feat = inputs.get("features")
        if self.state is None:
            return self._initialise(seq, feat)
        setup, state = self.setup, self.state
        assert setup is not None
        frame = None
        if isinstance(feat, Features):
            try:
                frame = setup.observation(frame_of(feat, seq, setup.image_shape)[0])
            except StageInputError as e:
                self.report("bad_features", f"{e}; coasting", seq)
        else:
            self.report("missing_features", f"frame {seq}: no features arrived; coasting", seq)
        props = self._proposals(seq, inputs) if frame is not None else None
        header = feat.header if isinstance(feat, Features) else self.header(seq, 0)
        p: GFlowFilterParams = self.params  # type: ignore[assignment]
        if props is not None:
            try:
                new, est = update(state, props, frame, setup.model, setup.cfg, update_rng(p.seed, self.ctx.stream, seq))
            except (ValueError, np.linalg.LinAlgError) as e:
                self.report("update_failed", f"frame {seq}: {type(e).__name__}: {e}; coasting", seq)
                props = None
        if props is None:
            return self._coast(seq, header)
        self.state = new
        self.steps += 1
        out_state = states_msg(header, new.poses, new.tex_mean, new.tex_var, new.log_credibility, est.parents,
                               setup.image_shape, setup.digest, first=False, tex_anchor=new.tex_anchor)
        # confidence: the fraction of vertices the frame shows as the face (the likelihood's outlier process)
        conf = min(max(est.inlier_fraction, 0.0), 1.0)
        self.confidence = (conf, "lost" if conf < p.lost_below else "occluded" if conf < p.occluded_below
                           else "tracked")
        estimate = self._estimate_msg(header, est.pose, est.pose_std, est.rotation, est.spread_px, est.ess,
                                      est.expert_points, est.mean_points, est.bbox, est.log_credibility, est.parents,
                                      est.resampled, "track")
        return [("state", out_state), ("estimate", estimate)]

    def _proposals(self, seq: int, inputs: Mapping[str, Message | None]):
        """Every shard's proposals for ``seq``, concatenated; None (reported) if any is missing or bad."""
        p: GFlowFilterParams = self.params  # type: ignore[assignment]
        assert self.setup is not None
        parts = []
        for k in range(p.shards):
            msg = inputs.get(f"proposals{k}")
            if not isinstance(msg, PoseProposals):
                self.report("missing_proposals", f"frame {seq}: no proposals from shard {k} of {p.shards}; coasting",
                            seq)
                return None
            try:
                parts.append(unpack_proposals(msg, self.setup, k, p.shards, self.shard_idx[k],
                                              f"frame {seq}: proposals of shard {k}"))
            except StageInputError as e:
                self.report("bad_proposals", f"{e}; coasting", seq)
                return None
        return concatenate_proposals(parts)

    def _initialise(self, seq: int, feat: Message | None) -> list[Output]:
        p: GFlowFilterParams = self.params  # type: ignore[assignment]
        if not isinstance(feat, Features):
            return []
        try:
            grey, frame = frame_of(feat, seq)
        except StageInputError as e:
            self.report("bad_features", f"{e}; waiting for a usable first frame", seq)
            return []
        try:
            setup = prepare_model(p, self.ctx.resources, grey.shape)  # type: ignore[arg-type]
        except (StageInputError, ValueError) as e:
            if str(e) != self.init_error:  # once, not on every frame
                self.init_error = str(e)
                self.report("init_failed", f"frame {seq}: {e}; not tracking", seq)
            return []
        frame = setup.observation(grey)
        if setup.clipped:
            self.report("init_box_clipped", f"frame {seq}: initial box {p.init} reaches outside the "
                                            f"{grey.shape[1]}x{grey.shape[0]} frame; using {tuple(setup.box.round(2))}",
                        seq)
        rng = jitter = None
        if any(v > 0 for v in p.init_jitter):
            r, tr, c = p.init_jitter
            # std of the tangent-space jitter: (rotation x 3, translation x 2, |c0| * fraction)
            jitter = np.concatenate([np.full(3, r), np.full(2, tr), c * np.abs(setup.pose0[COEF])])
            rng = frame_rng(p.seed, self.ctx.stream, seq, PURPOSE_INIT)
        # the filter keeps no backgrounds: the proposal stages start them from this frame
        state = init_state(setup.model, setup.pose0, frame, replace(setup.cfg, background=False), rng=rng,
                           pose_jitter_std=jitter)
        self.setup, self.state = setup, state
        E = state.n_experts
        parents = np.arange(E, dtype=np.int64)
        out_state = states_msg(feat.header, state.poses, state.tex_mean, state.tex_var, state.log_credibility,
                               parents, setup.image_shape, setup.digest, first=True, tex_anchor=state.tex_anchor)
        return [("state", out_state), ("estimate", self._summary_estimate(feat.header, state, "init"))]

    def _coast(self, seq: int, header: Header) -> list[Output]:
        """No usable observation: poses and credibilities kept, texels predicted only (eq. 9, 10)."""
        setup, state = self.setup, self.state
        assert setup is not None and state is not None
        # Var(V_t | u_{1:t-1}, y_{1:t-1}) = Var(V_{t-1} | ...) + Psi_v   (eq. 10); mean unchanged (eq. 9)
        # (or reverting toward the first look, texture_decay < 1)
        E = state.n_experts
        tex_mean, tex_var = predict_texels(state, np.arange(E), setup.cfg)
        tex_mean, tex_var = np.array(tex_mean), np.array(tex_var)
        tex_mean.setflags(write=False)
        tex_var.setflags(write=False)
        self.state = replace(state, tex_mean=tex_mean, tex_var=tex_var)
        self.coasted += 1
        self.steps += 1
        out_state = states_msg(header, state.poses, tex_mean, tex_var, state.log_credibility,
                               np.arange(E, dtype=np.int64), setup.image_shape, setup.digest, first=False,
                               tex_anchor=state.tex_anchor)
        return [("state", out_state), ("estimate", self._summary_estimate(header, self.state, "coast"))]

    def _summary_estimate(self, header: Header, state: ExpertState, kind: str) -> PoseEstimate:
        """The estimate of a state with no new observation (first frame, coasting)."""
        setup = self.setup
        assert setup is not None
        lc = state.log_credibility
        mean = posterior_mean_pose(state.poses, lc)
        pts = project(setup.model.bases, state.poses)
        mean_pts = project(setup.model.bases, mean)
        W = np.exp(lc)
        d2 = np.sum((pts - mean_pts[None]) ** 2, axis=-1).mean(axis=-1)
        return self._estimate_msg(header, mean, pose_spread(state.poses, lc, mean), rotation_matrices(mean),
                                  float(np.sqrt(W @ d2 / W.sum())), float(ess(lc)), pts, mean_pts,
                                  bounding_box(mean_pts), lc, np.arange(state.n_experts, dtype=np.int64), False, kind)

    def _estimate_msg(self, header: Header, pose, pose_std, rotation, spread_px, ess_val, expert_points, mean_points,
                      bbox, log_cred, parents, resampled: bool, kind: str) -> PoseEstimate:
        setup = self.setup
        assert setup is not None
        model = setup.model
        if model.reference_box is not None:
            # a learned face: the user's box, moved and scaled with the face
            bbox = following_box(pose, setup.pose0, setup.box)
        box = tuple(float(v) for v in bbox)
        self.last = {"seq": header.seq, "state": kind, "box": [round(v, 1) for v in box], "ess": round(ess_val, 1),
                     "spread_px": round(spread_px, 2), "confidence": round(self.confidence[0], 3)}
        return PoseEstimate(
            header=header, box=box, pose=tuple(float(v) for v in pose),  # type: ignore[arg-type]
            pose_std=tuple(float(v) for v in pose_std), rotation=tuple(float(v) for v in np.ravel(rotation)),
            spread_px=float(spread_px), ess=float(ess_val),
            expert_points=NDArray.of(np.asarray(expert_points, dtype=np.float32)),
            mean_points=NDArray.of(np.asarray(mean_points, dtype=np.float32)),
            log_credibility=NDArray.of(np.asarray(log_cred, dtype=np.float64)),
            parents=NDArray.of(np.asarray(parents, dtype=np.int64)), resampled=bool(resampled), state=kind,
            confidence=float(self.confidence[0]), target_state=self.confidence[1],
            landmarks=None if model.landmarks is None else NDArray.of(np.asarray(model.landmarks, dtype=np.int32)),
            yaw_pitch_roll=tuple(float(v) for v in yaw_pitch_roll(rotation)),  # type: ignore[arg-type]
            expression=tuple(float(v) for v in expression(np.asarray(pose)[COEF], model.morph_std)))

    # -- state ------------------------------------------------------------------------------------
    def summary(self) -> dict:
        return dict(self.last, steps=self.steps, coasted=self.coasted)

    def snapshot(self) -> bytes:
        st = None
        if self.state is not None and self.setup is not None:
            s = self.state
            st = states_msg(self.header(int(self.last.get("seq", 0)), 0), s.poses, s.tex_mean,
                            s.tex_var, s.log_credibility, np.arange(s.n_experts, dtype=np.int64),
                            self.setup.image_shape, self.setup.digest, first=False, tex_anchor=s.tex_anchor)
        snap = _Snapshot(version=SNAPSHOT_VERSION,
                         image_shape=None if self.setup is None else tuple(self.setup.image_shape),  # type: ignore[arg-type]
                         digest="" if self.setup is None else self.setup.digest, state=st, steps=self.steps,
                         coasted=self.coasted, init_error=self.init_error, confidence=self.confidence[0],
                         target_state=self.confidence[1])
        return msgspec.msgpack.encode(snap)

    def restore(self, data: bytes) -> None:
        try:
            snap = msgspec.msgpack.decode(data, type=_Snapshot)
        except msgspec.DecodeError as e:
            raise ValueError(f"not a gflow.filter snapshot: {e}") from None
        if snap.version != SNAPSHOT_VERSION:
            raise ValueError(f"gflow.filter snapshot version {snap.version}, this code reads {SNAPSHOT_VERSION}")
        self.setup = self.state = None
        if snap.image_shape is not None:
            setup = prepare_model(self.params, self.ctx.resources, snap.image_shape)  # type: ignore[arg-type]
            if setup.digest != snap.digest:
                raise ValueError(f"the snapshot was made with another G-flow configuration, model or seed (digest "
                                 f"{snap.digest}, this stage has {setup.digest})")
            self.setup = setup
            if snap.state is not None:
                try:
                    a = unpack_states(snap.state, setup, "gflow.filter snapshot")
                except StageInputError as e:
                    raise ValueError(str(e)) from None
                arrs = {k: a[k].copy() for k in ("poses", "tex_mean", "tex_var", "log_credibility")}
                for v in arrs.values():
                    v.setflags(write=False)
                self.state = ExpertState(bg_mean=None, bg_var=None, image_shape=setup.image_shape,
                                         tex_anchor=a["tex_anchor"], **arrs)
        self.steps, self.coasted, self.init_error = snap.steps, snap.coasted, snap.init_error
        self.confidence = (snap.confidence, snap.target_state)
