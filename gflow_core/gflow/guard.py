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
* **A likelihood ratio for a candidate away from the experts, where the edges are alone.** Where
  the colour cue is weighed, edges and colour, two independent cues, judge a candidate and one
  judged present re-seats the experts. Where it is not (grey video, or a colour that does not tell
  the target from clutter: :func:`gflow_core.m2.lost.colour_weighed`), a candidate re-seats them
  only where the estimate is judged not the target as it looks (P(visible) < 1/2) and the
  candidate judged it (P(visible) >= 1/2; its edge distance the best of as many clutter draws as
  its search window holds clutter rings), each on the edges and G-flow's own model
  (:func:`_away_wins`): the misfit ``1 - fit`` of the first look (:func:`first_look_fit`: the
  normalised correlation of the first frame's texels with the frame at the pose's vertices) with
  two chi-squared distributions of its own, learnt on found frames: at the estimate (the target)
  and the best of the ring around it (clutter, :func:`first_look_clutter`). Before, the first look
  had to fit the candidate better than the estimate and within two standard deviations of the
  found frames' mean, either side: on dollar, where an identical stack of bills lies beside the
  one tracked (which is opened), the second stack, settled, fell within the band after a loss and
  took the experts (29.33 px); the ratio keeps them, as the estimate still fits the first look as
  the target has lately (its P(visible) 1.0 at frame 149: the estimate is not judged lost; 5.19
  px). On twinnings a settled patch of wall still takes the experts from the turned box at frame
  310, as before, but the ratio brings them back to the box at frame 350, where the band did not
  (31.33 -> 18.23 px). With colour's ratio too where colour is weighed, david_indoor's stress cases
  `sweep-40` and `slide-60` lost the face's points (landmark NME after the window 0.126 -> 0.266,
  0.068 -> 0.792). The correlation, not the fraction of vertices the texels explain (eq. 13
  against the outlier process): a plain wall explains most texels of a contrast-normalised face within three
  standard deviations (about 0.9 of them, as much as the face in bright light), and has no
  correlation with it. A motion prior on the candidate's place (a random walk from the held box,
  its spread G-flow's translation prior or learnt from the speed of found frames) was measured, with
  colour's ratio too, and not kept: tiger1 5.48 -> 6.84 px with either (a target that moves fast
  while lost), twinnings 18.23 -> 28.12 and 36.42 px.
* **G-flow's likelihood for a candidate within the experts' box, and for the box reported.** A
  candidate within the experts' box re-seats them only if the first look, settled there, fits the
  frame better than at the experts' pose and about as well as it did on found frames (a misfit
  within two standard deviations of their mean, either side: :func:`_confirms`): after a loss the
  experts may be back near the face with the wrong pose. While lost, where the first look fits the
  estimate better than the held place, the experts' box is reported rather than the held one (a
  face turning in the image plane fails the axis-bound verification while the experts follow it,
  jumping). Neither applies the colour rule: on caviar1 the man who walks past the target explains
  the grey-level first look as well as she does, and where colour is weighed, edges and colour
  decide what is reported.

The guard reads the grey frame and, for colour frames, the colour bins (:mod:`gflow_core.colour`);
G-flow's likelihood still reads the grey levels alone. No I/O here.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

from .. import redetect
from ..m2 import lost as lostmod
from ..m2.lost import Anchor, LostParams, LostState
from ..visibility import ChiSquare, Cue, Visibility, visibility
from .filter import ExpertState, GFlowConfig, _ro
from .geometry import COEF, ROT, TRANS, project
from .head_model import MorphableModel
from .image import FrameData, bilinear_stencil
from .pose_opinion import TextureView, coarse_to_fine_peak, search_offsets

__all__ = ["GuardStep", "guard_params", "anchor_of", "channels", "step", "reseat_pose", "reseat", "settle",
           "first_look_fit", "witnessed"]

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
    look_clutter : running moments of the first look's best misfit beside the estimate on those frames
        (:func:`first_look_clutter`).
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
    look_clutter: ChiSquare = ChiSquare()


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
        pts = project(model.bases, np.asarray(pose, dtype=np.float64)[None])
        return float(_correlations(mu, flat, frame.shape, pts)[0])

    return fit


