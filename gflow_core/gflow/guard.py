"""Lost-target guard for G-flow: verify the estimate, hold it while the target is hidden, search for
it and re-seat the experts where it is found. A departure from the paper, which is silent on
losing the target.

Marks et al. (2004) weigh each expert by how well its pose explains the frame (eq. 17, 19). An
occluder or a passer-by that the texels can explain well enough takes the experts with it, and
nothing brings them back: on caviar1's stress clips the man in black who walks in front of the
target took every expert along with him, at a fraction of vertices explained of 0.97, in the
untouched control clip too. The guard is :mod:`gflow_core.m2.lost`, the contour trackers' guard,
around G-flow's estimate box:

* **Verification.** r_t, the normalised correlation of edge-orientation channels between the
  user's box on the first frame (the anchor, never updated) and the estimate's box, and with
  colour frames rho_c, the Bhattacharyya distance of the boxes' hue-saturation histograms
  (Perez et al. 2002). Neither depends on G-flow's texels, which may have learnt the distractor.
* **Hidden / lost** from the chi-squared distributions of those distances (Toyama & Blake 2002,
  sec. 3), the target's learnt on frames judged found, the clutter's from the best box around
  the estimate (:func:`gflow_core.visibility.visibility`): no threshold of its own.
* **Hold.** While lost, the reported box is the last found one, with ``target_state``
  ``occluded`` (or ``lost`` once the search covers the whole frame), and so are the reported
  points (the held pose's, :attr:`GuardStep.held_pose`). The experts go on as G-flow moves them,
  kept within ``lost_hold`` box sizes of the held box (:meth:`.tracker.GFlowTracker.update`, as the
  contour trackers keep their particles in the hold window): G-flow's likelihood follows whatever
  explains the frame best while the face is hidden or turned away -- on david_indoor played at every
  3rd frame, the plain wall beside a face turning to profile -- and kept near, the experts are where
  the face comes back (landmark NME 0.225 -> 0.136 at every 3rd frame, 0.104 -> 0.081 at full rate,
  means of seeds 1-3).
* **Re-detection** over a window that widens each lost frame up to the whole frame
  (:func:`gflow_core.m2.lost.search`). A candidate judged the target as it looks
  (P(visible) >= 1/2) away from the experts' box re-seats every expert (:func:`reseat`) at the pose
  where the first look fits the frame in the candidate's box (:func:`settle`: the first frame's
  pose moved and scaled into the box, then the peak of eq. 14 with the first frame's texels), with
  texels read from the frame there (as on the first frame, eq. 7-8 with ``Var(V_1)``) and equal
  credibilities. A box is all the search finds: moving the last found pose into it, as before,
  left the points off the face (a turned or tilted pose, or the box a few pixels off), and the
  texels read there then held them off. A candidate within the experts' box leaves them as they
  are, unless the first look, settled there, fits the frame better than at their estimate (G-flow's
  check below): after a loss the experts may come back near the face with the wrong pose, or with
  the texels of what they followed meanwhile.
* **G-flow's likelihood as a check, where the edges are alone.** Where the colour cue is not
  weighed (a grey video, or colour that does not tell the target from clutter:
  :func:`gflow_core.m2.lost.colour_weighed`), the edges alone decided too often: a face rolling
  in the image plane fails the axis-bound verification while the experts follow it (jumping),
  and on david_indoor, where the face walks into bright light, a candidate elsewhere was taken
  for it. There G-flow's own model must agree (:func:`first_look_fit`: the normalised correlation
  of the first frame's texels with the frame at the pose's vertices): a candidate re-seats the
  experts only if the first look fits the frame better there than at the experts' pose, and about
  as well as it did on found frames (a misfit within two standard deviations of their mean, either
  side: a candidate far better than the target has lately fitted is a look-alike of the first
  look); and
  where it fits better at the experts' pose than at the held box, the experts' box is reported
  rather than the held one. The correlation, not the fraction of vertices the texels explain
  (eq. 13 against the outlier process): a plain wall explains most texels of a contrast-normalised
  face within three standard deviations (about 0.9 of them, as much as the face in bright light),
  and has no correlation with it. Where colour is weighed, edges and colour decide: on caviar1 the
  man who walks past the target explains the grey-level first look as well as she does, and the
  check kept the experts on him.

The guard reads the grey frame and, for colour frames, the colour bins (:mod:`gflow_core.colour`);
G-flow's likelihood still reads the grey levels alone. No I/O here.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

from ..m2 import lost as lostmod
from ..m2.lost import Anchor, LostParams, LostState
from ..visibility import ChiSquare, Visibility
from .filter import ExpertState, GFlowConfig, _ro
from .geometry import COEF, ROT, TRANS, project
from .head_model import MorphableModel
from .image import FrameData, bilinear_stencil
from .pose_opinion import TextureView, coarse_to_fine_peak, search_offsets

__all__ = ["GuardStep", "guard_params", "anchor_of", "channels", "step", "reseat_pose", "reseat", "settle",
           "first_look_fit"]

#: (H, W) uint8 grey -> (H, W, 4) the guard's orientation channels
channels = lostmod.channels


@dataclass(frozen=True)
class GuardStep:
    """One frame's verdict.

    lost : the guard's state after the frame.
    box : (4,) the box to report (the estimate's, the held one, or the re-detected one).
    pose : (P,) the pose to re-seat the experts at, or None (no re-detection this frame).
    confidence : P(visible) of the box (1 - P(hidden) during the warm-up).
    target_state : ``tracked``, ``occluded`` (held, still searching nearby) or ``lost`` (the
        search covers the whole frame).
    phase : ``track``, ``lost`` or ``redetect``.
    level : running moments of the first look's misfit ``1 - fit`` at the estimate on found frames.
    held_pose : (P,) the pose of the held box when that is the box reported (the face where it was last
        found: the estimate's points are that pose's too), else None.
    """

    lost: LostState
    box: tuple[float, float, float, float]
    pose: np.ndarray | None
    confidence: float
    target_state: str
    phase: str
    level: ChiSquare = ChiSquare()
    held_pose: np.ndarray | None = None


def guard_params(window: float, growth: float) -> LostParams:
    """The guard's settings (:class:`gflow_core.m2.lost.LostParams` with the hold window and growth)."""
    return LostParams(window=window, growth=growth)


def anchor_of(grey: np.ndarray, box: tuple[float, float, float, float], p: LostParams,
              bins: np.ndarray | None) -> Anchor:
    """The anchor of the user's ``box`` on the first frame ``grey`` (H, W) uint8, with its colour
    histogram when ``bins`` (H, W) uint8 are given."""
    return lostmod.anchor_of(lostmod.channels(grey), box, p, bins)


def reseat_pose(held_pose: np.ndarray, held_box: tuple[float, ...], box: tuple[float, ...]) -> np.ndarray:
    """The pose whose box is ``box``: ``held_pose`` (P,) (whose box was ``held_box``) with its morph
    coefficients scaled by f = box size / held size and its translation moved.

    Both of G-flow's boxes (the projected vertices' bounding box, and a learned face's following
    box, :func:`.face_pose.following_box`) scale about the translation ``l`` when every
    coefficient is scaled (eq. 1 is linear in ``c``), so with centres ``m``:
    ``l' = m_box - f (m_held - l)``."""
    u = np.array(held_pose, dtype=np.float64, copy=True)
    f = float(np.sqrt((box[2] * box[3]) / max(held_box[2] * held_box[3], 1e-9)))
    m_held = np.array([held_box[0] + held_box[2] / 2.0, held_box[1] + held_box[3] / 2.0])
    m_box = np.array([box[0] + box[2] / 2.0, box[1] + box[3] / 2.0])
    l = u[TRANS].copy()
    u[COEF] *= f
    # l' = m_box - f (m_held - l)
    u[TRANS] = m_box - f * (m_held - l)
    return u


def reseat(experts: ExpertState, pose: np.ndarray, frame: np.ndarray, model: MorphableModel,
           cfg: GFlowConfig) -> ExpertState:
    """Every expert at ``pose`` (P,) with texels read from ``frame`` (H, W) float64 there, as on the
    first frame (:func:`.filter.init_state`: ``Var(V_1) = v_init_var``, ``unknown_var`` outside the
    image), equal credibilities. Backgrounds and the texture anchor are kept."""
    E = experts.n_experts
    poses = np.tile(np.asarray(pose, dtype=np.float64), (E, 1))
    st = bilinear_stencil(project(model.bases, poses), frame.shape)
    y = st.sample(np.ascontiguousarray(frame, dtype=np.float64).reshape(-1))
    return ExpertState(poses=_ro(poses), tex_mean=_ro(np.where(st.inside, y, 0.5)),
                       tex_var=_ro(np.where(st.inside, cfg.v_init_var, cfg.unknown_var)),
                       bg_mean=experts.bg_mean, bg_var=experts.bg_var,
                       log_credibility=_ro(np.full(E, -np.log(E))), image_shape=experts.image_shape,
                       tex_anchor=experts.tex_anchor)


def settle(pose: np.ndarray, pyramid: Sequence[FrameData], experts: ExpertState, model: MorphableModel,
           cfg: GFlowConfig) -> np.ndarray:
    """The pose near ``pose`` (P,) where the first look fits the frame: the peak of eq. 14 with the
    first frame's texels (:func:`first_look_fit`'s), found as an expert's peak is
    (:func:`.pose_opinion.coarse_to_fine_peak`: the translation search on the coarsest level of
    ``pyramid``, then Gauss-Newton coarse to fine), with the pose transition's spread about ``pose``
    and, for the rotation, the frontal reset's (``reset_std_deg``; the walk's without a reset).

    A re-detection finds a box, not a pose: :func:`step` places the first frame's pose in it and
    settles it here, so that the experts are re-seated with their points on the face rather than
    where a box-sized guess put them.

    Returns (P,) float64.
    """
    mean, var = _first_look(experts, cfg)
    std = cfg.prior_std(model.n_bases)
    if cfg.reset_rate > 0.0:
        std[ROT] = np.radians(cfg.reset_std_deg)
    u0 = np.asarray(pose, dtype=np.float64)[None]
    peak = coarse_to_fine_peak(model.bases, pyramid, u0, TextureView(mean=mean, var=var + cfg.psi_v), cfg.sigma_w,
                               std, cfg.gn_iterations, use_background=False, photometric=cfg.photometric_model(),
                               offsets=search_offsets(cfg.search_radius, cfg.search_step),
                               max_rotation=np.radians(cfg.max_rotation_deg), search_stride=cfg.search_stride,
                               outlier_sq=cfg.outlier_sigmas ** 2, scale=cfg.scale_limits())
    return peak.u_hat[0]


def _first_look(experts: ExpertState, cfg: GFlowConfig) -> tuple[np.ndarray, np.ndarray]:
    """The first frame's texels and their variance ``v_init_var`` (1, n), or without them the experts'
    mean texels and variances."""
    if experts.tex_anchor is not None:
        mean = np.asarray(experts.tex_anchor, dtype=np.float64)[None]
        return mean, np.full_like(mean, cfg.v_init_var)
    return (np.asarray(experts.tex_mean).mean(axis=0, keepdims=True),
            np.asarray(experts.tex_var).mean(axis=0, keepdims=True))


def first_look_fit(experts: ExpertState, frame: np.ndarray, model: MorphableModel, cfg: GFlowConfig
                   ) -> Callable[[np.ndarray], float]:
    """``fit(pose)``: how well the first look fits ``frame`` (H, W) at ``pose`` (P,): the normalised
    correlation of the first frame's texels (``tex_anchor``; without them the experts' mean texels)
    with the frame at the projected vertices, over the vertices in the image, times the fraction of
    them in the image (a pose half out of the frame fits half as well); 0 for a flat patch or fewer
    than 3 vertices in the image. In [-1, 1]."""
    mu = _first_look(experts, cfg)[0][0]
    flat = np.ascontiguousarray(frame, dtype=np.float64).reshape(-1)

    def fit(pose: np.ndarray) -> float:
        st = bilinear_stencil(project(model.bases, np.asarray(pose, dtype=np.float64)[None]), frame.shape)
        y, ok = st.sample(flat)[0], st.inside[0]
        if ok.sum() < 3:
            return 0.0
        a, b = mu[ok] - mu[ok].mean(), y[ok] - y[ok].mean()
        den = float(np.sqrt((a * a).sum() * (b * b).sum()))
        # rho = sum (mu - <mu>)(y - <y>) / sqrt(sum (mu - <mu>)^2 sum (y - <y>)^2), times the inside fraction
        return float((a * b).sum()) / den * float(ok.mean()) if den > 0 else 0.0

    return fit


def step(lost: LostState, anchor: Anchor, p: LostParams, channels: np.ndarray, bins: np.ndarray | None,
         box: tuple[float, float, float, float], pose: np.ndarray, scales: tuple[float, ...],
         fit: Callable[[np.ndarray], float] | None = None, level: ChiSquare = ChiSquare(),
         place: Callable[[tuple[float, float, float, float]], np.ndarray] | None = None) -> GuardStep:
    """Judge the estimate ``box`` (x, y, w, h) of pose ``pose`` (P,) on a frame's orientation channels
    (H, W, 4) and colour bins (H, W) or None; hold and search while lost (:mod:`gflow_core.m2.lost`).
    With ``fit`` (:func:`first_look_fit`) a candidate away from the estimate re-seats the experts only
    where the first look fits the frame better than at the estimate, and about as well as it did at
    the target: its misfit ``1 - fit`` within two standard deviations of the mean of the found
    frames' (``level``, learnt at the guard's rate). The check applies only while the colour cue
    is not weighed (edges alone). With ``place`` the experts are re-seated at ``place(box)`` of the
    candidate's box (:func:`settle` of the first frame's pose placed in it), else at the held pose
    moved and scaled into it (:func:`reseat_pose`); a candidate within the estimate's box re-seats
    them only where ``fit`` confirms it (whether colour is weighed or not)."""
    seen = lostmod.observe(channels, anchor, box, p, bins)
    held_now = (*box, *(float(v) for v in pose))
    first_look = fit
    if lostmod.colour_weighed(seen.colour, lost):
        # edges and colour, two independent cues, decide; G-flow's likelihood has its say only where the
        # edges are alone (grey video, or a colour that does not tell the target from clutter)
        fit = None
    st, vis, is_lost = lostmod.judge(lost, seen, held_now, p)
    f_est = None if fit is None else fit(pose)
    if not is_lost:
        if f_est is not None:
            level = level.update(1.0 - f_est, p.rate)
        return GuardStep(st, box, None, _confidence(vis, st, p), "tracked", "track", level)
    held = st.held
    if held is None:  # lost before any frame was found (the estimate left the frame at once)
        held = held_now
    h_box = (held[0], held[1], held[2], held[3])
    h_pose = np.array(held[4:], dtype=np.float64)
    ring = None if seen.clutter is None else seen.clutter[1]
    cand, cvis, covers = lostmod.search(channels, anchor, h_box, st, p, scales, ring, bins)
    state = "lost" if covers else "occluded"
    if cand is not None and cvis is not None and cvis.present:
        f = float(np.exp(cand.log_f))
        w, h = h_box[2] * f, h_box[3] * f
        new_box = (float(cand.centre[0] - (w - 1) / 2.0), float(cand.centre[1] - (h - 1) / 2.0), float(w), float(h))
        if _inside(cand.centre, box):
            # found where G-flow's experts already are: they stay, unless the first look, settled in the
            # candidate's box, fits the frame better than at their estimate (their points were put off the
            # face by what they followed while it was lost)
            if place is not None and first_look is not None:
                new_pose = place(new_box)
                if _confirms(1.0 - first_look(new_pose), 1.0 - first_look(pose), level, p):
                    st = lostmod.found_again(st, cand.r, (*new_box, *(float(v) for v in new_pose)), p)
                    return GuardStep(st, new_box, new_pose, float(cvis.visible), "tracked", "redetect", level)
            st = lostmod.found_again(st, cand.r, held_now, p)
            return GuardStep(st, box, None, float(cvis.visible), "tracked", "track", level)
        new_pose = reseat_pose(h_pose, h_box, new_box) if place is None else place(new_box)
        if fit is None or f_est is None or _confirms(1.0 - fit(new_pose), 1.0 - f_est, level, p):
            st = lostmod.found_again(st, cand.r, (*new_box, *(float(v) for v in new_pose)), p)
            return GuardStep(st, new_box, new_pose, float(cvis.visible), "tracked", "redetect", level)
        # G-flow's model does not confirm it: no re-seat
    if fit is not None and f_est is not None and fit(h_pose) <= f_est:
        # the first look fits the estimate better than the held place (a face turning in the image plane
        # fails the axis-bound verification while the experts follow it): report the experts' box
        return GuardStep(st, box, None, float(vis.visible), state, "lost", level)
    return GuardStep(st, h_box, None, float(vis.visible), state, "lost", level, h_pose)


def _confirms(d_cand: float, d_est: float, level: ChiSquare, p: LostParams) -> bool:
    """G-flow's first look confirms a candidate of misfit ``d_cand``: below the estimate's ``d_est``, and
    within two standard deviations of the mean misfit of the found frames, either side. Two: one held
    the target off the face on david_indoor, where its look had changed with the light (0.58-0.65
    against 0.44 +- 0.09). Either side: a candidate that fits the first look far better than the
    target has lately is a look-alike of the first look rather than the target as it looks now (on
    dollar an identical stack of bills lies beside the one tracked, whose look changes as it is
    opened)."""
    if d_cand >= d_est:
        return False
    if level.n < p.warmup:
        return True
    var = max(level.m2 - level.m1 * level.m1, 0.0)
    return abs(d_cand - level.m1) <= 2.0 * float(np.sqrt(var))


def _inside(centre: np.ndarray, box: tuple[float, float, float, float]) -> bool:
    """Whether ``centre`` (x, y) lies within half a box of ``box``'s centre in x and y (the box itself)."""
    c = np.array([box[0] + (box[2] - 1) / 2.0, box[1] + (box[3] - 1) / 2.0])
    return bool(abs(centre[0] - c[0]) <= box[2] / 2.0 and abs(centre[1] - c[1]) <= box[3] / 2.0)


def _confidence(vis: Visibility, st: LostState, p: LostParams) -> float:
    # during the warm-up the target distribution is still being learnt: 1 - P(hidden)
    return float(vis.visible if st.found > p.warmup else 1.0 - vis.hidden)
