"""G-flow as a :class:`gflow_core.tracker.TrackingFilter`: one frame is :meth:`GFlowTracker.propose`
(each expert's pose opinion, eq. 14-16, 19) then :meth:`GFlowTracker.update` (credibility,
resampling, texel update, eq. 17, 19, sec. 3.4, eq. 7-10), on :mod:`.filter`.

Around the filter of :mod:`.filter` this module holds what the tracker adds: what it reads of a
frame (:meth:`GFlowTracker.observe`: grey levels / 255, local-contrast normalised), the model
placed in the user's box (:func:`model_setup`), the estimate it reports (the box that follows a
learned face, the confidence and the target's state) and coasting over a frame it cannot use.

Random draws (:class:`gflow_core.tracker.FrameRng` of frame ``t``): expert ``i`` proposes from
``stream(i)``, the update resamples from ``stream()``, and the experts' initial jitter (first
frame only) comes from ``stream(PURPOSE_INIT)``, the samples the mixture proposal draws about the
online model's place of the face (``online_mix``, :mod:`.mixture`) from ``stream(PURPOSE_MIX)``. So
proposals made for any partition of the experts (the pipeline's shards) concatenate to those of one
call, bit for bit.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np

from .. import colour as col
from ..features import to_grey
from ..m2.lost import Anchor, LostParams, LostState, bound_positions
from ..tracker import Box, Estimate, FrameRng, UnusableFrame
from ..visibility import ChiSquare
from . import guard, online_guard
from .credibility import ess, log_evidence, pose_spread, posterior_mean_pose
from .face_pose import expression, following_box, yaw_pitch_roll
from .filter import (
    ExpertState,
    GFlowConfig,
    Proposals,
    advance_background,
    init_state,
    predict_background,
    predict_texels,
    propose,
    update,
)
from .geometry import COEF, TRANS, project, rotation_matrices
from .head_model import MorphableModel, bounding_box, fit_head_model_to_box, pose_for_box
from .mixture import detector_starts, mixture_proposals
from .image import FrameData, frame_pyramid, local_contrast, prepare_frame
from .pose_opinion import local_background_of
from .params import GFlowParams

__all__ = ["GFlowTracker", "GFlowState", "GFlowObservation", "ModelSetup", "model_setup", "clip_box",
           "observation", "PURPOSE_INIT", "TRACKER"]

#: ``FrameRng.stream`` path of the experts' initial jitter
PURPOSE_INIT = 0x6F10
#: the draws of the mixture proposal's samples about the online model's place (:mod:`.mixture`)
PURPOSE_MIX = 0x6F11
_PROPOSAL_ARRAYS = ("u_hat", "sigma_hat", "samples", "log_weights", "log_evidence", "gn_objective")


def clip_box(box: Sequence[float], shape: tuple[int, int]) -> tuple[np.ndarray, bool]:
    """The initial box clipped to the image ``[-0.5, W - 0.5] x [-0.5, H - 0.5]``.

    Returns
    -------
    box : (4,) float64, (x, y, w, h)
    clipped : bool, True if the box had to be cut.

    Raises
    ------
    ValueError
        When less than 1 x 1 pixel of the box lies in the image.
    """
    H, W = shape
    x, y, w, h = (float(v) for v in box)
    x0, y0 = max(x, -0.5), max(y, -0.5)
    x1, y1 = min(x + w, W - 0.5), min(y + h, H - 0.5)
    if x1 - x0 < 1.0 or y1 - y0 < 1.0:
        raise ValueError(f"initial box (x={x:g}, y={y:g}, w={w:g}, h={h:g}) lies outside the {W}x{H} frame "
                         f"(x must overlap [-0.5, {W - 0.5}] and y [-0.5, {H - 0.5}] by at least a pixel)")
    out = np.array([x0, y0, x1 - x0, y1 - y0])
    return out, bool(not np.allclose(out, [x, y, w, h]))


def observation(grey: np.ndarray, contrast_sigma: float = 0.0) -> np.ndarray:
    """What G-flow observes of a grey uint8 frame ``(H, W)``: grey levels / 255, local-contrast
    normalised when ``contrast_sigma > 0`` (:func:`.image.local_contrast`), ``(H, W)`` float64."""
    y = grey.astype(np.float64) / 255.0
    return local_contrast(y, contrast_sigma) if contrast_sigma > 0 else y


@dataclass(frozen=True)
class ModelSetup:
    """The model placed in the user's box on frames of one size, and the configuration it implies.

    Attributes
    ----------
    model : MorphableModel
    pose0 : (P,) float64, the initial pose (its projection fills the clipped box).
    cfg : GFlowConfig, with the scale wall's reference and the morph prior filled in.
    box : (4,) float64, the initial box actually used (clipped to the frame).
    clipped : bool, whether the box had to be clipped.
    image_shape : (H, W)
    contrast_sigma : float, the frames' local contrast normalisation (0: none).
    """

    model: MorphableModel
    pose0: np.ndarray
    cfg: GFlowConfig
    box: np.ndarray
    clipped: bool
    image_shape: tuple[int, int]
    contrast_sigma: float = 0.0

    def observation(self, grey: np.ndarray) -> np.ndarray:
        """``y_t`` of a grey uint8 frame (:func:`observation` with this run's ``contrast_sigma``)."""
        return observation(grey, self.contrast_sigma)


def model_setup(params: GFlowParams, box: Sequence[float], shape: tuple[int, int],
                model: Any = None) -> ModelSetup:
    """Place the model in ``box`` on frames of ``shape`` (the proposal and the filter stages both do
    this, identically).

    Parameters
    ----------
    params : GFlowParams
    box : (x, y, w, h), clipped to the frame.
    shape : (H, W)
    model : MorphableModel or None
        A learned model (``params.model`` loaded by the caller), placed in the box as it sat on the
        training faces (:func:`.head_model.pose_for_box`); None: the generic ellipsoid head fitted
        into the box (``depth_ratio``, ``head_grid``).

    Raises
    ------
    ValueError
        A box outside the frame, a ``model`` that is not a morphable model, or one that does not
        fit the configuration (``prior_std_coefficients`` of the wrong length).
    """
    clipped_box, clipped = clip_box(box, shape)
    try:
        if model is not None:
            if not isinstance(model, MorphableModel):
                raise ValueError(f"the model file {params.model!r} holds a {type(model).__name__}; G-flow needs a "
                                 f"morphable model (model file kind 'morphable')")
            pose0 = pose_for_box(model, clipped_box, shape)
        else:
            model, pose0 = fit_head_model_to_box(clipped_box, shape, n_lon=params.head_grid[0],
                                                 n_lat=params.head_grid[1], depth_ratio=params.depth_ratio)
        cfg = params.config(model, pose0)
    except ValueError as e:
        raise ValueError(f"cannot place the G-flow model in the initial box {tuple(clipped_box.round(2))}: {e}") \
            from None
    return ModelSetup(model, pose0, cfg, clipped_box, clipped, (int(shape[0]), int(shape[1])), params.contrast_sigma)


@dataclass(frozen=True)
class GFlowObservation:
    """What G-flow reads of one frame.

    Attributes
    ----------
    grey : (H, W) uint8, the frame's grey levels.
    y : (H, W) float64, ``y_t`` (:func:`observation`).
    bins : (H, W) uint8 colour bins (:func:`gflow_core.colour.bins`) for the lost guard's colour cue,
        or None (a grey frame, or no colour cue).
    pyramid : ``y_t`` validated with its gradient images, level 0 first (:func:`.image.frame_pyramid`),
        made ahead by :meth:`GFlowTracker.with_pyramid`; None: :meth:`GFlowTracker.propose` makes it.
    channels : (H, W, 4) float32, the lost guard's orientation channels of ``grey``, made ahead by
        :meth:`GFlowTracker.with_channels`; None: :meth:`GFlowTracker.update` makes them.

    The last two are what a frame costs before any expert is looked at; a pipeline stage computes
    them as soon as the frame arrives (``stages/gflow_proposal.py``, ``gflow_filter.py``), while it
    waits for the experts. Made ahead or not, they are the same arrays, so the results are too.
    """

    grey: np.ndarray
    y: np.ndarray
    bins: np.ndarray | None = None
    pyramid: tuple[FrameData, ...] | None = None
    channels: np.ndarray | None = None


@dataclass(frozen=True)
class GFlowState:
    """The posterior after a frame: the experts, the model they use, and how the target was judged.

    Attributes
    ----------
    setup : ModelSetup
    experts : ExpertState
        With the backgrounds when ``cfg.background`` and the caller keeps them (the pipeline's
        filter stage does not: its proposal stages do).
    confidence : float, of the last frame with evidence.
    target_state : str, of the last frame with evidence.
    anchor : the lost guard's anchor (the user's box on the first frame), None without the guard.
    lost : the lost guard's state (:mod:`.guard`).
    fit_level : the guard's running moments of the first look's misfit on found frames.
    look_clutter : ... and of its best misfit beside the estimate there (:func:`.guard.first_look_clutter`).
    online : the online guard's model of the face (:mod:`.online_guard`), None without it.
    """

    setup: ModelSetup
    experts: ExpertState
    confidence: float = 1.0
    target_state: str = "tracked"
    anchor: Anchor | None = None
    lost: LostState = LostState()
    fit_level: ChiSquare = ChiSquare()
    look_clutter: ChiSquare = ChiSquare()
    online: online_guard.OnlineFace | None = None


def online_params(params: GFlowParams) -> online_guard.OnlineParams | None:
    """The online guard's settings (:mod:`.online_guard`), None without it (or without the lost guard)."""
    if not (params.online_guard and params.lost_guard):
        return None
    return online_guard.OnlineParams(window=params.online_window, growth=params.online_growth,
                                     patience=params.online_patience, apart=params.online_apart,
                                     cue=params.online_cue, floor=params.online_floor)


def guard_params(params: GFlowParams, dt: float = 1.0) -> LostParams | None:
    """The lost guard's settings for a step of ``dt`` frame periods (its re-detection window widens by
    ``lost_growth`` box sizes a period), None without the guard."""
    return guard.guard_params(params.lost_window, params.lost_growth * dt) if params.lost_guard else None


class GFlowTracker:
    """G-flow's :class:`gflow_core.tracker.TrackingFilter` (stateless: everything is in
    :class:`GFlowState`)."""

    name = "gflow"
    Params = GFlowParams

    # -- inputs ---------------------------------------------------------------------------------
    def observe(self, params: GFlowParams, image: np.ndarray) -> GFlowObservation:
        """The grey frame (``features.to_grey`` of a BGR or grey image), ``y_t`` and, for the lost
        guard's colour cue, the colour bins of a frame with colour.

        Raises
        ------
        UnusableFrame
            A uniform frame (all black, saturated or any single grey level): it carries no
            information about the pose and would overwrite the textures.
        ValueError
            Not an image of at least 2 x 2 pixels.
        """
        grey = to_grey(image) if np.ndim(image) == 3 else np.asarray(image)
        obs = self.observe_grey(params, grey)
        if self.reads_colour(params) and not col.is_grey(image):
            obs = dataclasses.replace(obs, bins=col.bins(image))
        return obs

    @staticmethod
    def reads_colour(params: GFlowParams) -> bool:
        """Whether the tracker reads a colour frame's bins (:attr:`GFlowObservation.bins`): only the
        lost guard does, when it weighs colour (``lost_guard`` and ``lost_colour``)."""
        return params.lost_guard and params.lost_colour

    def observe_grey(self, params: GFlowParams, grey: np.ndarray) -> GFlowObservation:
        """:meth:`observe` of a frame already in grey levels ``(H, W)`` uint8."""
        if grey.ndim != 2 or grey.dtype != np.uint8 or min(grey.shape) < 2:
            raise ValueError(f"grey image must be (H, W) uint8 of at least 2x2 pixels, got {grey.dtype} {grey.shape}")
        lo, hi = int(grey.min()), int(grey.max())
        if lo == hi:
            raise UnusableFrame(f"every pixel is {lo} (a blank or saturated frame carries no information about the "
                                f"pose, and would overwrite the textures)")
        return GFlowObservation(grey=grey, y=observation(grey, params.contrast_sigma))

    def with_pyramid(self, params: GFlowParams, obs: GFlowObservation) -> GFlowObservation:
        """``obs`` with the pyramid :meth:`propose` reads (``y_t`` validated, its gradient images and
        ``pyramid_levels - 1`` coarser levels, :func:`.image.frame_pyramid`)."""
        if obs.pyramid is not None:
            return obs
        pyramid = tuple(frame_pyramid(prepare_frame(obs.y), params.pyramid_levels))
        if params.local_background > 0:
            # the local background the proposal reads at level 0 (its chains' objective and the weights), made ahead
            local_background_of(pyramid[0], params.local_background, params.sigma_w)
        return dataclasses.replace(obs, pyramid=pyramid)

    def with_channels(self, params: GFlowParams, obs: GFlowObservation) -> GFlowObservation:
        """``obs`` with the lost guard's orientation channels of the grey frame (none without the guard)."""
        if obs.channels is not None or not params.lost_guard:
            return obs
        return dataclasses.replace(obs, channels=guard.channels(obs.grey))

    def with_bins(self, params: GFlowParams, obs: GFlowObservation, bins: np.ndarray | None) -> GFlowObservation:
        """``obs`` with a colour frame's bins ``bins`` (H, W) uint8 made elsewhere (a pipeline's
        preprocess stage, :func:`gflow_core.colour.bins`) when the tracker reads colour
        (:meth:`reads_colour`); ``obs`` as it is without bins (a grey frame, or bins that could not be
        used: the lost guard then weighs edges alone) or when it does not read them."""
        if bins is None or not self.reads_colour(params):
            return obs
        return dataclasses.replace(obs, bins=bins)

    # -- the filter -----------------------------------------------------------------------------
    def init(self, params: GFlowParams, obs: GFlowObservation, box: Box, rng: FrameRng,
             resources: Mapping[str, Any], *, backgrounds: bool = True) -> tuple[GFlowState, Estimate]:
        """The experts at the first frame: the model placed in ``box``, every expert at that pose
        (jittered by ``init_jitter``: the paper initialises them "randomly near the correct pose",
        sec. 5), texels read from the frame with ``Var(V_1) = v_init_var``.

        ``backgrounds=False`` keeps no background textures even with ``background`` on (the
        pipeline's filter stage, whose proposal stages keep them).

        Raises ``ValueError`` (:func:`model_setup`) when the model cannot be placed in ``box``.
        """
        setup = model_setup(params, box, obs.grey.shape, resources.get("model"))
        jitter = None
        draw = None
        if any(v > 0 for v in params.init_jitter):
            r, tr, c = params.init_jitter
            # std of the tangent-space jitter: (rotation x 3, translation x 2, |c0| * fraction)
            jitter = np.concatenate([np.full(3, r), np.full(2, tr), c * np.abs(setup.pose0[COEF])])
            draw = rng.stream(PURPOSE_INIT)
        cfg = setup.cfg if backgrounds else dataclasses.replace(setup.cfg, background=False)
        experts = init_state(setup.model, setup.pose0, obs.y, cfg, rng=draw, pose_jitter_std=jitter)
        gp = guard_params(params)
        x, y, w, h = (float(v) for v in setup.box)
        anchor = None if gp is None else guard.anchor_of(obs.grey, (x, y, w, h), gp,
                                                         obs.bins if params.lost_colour else None)
        op = online_params(params)
        online = None if op is None or anchor is None else online_guard.start(obs.grey, (x, y, w, h), op)
        state = GFlowState(setup, experts, anchor=anchor, online=online)
        return state, self.summary_estimate(state, rng.t, "init")

    def propose(self, params: GFlowParams, state: GFlowState, obs: GFlowObservation, rng: FrameRng,
                dt: float = 1.0, experts: np.ndarray | None = None) -> Proposals:
        """Pose opinions (sec. 3.2) and likelihoods (eq. 19) of the experts ``experts`` (default:
        all), each from its own generator ``rng.stream(i)`` (:func:`.filter.propose`).

        Raises ``ValueError`` (or ``numpy.linalg.LinAlgError``) when the proposals cannot be made or
        are not finite.
        """
        s = state.setup
        idx = np.arange(state.experts.n_experts, dtype=np.int64) if experts is None else np.asarray(experts)
        props = propose(state.experts, obs.y, s.model, s.cfg, [rng.stream(int(i)) for i in idx], idx, dt,
                        pyramid=obs.pyramid)
        bad = [f for f in _PROPOSAL_ARRAYS if not np.isfinite(getattr(props, f)).all()]
        if bad:
            raise ValueError(f"non-finite {', '.join(bad)}")
        return props

    def update(self, params: GFlowParams, state: GFlowState, proposal: Proposals, obs: GFlowObservation,
               rng: FrameRng) -> tuple[GFlowState, Estimate]:
        """Credibility (eq. 17, 19), resampling from ``rng.stream()`` (sec. 3.4) and the texel update
        (eq. 7-10) (:func:`.filter.update`, over the ``proposal.dt`` periods the step spans), then the
        lost guard (:mod:`.guard`): the estimate is verified, held while the target is judged hidden or
        lost (box and points where it was last found, the experts kept within ``lost_hold`` box sizes
        of it, :meth:`_hold`), and the experts re-seated where a search finds it again (phase
        ``redetect``), at the pose where the first look fits the frame there (:meth:`_place`). The
        confidence is the guard's P(visible); without the guard it is the fraction of vertices the frame
        explains as the object (``Estimate.inlier_fraction``), below ``occluded_below`` the target is
        occluded, below ``lost_below`` lost. With the online guard's ``online_cue``, its model of the face
        weighs every sample first (:meth:`_with_cue`)."""
        s = state.setup
        op = online_params(params)
        resp = None
        if op is not None and state.online is not None and (op.cue > 0 or params.online_mix > 0):
            resp = online_guard.response(state.online, obs.grey, op)
            if params.online_mix > 0:
                # samples drawn about where the online model places the face too, weights for the mixture (.mixture)
                proposal = self._with_detector(params, state, proposal, obs, resp, op, rng)
            if op.cue > 0:
                # the online model of the face, a second cue in the importance weights (eq. 16; .online_guard.cue)
                proposal = self._with_cue(s, proposal, resp, op)
        new, est = update(state.experts, proposal, obs.y, s.model, s.cfg, rng.stream())
        gp = guard_params(params, proposal.dt)
        if gp is None or state.anchor is None:
            conf = min(max(est.inlier_fraction, 0.0), 1.0)
            judged = "lost" if conf < params.lost_below else "occluded" if conf < params.occluded_below else "tracked"
            out = GFlowState(s, new, conf, judged, state.anchor, state.lost, state.fit_level, state.look_clutter,
                             state.online)
            return out, self._estimate_of(out, rng.t, "track", est)
        channels = self.with_channels(params, obs).channels
        assert channels is not None  # the guard is on
        g = guard.step(state.lost, state.anchor, gp, channels, obs.bins if params.lost_colour else None,
                       self._box(s, est.pose, est.bbox), est.pose, tuple(params.lost_scales),
                       guard.first_look_fit(new, obs.y, s.model, s.cfg), state.fit_level,
                       place=lambda box: self._place(params, s, new, obs, box),
                       ring_fit=guard.first_look_clutter(new, obs.y, s.model, s.cfg, gp.ring),
                       look_clutter=state.look_clutter, witness=params.lost_witness)
        online = state.online
        if op is not None:
            # the online model of the face vouches for the experts' box or re-seats them (.online_guard)
            ebox = self._box(s, est.pose, est.bbox)
            face = online if online is not None else online_guard.start(obs.grey, ebox, op)
            g, online = online_guard.overrule(g, online_guard.look(face, obs.grey, ebox, proposal.dt, op, resp), ebox,
                                              est.pose, op, lambda box: self._place(params, s, new, obs, box))
        if g.pose is None:
            if g.phase == "lost" and g.lost.held is not None and params.lost_hold > 0:
                new = self._hold(s, new, g.lost.held, params.lost_hold)
            out = GFlowState(s, new, g.confidence, g.target_state, state.anchor, g.lost, g.level, g.look_clutter,
                             online)
            if g.held_pose is not None:
                # the held box is reported: the face where it was last found, its points with it
                return out, self._held_estimate(out, rng.t, est, g.box, g.held_pose)
            return out, self._estimate_of(out, rng.t, g.phase, est, g.box)
        # re-detected: every expert re-seated at the candidate, texels read there
        seated = guard.reseat(new, g.pose, obs.y, s.model, s.cfg)
        if seated.bg_mean is not None and state.experts.bg_mean is not None:
            # the backgrounds advanced at the re-seated poses, as a proposal stage's replica does from the
            # state message (its parents: every expert its own)
            bg_mean, bg_var = advance_background(state.experts.bg_mean, state.experts.bg_var, seated.poses,
                                                 np.arange(seated.n_experts, dtype=np.int64), obs.y, s.model, s.cfg)
            seated = dataclasses.replace(seated, bg_mean=bg_mean, bg_var=bg_var)
        out = GFlowState(s, seated, g.confidence, g.target_state, state.anchor, g.lost, g.level, g.look_clutter,
                         online)
        return out, _with_fit(self.summary_estimate(out, rng.t, g.phase), est)

    def _with_cue(self, setup: ModelSetup, proposal: Proposals, resp: Any, op: online_guard.OnlineParams
                  ) -> Proposals:
        """``proposal`` with the online model's likelihood of each sample's box (:meth:`_box`) as a second cue:
        its log added to the sample's log importance weight (eq. 16) and the expert's likelihood (eq. 19)
        re-estimated from the weights so fused (the cues' likelihoods multiplied, Perez, Vermaak & Blake 2004)."""
        samples = proposal.samples
        centres = self._centres(setup, samples)
        log_l = online_guard.cue(resp, centres.reshape(-1, 2), op).reshape(samples.shape[:2])
        # w_t(d, e) p_online(y_t | u^(d, e))                                  (eq. 16, times the second cue)
        log_w = proposal.log_weights + log_l
        log_w.setflags(write=False)
        ev = log_evidence(log_w)
        ev.setflags(write=False)
        return dataclasses.replace(proposal, log_weights=log_w, log_evidence=ev)

    def _with_detector(self, params: GFlowParams, state: GFlowState, proposal: Proposals, obs: GFlowObservation,
                       resp: Any, op: online_guard.OnlineParams, rng: FrameRng) -> Proposals:
        """``proposal`` drawn from the mixture of the experts' opinions and the online model's detection
        (:func:`.mixture.mixture_proposals`, ``online_mix`` of each expert's samples) where the model places
        the face on this frame, fully or partly (:func:`.online_guard.place`: P(visible) + P(partial) >=
        P(hidden), the gate its learning uses; a turning face is judged partly visible); ``proposal`` itself
        where it does not."""
        assert state.online is not None
        s = state.setup
        place, _, vis = online_guard.place(state.online, resp, proposal.dt, op)
        if not vis.present:
            return proposal
        starts = detector_starts(proposal.u_hat, self._centres(s, proposal.u_hat), place)
        pyramid = self.with_pyramid(params, obs).pyramid
        assert pyramid is not None
        return mixture_proposals(state.experts, proposal, pyramid, s.model, s.cfg, starts, params.online_mix,
                                 rng.stream(PURPOSE_MIX))

    @staticmethod
    def _centres(setup: ModelSetup, poses: np.ndarray) -> np.ndarray:
        """The centres (..., 2) (x, y) of the boxes of poses (..., P) (:meth:`_box`), as the online model
        places a box's centre: x + (w - 1) / 2."""
        if setup.model.reference_box is not None:
            boxes = following_box(poses, setup.pose0, setup.box)
        else:
            boxes = bounding_box(project(setup.model.bases, poses.reshape(-1, poses.shape[-1]))
                                 ).reshape(*poses.shape[:-1], 4)
        # the box's centre as the online model places it: x + (w - 1) / 2
        return boxes[..., :2] + 0.5 * (boxes[..., 2:] - 1.0)

    def _place(self, params: GFlowParams, setup: ModelSetup, experts: ExpertState, obs: GFlowObservation,
               box: tuple[float, float, float, float]) -> np.ndarray:
        """The pose to re-seat the experts at for a re-detected ``box``: the first frame's pose moved and
        scaled into it (:func:`.guard.reseat_pose`), settled where the first look fits the frame
        (:func:`.guard.settle`)."""
        pose0 = setup.pose0
        box0 = self._box(setup, pose0, bounding_box(project(setup.model.bases, pose0)))
        pyramid = self.with_pyramid(params, obs).pyramid
        assert pyramid is not None
        return guard.settle(guard.reseat_pose(pose0, box0, box), pyramid, experts, setup.model, setup.cfg)

    def _estimate_of(self, state: GFlowState, t: int, phase: str, est: Any,
                     box: tuple[float, float, float, float] | None = None) -> Estimate:
        """:meth:`estimate` of :func:`.filter.update`'s estimate ``est``, with ``box`` reported instead
        of the posterior's when given (the lost guard's held box)."""
        return _with_fit(self.estimate(state, t, phase, est.pose, est.pose_std, est.rotation, est.spread_px, est.ess,
                                       est.expert_points, est.mean_points, est.bbox, est.log_credibility,
                                       est.parents, est.resampled, box=box), est)

    def _hold(self, setup: ModelSetup, experts: ExpertState, held: tuple[float, ...], reach: float) -> ExpertState:
        """The experts kept near the face while the lost guard holds it where it was last found: each
        expert's box centre (:meth:`_box`) moved, by its translation ``l``, into the held box's centre
        +- ``reach`` box sizes (:func:`gflow_core.m2.lost.bound_positions`, as the contour trackers keep
        their particles). G-flow's likelihood follows whatever explains the frame best while the face
        is hidden or turned away (a plain wall, a shoulder); kept within reach, the experts are where the
        face comes back."""
        model = setup.model
        boxes = np.array([self._box(setup, u, bounding_box(p)) for u, p in zip(experts.poses,
                                                                               project(model.bases, experts.poses))])
        centre = boxes[:, :2] + 0.5 * boxes[:, 2:]
        hc = (held[0] + 0.5 * held[2], held[1] + 0.5 * held[3])
        shift = bound_positions(centre, hc, (reach * held[2], reach * held[3])) - centre
        if not shift.any():
            return experts
        poses = np.array(experts.poses)
        # both of G-flow's boxes move with the translation l (eq. 1)
        poses[:, TRANS] += shift
        poses.setflags(write=False)
        return dataclasses.replace(experts, poses=poses)

    def _held_estimate(self, state: GFlowState, t: int, est: Any, box: tuple[float, float, float, float],
                       pose: np.ndarray) -> Estimate:
        """The estimate of a frame whose target the lost guard holds where it was last found: the held
        ``box`` and the held ``pose`` (P,) with its rotation and projected points; the experts' spread,
        points and credibilities as they are."""
        mean_pts = project(state.setup.model.bases, pose)
        return _with_fit(self.estimate(state, t, "lost", pose, est.pose_std, rotation_matrices(pose), est.spread_px,
                                       est.ess, est.expert_points, mean_pts, bounding_box(mean_pts),
                                       est.log_credibility, est.parents, est.resampled, box=box), est)

    @staticmethod
    def _box(setup: ModelSetup, pose: np.ndarray, bbox: np.ndarray) -> tuple[float, float, float, float]:
        """The box of ``pose``: a learned face's following box, else ``bbox`` (the projected vertices')."""
        b = following_box(pose, setup.pose0, setup.box) if setup.model.reference_box is not None else bbox
        return (float(b[0]), float(b[1]), float(b[2]), float(b[3]))

    def coast(self, params: GFlowParams, state: GFlowState, rng: FrameRng,
              obs: GFlowObservation | None = None) -> tuple[GFlowState, Estimate]:
        """No evidence from frame ``rng.t``: poses and credibilities kept, texels predicted only (eq. 9,
        10). Backgrounds, when kept, are updated with ``obs`` at the kept poses (the frame was seen)
        or only predicted (it was not)."""
        s, st = state.setup, state.experts
        E = st.n_experts
        # Var(V_t | u_{1:t-1}, y_{1:t-1}) = Var(V_{t-1} | ...) + Psi_v   (eq. 10); mean unchanged (eq. 9)
        # (or reverting toward the first look, texture_decay < 1)
        tex_mean, tex_var = (np.array(a) for a in predict_texels(st, np.arange(E), s.cfg))
        tex_mean.setflags(write=False)
        tex_var.setflags(write=False)
        bg_mean, bg_var = st.bg_mean, st.bg_var
        if bg_mean is not None and bg_var is not None:
            parents = np.arange(E, dtype=np.int64)
            if obs is not None:
                bg_mean, bg_var = advance_background(bg_mean, bg_var, st.poses, parents, obs.y, s.model, s.cfg)
            else:
                bg_mean, bg_var = predict_background(bg_mean, bg_var, parents, s.cfg)
        out = dataclasses.replace(state, experts=dataclasses.replace(st, tex_mean=tex_mean, tex_var=tex_var,
                                                                     bg_mean=bg_mean, bg_var=bg_var))
        return out, self.summary_estimate(out, rng.t, "coast")

    def update_or_coast(self, params: GFlowParams, state: GFlowState, proposal: Proposals | None,
                        obs: GFlowObservation | None, rng: FrameRng) -> tuple[GFlowState, Estimate, str | None]:
        """:meth:`update` with ``proposal`` and ``obs`` when there are both, else :meth:`coast`; an update
        that fails (a ``ValueError`` or ``LinAlgError`` of degenerate proposals) coasts too, so one bad
        frame never ends the track.

        Returns the state, the estimate (phase ``coast`` when it coasted) and, when the update failed,
        why (``"LinAlgError: ..."``; None otherwise)."""
        failure = None
        if obs is not None and proposal is not None:
            try:
                new, est = self.update(params, state, proposal, obs, rng)
            except (ValueError, np.linalg.LinAlgError) as e:
                failure = f"{type(e).__name__}: {e}"
            else:
                return new, est, None
        new, est = self.coast(params, state, rng, obs)
        return new, est, failure

    # -- the estimate ---------------------------------------------------------------------------
    def summary_estimate(self, state: GFlowState, t: int, phase: str) -> Estimate:
        """The estimate of experts with no new observation (first frame, coasting): the posterior
        mean pose of the experts' poses under their credibilities."""
        model, st = state.setup.model, state.experts
        lc = st.log_credibility
        mean = posterior_mean_pose(st.poses, lc)
        pts = project(model.bases, st.poses)
        mean_pts = project(model.bases, mean)
        W = np.exp(lc)
        d2 = np.sum((pts - mean_pts[None]) ** 2, axis=-1).mean(axis=-1)
        return self.estimate(state, t, phase, mean, pose_spread(st.poses, lc, mean), rotation_matrices(mean),
                             float(np.sqrt(W @ d2 / W.sum())), float(ess(lc)), pts, mean_pts, bounding_box(mean_pts),
                             lc, np.arange(st.n_experts, dtype=np.int64), False)

    def estimate(self, state: GFlowState, t: int, phase: str, pose: np.ndarray, pose_std: np.ndarray,
                 rotation: np.ndarray, spread_px: float, ess_val: float, expert_points: np.ndarray,
                 mean_points: np.ndarray, bbox: np.ndarray, log_credibility: np.ndarray, parents: np.ndarray,
                 resampled: bool, box: tuple[float, float, float, float] | None = None) -> Estimate:
        """G-flow's estimate of frame ``t``.

        ``box`` is, when given, the lost guard's (held or re-detected); otherwise, for a learned face
        (a model with a reference box), the initial box moved and scaled with the face
        (:func:`.face_pose.following_box`), else ``bbox``, the bounding box of the projected vertices
        of the posterior mean pose. ``extras``:

        * ``pose`` (P,), ``pose_std`` (P,): posterior mean and standard deviation (tangent space);
        * ``rotation`` (3, 3): the mean pose's rotation;
        * ``spread_px``: RMS distance of the experts' projected vertices from the mean's;
        * ``ess``: effective sample size of the credibilities before resampling;
        * ``expert_points`` (E, n, 2), ``mean_points`` (n, 2): projected vertices (the paper's fig. 2);
        * ``log_credibility`` (E,), ``parents`` (E,) int64, ``resampled`` bool;
        * ``landmarks`` (n,) int or None: a learned face's reference landmark of each vertex;
        * ``yaw_pitch_roll`` (3,) degrees and ``expression`` (k - 1,) (:mod:`.face_pose`);
        * after an update (:meth:`update`), also ``inlier_fraction`` and ``inlier_count``
          (:class:`.filter.Estimate`): the fraction of vertices the frame explains as the object,
          expected and counted.
        """
        setup = state.setup
        model = setup.model
        if box is None:
            # the posterior's box (a learned face: the user's box, moved and scaled with the face)
            box = self._box(setup, pose, bbox)
        extras = {
            "pose": pose, "pose_std": pose_std, "rotation": rotation, "spread_px": float(spread_px),
            "ess": float(ess_val), "expert_points": expert_points, "mean_points": mean_points,
            "log_credibility": log_credibility, "parents": parents, "resampled": bool(resampled),
            "landmarks": model.landmarks, "yaw_pitch_roll": yaw_pitch_roll(rotation),
            "expression": expression(np.asarray(pose)[COEF], model.morph_std),
        }
        return Estimate(frame=int(t), box=(box[0], box[1], box[2], box[3]), confidence=float(state.confidence),
                        target_state=state.target_state, phase=phase, extras=extras)


def _with_fit(out: Estimate, est: Any) -> Estimate:
    """``out`` with the fraction of vertices the frame explains as the object, expected and counted, of
    :func:`.filter.update`'s estimate ``est`` in its extras (``inlier_fraction``, ``inlier_count``): the
    frame's fit as the experts' texels saw it, whatever the lost guard made of it. Not recorded."""
    return dataclasses.replace(out, extras={**out.extras, "inlier_fraction": float(est.inlier_fraction),
                                            "inlier_count": float(est.inlier_count)})


#: the one instance (it keeps no state)
TRACKER = GFlowTracker()