def first_look_clutter(experts: ExpertState, frame: np.ndarray, model: MorphableModel, cfg: GFlowConfig,
                       ring: float) -> Callable[[np.ndarray, tuple[float, float, float, float]], float]:
    """``best(pose, box)``: the best fit of the first look (:func:`first_look_fit`) to ``frame`` (H, W)
    at ``pose`` (P,) moved, by its translation, to centres around ``box`` (x, y, w, h): on a grid of a
    quarter box size, within ``ring`` box sizes of its centre and farther than half a box in x or y
    (the ring in which :func:`gflow_core.m2.lost.observe` samples the edges' clutter). A sample of what
    the best look-alike beside the target scores with the first look (eq. 1 is linear in the
    translation ``l``, so every point moves with it)."""
    mu = _first_look(experts, cfg)[0][0]
    flat = np.ascontiguousarray(frame, dtype=np.float64).reshape(-1)
    g = np.arange(-np.floor(4 * ring), np.floor(4 * ring) + 1) / 4.0
    gx, gy = np.meshgrid(g, g)
    away = (np.abs(gx) > 0.5) | (np.abs(gy) > 0.5)
    steps = np.stack([gx[away], gy[away]], axis=1)

    def best(pose: np.ndarray, box: tuple[float, float, float, float]) -> float:
        pts = project(model.bases, np.asarray(pose, dtype=np.float64)[None])[0]
        offsets = steps * np.array([box[2], box[3]])
        return float(_correlations(mu, flat, frame.shape, pts[None] + offsets[:, None, :]).max())

    return best


def _correlations(mu: np.ndarray, flat: np.ndarray, shape: tuple[int, ...], pts: np.ndarray) -> np.ndarray:
    """(K,) fits of the first look ``mu`` (n,) to the frame ``flat`` (H W,) of ``shape`` at the points
    ``pts`` (K, n, 2): the correlation over the points in the image times their fraction (0 with fewer
    than 3 in the image or a flat patch)."""
    st = bilinear_stencil(pts, (int(shape[0]), int(shape[1])))
    y, ok = st.sample(flat), st.inside
    w = ok.astype(np.float64)
    cnt = w.sum(axis=1)
    c = np.maximum(cnt, 1.0)
    a = (mu[None] - (w * mu[None]).sum(axis=1, keepdims=True) / c[:, None]) * w
    b = (y - (w * y).sum(axis=1, keepdims=True) / c[:, None]) * w
    den = np.sqrt((a * a).sum(axis=1) * (b * b).sum(axis=1))
    # rho = sum (mu - <mu>)(y - <y>) / sqrt(sum (mu - <mu>)^2 sum (y - <y>)^2), times the inside fraction
    rho = np.where(den > 0, (a * b).sum(axis=1) / np.where(den > 0, den, 1.0), 0.0) * (cnt / ok.shape[1])
    return np.where(cnt >= 3, rho, 0.0)


def step(lost: LostState, anchor: Anchor, p: LostParams, channels: np.ndarray, bins: np.ndarray | None,
         box: tuple[float, float, float, float], pose: np.ndarray, scales: tuple[float, ...],
         fit: Callable[[np.ndarray], float] | None = None, level: ChiSquare = ChiSquare(),
         place: Callable[[tuple[float, float, float, float]], np.ndarray] | None = None,
         ring_fit: Callable[[np.ndarray, tuple[float, float, float, float]], float] | None = None,
         look_clutter: ChiSquare = ChiSquare(), witness: bool = False) -> GuardStep:
    """Judge the estimate ``box`` (x, y, w, h) of pose ``pose`` (P,) on a frame's orientation channels
    (H, W, 4) and colour bins (H, W) or None; hold and search while lost (:mod:`gflow_core.m2.lost`).

    With ``fit`` (:func:`first_look_fit`) and ``ring_fit`` (:func:`first_look_clutter`), found frames
    on which the colour cue is not weighed teach two distributions of the first look's misfit
    ``1 - fit``: at the estimate (``level``) and the best beside it (``look_clutter``), at the guard's
    rates. A candidate away from the estimate's box that the search judges present re-seats the experts
    (at ``place(box)`` of its box, :func:`settle`; else the held pose moved and scaled into it,
    :func:`reseat_pose`): where colour is weighed at once, else only on a likelihood ratio of both
    places, the target against clutter (:func:`_away_wins`). A candidate within the estimate's box
    re-seats them only where ``fit`` confirms it (:func:`_confirms`).

    With ``witness``, an estimate the edges judge lost whose box is reported (the first look fits it
    better than the held place) is reported ``tracked`` where the first look vouches for it
    (:func:`witnessed`); the guard's state, its search and the box are as without it (phase ``lost``).
    """
    seen = lostmod.observe(channels, anchor, box, p, bins)
    held_now = (*box, *(float(v) for v in pose))
    weighed = lostmod.colour_weighed(seen.colour, lost)
    st, vis, is_lost = lostmod.judge(lost, seen, held_now, p)
    f_est = None if fit is None else fit(pose)
    if not is_lost:
        if f_est is not None and not weighed:
            level = level.update(1.0 - f_est, p.rate)
            if ring_fit is not None:
                look_clutter = look_clutter.update(1.0 - ring_fit(pose, box), p.clutter_rate)
        return GuardStep(st, box, None, _confidence(vis, st, p), "tracked", "track", level, None, look_clutter)
    held = st.held
    if held is None:  # lost before any frame was found (the estimate left the frame at once)
        held = held_now
    h_box = (held[0], held[1], held[2], held[3])
    h_pose = np.asarray(held[4:], dtype=np.float64)
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
            if place is not None and fit is not None and f_est is not None:
                new_pose = place(new_box)
                if _confirms(1.0 - fit(new_pose), 1.0 - f_est, level, p):
                    st = lostmod.found_again(st, cand.r, (*new_box, *(float(v) for v in new_pose)), p)
                    return GuardStep(st, new_box, new_pose, float(cvis.visible), "tracked", "redetect", level, None,
                                     look_clutter)
            st = lostmod.found_again(st, cand.r, held_now, p)
            return GuardStep(st, box, None, float(cvis.visible), "tracked", "track", level, None, look_clutter)
        new_pose = reseat_pose(h_pose, h_box, new_box) if place is None else place(new_box)
        # where colour is weighed, edges and colour judged the candidate present (two independent cues);
        # where the edges are alone, the likelihood ratio of both places decides
        if weighed or _away_wins(seen, cand, st, lost, ring, p,
                                 None if fit is None or f_est is None else (1.0 - f_est, 1.0 - fit(new_pose)),
                                 level, look_clutter):
            st = lostmod.found_again(st, cand.r, (*new_box, *(float(v) for v in new_pose)), p)
            return GuardStep(st, new_box, new_pose, float(cvis.visible), "tracked", "redetect", level, None,
                             look_clutter)
    if fit is not None and f_est is not None and not weighed and fit(h_pose) <= f_est:
        # the first look fits the estimate better than the held place (a face turning in the image plane
        # fails the axis-bound verification while the experts follow it): report the experts' box
        wvis = None if not witness or ring_fit is None else witnessed(f_est, ring_fit(pose, box), level, look_clutter, p)
        if wvis is not None:
            # ... and where G-flow's first look vouches for it, report it tracked (the guard still holds and
            # searches: nothing else changes)
            # confidence: the first look's P(visible), low on a turned face (part of it is judged hidden)
            return GuardStep(st, box, None, float(wvis.visible), "tracked", "lost", level, None, look_clutter)
        return GuardStep(st, box, None, float(vis.visible), state, "lost", level, None, look_clutter)
    return GuardStep(st, h_box, None, float(vis.visible), state, "lost", level, h_pose, look_clutter)


def witnessed(f_est: float, f_ring: float, level: ChiSquare, look_clutter: ChiSquare, p: LostParams
              ) -> Visibility | None:
    """G-flow's own verdict on an estimate the edges judge lost: the visibility of the first look's
    misfit ``1 - f_est`` at the estimate (:func:`first_look_fit`) against its distributions on found
    frames, the target's ``level`` and the clutter's ``look_clutter`` (:func:`gflow_core.visibility.visibility`),
    where it is judged the target, as it looks or part hidden (:attr:`.Visibility.present`: the
    turned face's misfit rises above the frontal one's), the first look fits the estimate
    better than the best place beside it on this frame (``f_ring``, :func:`first_look_clutter`: the
    clutter does not explain it), and those distributions tell the target from clutter
    (:func:`_discriminates`); else None.

    A departure from the contour trackers' guard, whose edge anchor is the first box, never updated, so
    that an occluder is not learnt. The first look is the first frame's texels too, but on G-flow's 3-D
    vertices, which turn with the head: on david_indoor, as the face turns and walks into bright light,
    the edges' correlation with the first box falls below the clutter's (frames 306-348) while the first
    look still fits the estimate better than anything beside it. It is a witness rather than an updated
    template, in the manner of TLD's P-N constraints and LCT's long-term filter: nothing is learnt from a
    witnessed frame, and an occluder, which does not fit the face's first look, is not witnessed."""
    if not _discriminates(level, look_clutter, p) or f_est <= f_ring:
        return None
    vis = visibility(1.0 - f_est, level, look_clutter, p.min_std)
    return vis if vis.present else None


def _away_wins(seen: lostmod.Observation, cand: redetect.Candidate, st: LostState, lost: LostState,
               ring: float | None, p: LostParams, misfits: tuple[float, float] | None, level: ChiSquare,
               look_clutter: ChiSquare) -> bool:
    """Whether a candidate away from the estimate's box is the target and the estimate is not, where the
    colour cue is not weighed: P(visible) of the estimate below 1/2 and of the candidate at least 1/2
    (:func:`gflow_core.visibility.visibility`), on the edges' distances (the estimate's ``seen.r``
    against ``lost``'s distributions; the candidate's ``cand.r`` against ``st``'s, the best of
    ``trials`` draws: its search window's area over the clutter ring's) with, as a second cue, the first
    look's ``misfits`` (estimate, candidate) where its distributions ``level`` and ``look_clutter`` tell
    the target from clutter (:func:`_discriminates`).

    The first look's clutter distribution is what decides on dollar: a second, identical stack of bills
    lies beside the one tracked, which is opened; the first look fits the second stack far better than
    the opened one, but as the opened one fits it as the target has lately looked, the estimate is
    judged visible and the experts stay."""
    cues_e: tuple[Cue, ...] = ()
    cues_c: tuple[Cue, ...] = ()
    if misfits is not None and _discriminates(level, look_clutter, p):
        cues_e = (Cue(misfits[0], level, look_clutter),)
        cues_c = (Cue(misfits[1], level, look_clutter),)
    vis_e = visibility(1.0 - seen.r, lost.target, lost.clutter, p.min_std, cues=cues_e)
    trials = max(cand.area / ring, 1.0) if ring else 1.0
    vis_c = visibility(1.0 - cand.r, st.target, st.clutter, p.min_std, trials=trials, cues=cues_c)
    return vis_e.visible < 0.5 and vis_c.visible >= 0.5


def _discriminates(level: ChiSquare, clutter: ChiSquare, p: LostParams) -> bool:
    """Whether the first look tells the target from clutter: both misfit distributions learnt over
    ``p.warmup`` found frames or more, the target's mean below the clutter's."""
    return level.n >= p.warmup and clutter.n >= p.warmup and level.mean() < clutter.mean()


def _confirms(d_cand: float, d_est: float, level: ChiSquare, p: LostParams) -> bool:
    """G-flow's first look confirms a candidate within the estimate's box of misfit ``d_cand``: below the
    estimate's ``d_est``, and within two standard deviations of the mean misfit of the found frames,
    either side. Two: one held the target off the face on david_indoor, where its look had changed
    with the light (0.58-0.65 against 0.44 +- 0.09). Either side: a candidate that fits the first look
    far better than the target has lately is a look-alike of the first look rather than the target as
    it looks now."""
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

