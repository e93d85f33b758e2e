"""The contour particle filter (the chamfer tracker and learned M2) as pure functions of (params,
state, observation, draws): weigh proposals by eq. 7, resample, and guard against a lost target.

Toyama & Blake (IJCV 2002) weigh the particles X = (alpha, k) by the exemplar likelihood

    p(z | alpha, k) ~ exp(-rho(z, T_alpha x~_k) / (2 sigma_k^2)) / sigma_k^d_k      (eq. 7)

and resample. This module holds that step for the two contour trackers and the departures the
pipeline's filter stage (``stages/particle_filter.py``, an adapter of :class:`ContourFilter`) runs, and
the contour trackers' protocol (:class:`gflow_core.contour.protocol.ContourTracker`) updates with:

* **Initialisation.** With no learned model (the chamfer tracker) the template is the edge pixels
  inside the initial box, K = 1 with likelihood exp(-lambda rho). With a learned model the box
  places it: alpha_0 = (box centre, 0, s) with s the box size over the model's reference size, k
  drawn from pi (sec. 4.1, step 6), and the first frame weighed at once; frame 0's estimate is the
  box itself.
* **Scale prior** (chamfer; departure): the directed chamfer distance alone is smallest for a
  template shrunk onto dense edges, so with ``scale_prior`` > 0 each particle is also weighed by
  log s ~ N(0, scale_prior^2) (s relative to the first box).
* **Product of likelihoods** (learned models with appearance exemplars; departure,
  :mod:`.m2.appearance_metric`): each particle's chamfer kernel is multiplied by an appearance
  kernel, nearest of the learned exemplars and of a bounded online bank that starts with the
  initial box's region and adds the estimate's region on confident frames.
* **Kernel calibration** (departure, :func:`.m2.kernel.calibrate_sigma`): on frame 0 the learned
  kernels are widened so the initial box is a typical match on video the model was not learned on.
* **Box policy** (:mod:`.m2.target_shape`): with a learned model the estimate's box is the
  reference box under the MAP alpha (``box = reference``) or the paper's bounding box of
  T_alpha x~_k (``exemplar``); with none, the initial box carried by T_alpha.
* **Lost guard** (departure, :mod:`.m2.lost`): each tracked frame's estimate is verified against
  the initial box; a lost target's estimate is held, its particles kept near it, and the initial
  box searched for over a widening window until a candidate looks as the target did.
* **Template update** (chamfer; departure, :mod:`.template`): the K = 1 template, and the
  lost guard's anchor with it, is taken again from the estimate's box with Matthews et al.'s drift
  correction (PAMI 2004), after ``template_every`` frames in a row judged found and only where the
  first template has come to fit the target ``template_gain`` times worse than on the first
  frames. The paper's template is fixed; the M2 tracker's (``M2Params``, which has no such field)
  still is.
* **Following while lost** (chamfer, ``lost_follow``; departure from the guard's hold): while the
  lost guard holds the last found estimate, the reported estimate is the filter's own MAP estimate,
  kept within the hold window as the particles are, on frames where the current template still fits
  the edges there within ``template_gain`` times the first template's mean fit on the first frames
  (:func:`.template.still_fits`); elsewhere the last found estimate is held. The guard's verification
  is the correlation of edge-orientation channels with the first box; on a target whose look
  changes for good (skating1's turning skater) it judges the target lost while the filter is still
  on it, and a held box then stands still for the rest of the video. The edge model's own test
  tells the two apart where the look cannot: a filter on clutter has a template that fits badly.
* **Blank frames** (sec. 5.1.2, fig. 7): a frame with fewer than ``min_edges`` edge pixels, or one
  that could not be read, carries no evidence: every particle's likelihood is 1 (the posterior is
  the prior, "forced to rely on the prior").

Random draws of frame ``t`` (:class:`~gflow_core.tracker.FrameRng`): the initial cloud from
``stream(PURPOSE_INIT)``, k_0 from ``stream(PURPOSE_INIT_K)``, the resampling from
``stream(PURPOSE_RESAMPLE)``; the proposal's dynamics (:func:`gflow_core.contour.protocol.propose_cloud`)
from ``stream(PURPOSE_PROPOSAL)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any, Callable

import numpy as np

from .dynamics import PURPOSE_PROPOSAL
from .. import similarity
from .params import ChamferParams, ContourParams
from .template import align_first, anchor_peak, anchor_region, fit, still_fits, template_at
from ..m2 import dynamics as dyn
from ..m2 import lost as lostmod
from ..m2.appearance_metric import (AppearanceKernels, OnlineBank, appearance_log_lik, bank_update, new_bank,
                                   sample_patches_near)
from ..m2.dynamics import sample_categorical
from ..m2.kernel import calibrate_sigma
from ..m2.lost import Anchor, LostParams, LostState
from ..m2.model import M2Model
from ..m2.target_shape import fit_to_box
from ..m2.tracking import ContourExemplars, ParticleCloud, Posterior, curve_box, init_particles, posterior, \
    template_from_edges, weigh
from ..tracker import Box, Estimate, FrameRng

__all__ = ["ContourFilter", "ContourSetup", "ContourState", "ContourObservation", "FILTER", "setup",
           "k1_model", "restore_model", "guard_params", "PURPOSE_INIT", "PURPOSE_INIT_K", "PURPOSE_RESAMPLE", "PURPOSE_PROPOSAL"]

PURPOSE_INIT = 0x1417
PURPOSE_RESAMPLE = 0x2E5A
PURPOSE_INIT_K = 0x1418


@dataclass(frozen=True)
class ContourSetup:
    """What is fixed for a track: the initial box and the learned model placed for it.

    init : (x, y, w, h) the initial box; ref_size : (2,) its (w, h).
    learned : the learned model (its item frame fitted to the box's shape with ``fit_shape``), or
        None (the K = 1 chamfer tracker); learned_ex : its contour exemplars;
    app0 : its appearance kernels before calibration (None: none, or ``appearance`` off).
    """

    init: Box
    ref_size: np.ndarray
    learned: M2Model | None = None
    learned_ex: ContourExemplars | None = None
    app0: AppearanceKernels | None = None


def setup(params: ContourParams, init: Box, model: Any = None) -> ContourSetup:
    """Place a learned contour model (or none) for the initial box ``init``.

    Raises ``ValueError`` for a model that is not an M2 model with contour exemplars."""
    learned = model
    if learned is not None:
        if not isinstance(learned, M2Model):
            raise ValueError(f"the model is a {type(learned).__name__}, not an M2 model")
        if learned.kind != "curve":
            raise ValueError(f"the model has {learned.metric} patch exemplars; use the patch.filter stage "
                             f"(graph m2_patch) for patch models")
        if params.fit_shape:
            # the model's item frame stretched to the user's box shape (gflow_core.m2.target_shape)
            learned = fit_to_box(learned, init)
    return ContourSetup(init=init, ref_size=np.array(init[2:], dtype=np.float64), learned=learned,
                        learned_ex=learned.to_contour_exemplars() if learned is not None else None,
                        app0=learned.appearance if learned is not None and params.appearance else None)


def k1_model(template: np.ndarray, lam: float) -> ContourExemplars:
    """The chamfer tracker's model: one exemplar, the template, with likelihood exp(-lambda rho)."""
    return ContourExemplars.single(template, lam, dyn.random_walk(1.0, 0.01, 0.01))


@dataclass(frozen=True)
class ContourObservation:
    """What the contour filter reads of a frame (the preprocess stage's features).

    edges : (H, W) uint8 edge map; chamfer : (H, W) float chamfer image, or None when the frame is
    unusable (no evidence); blank : fewer than ``min_edges`` edge pixels (no evidence); grey :
    (H, W) uint8 grey image, or None (the appearance cues are skipped: chamfer only); channels :
    () -> (H, W, 4) the lost guard's orientation channels of ``grey`` (computed when first asked);
    bins : (H, W) uint8 colour bins of the frame (:func:`gflow_core.colour.bins`), or None (the lost
    guard weighs no colour).
    """

    edges: np.ndarray | None
    chamfer: np.ndarray | None
    blank: bool = False
    grey: np.ndarray | None = None
    channels: Callable[[], np.ndarray] | None = None
    bins: np.ndarray | None = None


@dataclass(frozen=True)
class ContourState:
    """The posterior after a frame and what the filter learnt.

    setup : ContourSetup; model : the contour exemplars (calibrated on frame 0); template : (P, 2) the
    K = 1 template (None with a learned model); app : the appearance kernels (calibrated); bank : the
    online appearance exemplars; cloud : the resampled posterior; lost : the lost guard's state;
    anchor : its channels of the initial box (or of the box the template was last taken from);
    judged : (confidence, target_state) of the last estimate; first : (P, 2) the first K = 1
    template, T_1 of the drift correction (None with a learned model); template_clock : the frame
    the template update counts from (the last update, or the last frame not judged found);
    first_anchor : (th, tw, 4) the lost guard's channels of the first box (None: no guard), the
    first anchor of the drift correction; first_fit : (sum, count) of the first template's rho at
    the estimates of the first frames.
    """

    setup: ContourSetup
    model: ContourExemplars
    cloud: ParticleCloud
    template: np.ndarray | None = None
    app: AppearanceKernels | None = None
    bank: OnlineBank | None = None
    lost: LostState = LostState()
    anchor: Anchor | None = None
    judged: tuple[float, str] = (1.0, "tracked")
    first: np.ndarray | None = None
    template_clock: int = 0
    first_anchor: np.ndarray | None = None
    first_fit: tuple[float, int] = (0.0, 0)


def guard_params(params: ContourParams) -> LostParams | None:
    """The lost guard's settings (None: no guard)."""
    return LostParams(window=params.lost_window, growth=params.lost_growth) if params.lost_guard else None


class ContourFilter:
    """The contour particle filter's update, init and box policy (stateless: everything is in
    :class:`ContourState`), on the features of a frame. The proposal and the features are
    :mod:`gflow_core.contour.protocol`'s, which puts this filter on the tracker protocol."""

    name = "contour"
    Params = ContourParams

    # -- the first frame ------------------------------------------------------------------------
    def init(self, params: ContourParams, obs: ContourObservation, setup_: ContourSetup, rng: FrameRng
             ) -> tuple[ContourState, Estimate]:
        """The posterior at the first frame from ``setup_.init`` (with a learned model, the first frame
        weighed at once). Raises ``ValueError`` for a box outside the frame or a template with no edges."""
        x, y, w, h = setup_.init
        if obs.edges is None:
            raise ValueError("no edge map")
        H, W = obs.edges.shape
        if x >= W or y >= H or x + w <= 0 or y + h <= 0:
            raise ValueError(f"initial box {setup_.init} lies outside the {W}x{H} frame")
        gp = guard_params(params)
        anchor = None
        if gp is not None and obs.grey is not None and obs.channels is not None:
            anchor = lostmod.anchor_of(obs.channels(), setup_.init, gp, obs.bins if params.lost_colour else None)
        if setup_.learned is None:
            pts = template_from_edges(obs.edges, setup_.init, params.max_points)
            model = k1_model(pts, params.lam)
            alpha0 = np.array([x + (w - 1) / 2.0, y + (h - 1) / 2.0, 0.0, 1.0])
            cloud = init_particles(alpha0, 0, params.particles, np.array(params.init_spread), rng.stream(PURPOSE_INIT))
            st = ContourState(setup_, model, cloud, template=pts, anchor=anchor, first=pts, template_clock=rng.t,
                              first_anchor=None if anchor is None else anchor.channels)
            est = self.estimate(params, st, rng.t, alpha0, 0, alpha0, np.zeros(4), float(params.particles), 0.0, "init")
            return st, est
        learned, learned_ex = setup_.learned, setup_.learned_ex
        assert learned_ex is not None
        model = learned_ex
        alpha0 = learned.alpha_from_box(setup_.init)
        cloud = init_particles(alpha0, 0, params.particles, np.array(params.init_spread), rng.stream(PURPOSE_INIT))
        # k_0 ~ pi (sec. 4.1, step 6: the mixture weights are the prior over exemplars)
        k0 = sample_categorical(model.pi, params.particles, rng.stream(PURPOSE_INIT_K))
        cloud = ParticleCloud(alpha=cloud.alpha, k=k0, log_w=np.zeros(params.particles))
        model, app = self._calibrate(params, setup_, model, obs, alpha0)
        bank = None
        if app is not None and params.online > 0 and obs.grey is not None:
            # online slot 0: the region of the user's box, kept for the whole track
            z0 = sample_patches_near(obs.grey, alpha0, learned.ref_size, app.res)[0]
            bank = new_bank(z0, rng.t)
        st = ContourState(setup_, model, cloud, app=app, bank=bank, anchor=anchor)
        return self._weigh(params, st, cloud, obs, rng, first=True)

    def _calibrate(self, params: ContourParams, setup_: ContourSetup, model: ContourExemplars,
                   obs: ContourObservation, alpha0: np.ndarray) -> tuple[ContourExemplars, AppearanceKernels | None]:
        """Widen the kernels so the user's box on frame 0 is a typical match (:func:`calibrate_sigma`)."""
        app = setup_.app0
        if not params.calibrate:
            return model, app
        assert setup_.learned is not None
        K = model.K
        at = ParticleCloud(alpha=np.tile(alpha0, (K, 1)), k=np.arange(K), log_w=np.zeros(K))
        if obs.chamfer is not None and not obs.blank:
            # rho_0 = min_k rho(T_alpha0 x~_k, z_0)
            rho0 = float(weigh(at, model, obs.chamfer)[1].min())
            model = replace(model, sigma=calibrate_sigma(model.sigma, model.d, rho0))
        if obs.grey is not None and app is not None:
            z = sample_patches_near(obs.grey, alpha0, setup_.learned.ref_size, app.res)
            rho_a0 = float(1.0 - appearance_log_lik(np.repeat(z, K, axis=0), np.arange(K), app, None)[1].max())
            app = replace(app, sigma=calibrate_sigma(app.sigma, app.d, rho_a0))
        return model, app

    # -- a frame --------------------------------------------------------------------------------
    def update(self, params: ContourParams, state: ContourState, proposal: ParticleCloud,
               obs: ContourObservation | None, rng: FrameRng) -> tuple[ContourState, Estimate]:
        """The posterior at frame ``rng.t``: ``proposal`` weighed by the frame (eq. 7, or no evidence
        when ``obs`` is None -- no frame arrived -- blank or unreadable), resampled, verified by the
        lost guard, and the online bank updated. The estimate's extras add ``log_lik`` (N,), the
        proposal's log-likelihoods."""
        return self._weigh(params, state, proposal, obs, rng)

    def _weigh(self, params: ContourParams, state: ContourState, cloud: ParticleCloud, obs: ContourObservation | None,
               rng: FrameRng, first: bool = False) -> tuple[ContourState, Estimate]:
        model, learned = state.model, state.setup.learned
        cham = None if obs is None else obs.chamfer
        if cham is None or (obs is not None and obs.blank):
            # no evidence: p(y_t | X_t) is the same for every X_t, so the posterior is the prior
            log_lik = np.zeros(cloud.n)
            phase = "coast"
        else:
            # log p(y | alpha, k) = -rho / (2 sigma_k^2) - d_k log sigma_k            (eq. 7)
            log_lik, _ = weigh(cloud, model, cham)
            phase = "track"
            if params.scale_prior > 0 and learned is None:
                # explicit prior on the size, log s ~ N(0, scale_prior^2) (s relative to the first box):
                # the directed chamfer distance alone is smallest for a template shrunk onto dense edges
                log_lik = log_lik - np.log(cloud.alpha[:, 3]) ** 2 / (2.0 * params.scale_prior ** 2)
        grey = None
        if phase == "track" and state.app is not None and obs is not None and obs.grey is not None:
            grey = obs.grey
            # x log K_app(rho_a(a_k or the online bank, z_alpha))      (product of the two kernels)
            assert learned is not None
            Z = sample_patches_near(grey, cloud.alpha, learned.ref_size, state.app.res)
            log_lik = log_lik + appearance_log_lik(Z, cloud.k, state.app, state.bank)[0]
        if first:
            phase = "init"
        post = posterior(cloud, log_lik, model.K, rng.stream(PURPOSE_RESAMPLE), params.particles)
        st = state
        if obs is not None and not first:
            post, phase, st = self._guard(params, st, obs, post, phase)
        if grey is not None and st.bank is not None and not first and phase == "track":
            st = self._update_bank(params, st, grey, post.map_alpha, post.map_k, rng.t)
        t1 = st.first
        if isinstance(params, ChamferParams) and params.template_every and t1 is not None and not first:
            if phase != "track" or obs is None:
                # the update waits for template_every frames judged found in a row
                st = replace(st, template_clock=rng.t)
            elif st.first_fit[1] < params.template_every:
                if obs.chamfer is not None:
                    # how well T_1 fits the target on the first frames: the reference of template_gain
                    r = fit(obs.chamfer, t1, post.map_alpha)
                    st = replace(st, first_fit=(st.first_fit[0] + r, st.first_fit[1] + 1))
            elif rng.t - st.template_clock >= params.template_every:
                st = self._update_template(params, st, obs, post.map_alpha, rng.t)
        st = replace(st, cloud=post.resampled)
        est = self.estimate(params, st, rng.t, post.map_alpha, post.map_k, post.mean_alpha, post.std_alpha, post.ess,
                            post.log_evidence, phase)
        log_lik.setflags(write=False)
        return st, replace(est, extras={**est.extras, "log_lik": log_lik})

    def _guard(self, params: ContourParams, st: ContourState, obs: ContourObservation, post: Posterior, phase: str
               ) -> tuple[Posterior, str, ContourState]:
        """Verify the estimate against the initial box; hold, bound and re-detect while lost
        (:mod:`gflow_core.m2.lost`). Returns the (possibly changed) posterior, phase and state."""
        gp = guard_params(params)
        if gp is None or st.anchor is None or phase != "track":
            if phase == "coast" and st.judged[1] == "tracked":
                st = replace(st, judged=(0.0, "tracked"))  # no evidence this frame
            return post, phase, st
        if obs.grey is None or obs.channels is None:
            return post, phase, st
        ch = obs.channels()
        box = self.box(params, st, post.map_alpha, post.map_k)
        bins = obs.bins if params.lost_colour else None
        seen = lostmod.observe(ch, st.anchor, box, gp, bins)
        lost_st, vis, lost = lostmod.judge(st.lost, seen, (*box, *post.map_alpha, post.map_k), gp)
        if not lost:
            return post, phase, replace(st, lost=lost_st, judged=(
                vis.visible if lost_st.found > gp.warmup else 1.0 - vis.hidden, "tracked"))
        held = lost_st.held
        assert held is not None
        h_box, h_alpha, h_k = (held[0], held[1], held[2], held[3]), np.array(held[4:8]), int(held[8])
        cand, cvis, covers = lostmod.search(ch, st.anchor, h_box, lost_st, gp, tuple(params.lost_scales),
                                            None if seen.clutter is None else seen.clutter[1], bins)
        alpha = post.resampled.alpha.copy()
        centre = np.array([h_box[0] + (h_box[2] - 1) / 2.0, h_box[1] + (h_box[3] - 1) / 2.0])
        if cand is not None and cvis is not None and cvis.present:
            # re-detected: the held state moved onto the candidate (and to its size), the particles with it
            f = float(np.exp(cand.log_f))
            shift = cand.centre - centre
            new_alpha = h_alpha.copy()
            new_alpha[:2] += shift
            new_alpha[3] *= f
            alpha[:, 3] *= f
            alpha[:, :2] = lostmod.bound_positions(alpha[:, :2] - post.mean_alpha[:2] + new_alpha[:2],
                                                   (float(new_alpha[0]), float(new_alpha[1])),
                                                   (0.25 * h_box[2] * f, 0.25 * h_box[3] * f))
            w, h = h_box[2] * f, h_box[3] * f
            new_box = (h_box[0] + shift[0] + (h_box[2] - w) / 2.0, h_box[1] + shift[1] + (h_box[3] - h) / 2.0, w, h)
            lost_st = lostmod.found_again(lost_st, cand.r, (*new_box, *new_alpha, h_k), gp)
            judged = (cvis.visible, "tracked")
            phase = "redetect"
        else:
            # hold the last found estimate; keep the particles within the window around it
            new_alpha = h_alpha
            half = (gp.window * h_box[2], gp.window * h_box[3])
            alpha[:, :2] = lostmod.bound_positions(alpha[:, :2] - centre + h_alpha[:2],
                                                   (float(h_alpha[0]), float(h_alpha[1])), half)
            if isinstance(params, ChamferParams) and params.lost_follow and obs.chamfer is not None \
                    and st.template is not None:
                # the filter's estimate, kept within the window as its particles are, is reported where the
                # template still fits the edges there (the edge model says the outline has not left)
                a = post.map_alpha.copy()
                a[:2] = lostmod.bound_positions(a[None, :2], (float(h_alpha[0]), float(h_alpha[1])), half)[0]
                if still_fits(obs.chamfer, st.template, a, st.first_fit, params.template_gain):
                    new_alpha = a
            judged = (vis.visible, "lost" if covers else "occluded")
            phase = "lost"
        post = replace(post, map_alpha=new_alpha, map_k=h_k,
                       resampled=ParticleCloud(alpha=alpha, k=post.resampled.k, log_w=post.resampled.log_w))
        return post, phase, replace(st, lost=lost_st, judged=judged)

    def _update_bank(self, params: ContourParams, st: ContourState, grey: np.ndarray, alpha: np.ndarray, k: int,
                     t: int) -> ContourState:
        """Count the estimate's nearest online exemplar; add its region when confident."""
        learned, app, bank = st.setup.learned, st.app, st.bank
        assert learned is not None and app is not None and bank is not None
        z = sample_patches_near(grey, alpha, learned.ref_size, app.res)
        _, r_best, nearest = appearance_log_lik(z, np.array([k]), app, bank)
        return replace(st, bank=bank_update(bank, z[0], int(nearest[0]), bool(r_best[0] >= params.confident_r), t,
                                            bound=params.online, every=params.online_every))

    def _update_template(self, params: ChamferParams, st: ContourState, obs: ContourObservation, alpha: np.ndarray,
                         t: int) -> ContourState:
        """Matthews et al.'s template update with drift correction (:mod:`.template`): the
        first template aligned again from the estimate ``alpha``; where it lands within epsilon of
        it, the template is taken again there, and with ``template_anchor`` the lost guard's anchor
        too, where the first anchor aligned again from there (by correlation) lands within epsilon
        (or one step of its search) as well; where either does not, nothing is taken."""
        if obs.chamfer is None or obs.edges is None or st.first is None:
            return st
        size = st.setup.ref_size
        box_size = math.sqrt(float(size[0] * size[1])) * float(alpha[3])
        eps, reach = params.template_drift * box_size, params.template_reach * box_size
        d = params.template_scale
        steps = (0.0, -d, d) if d > 0 else (0.0,)
        a_star, rho1 = align_first(obs.chamfer, st.first, alpha, max(1, math.ceil(reach)), steps, params.lam,
                                   params.scale_prior)
        if rho1 <= params.template_gain * st.first_fit[0] / max(st.first_fit[1], 1):
            return st  # T_1 still fits the target as it did: nothing to update
        # T_{n+1} = I_n(p*_n) if ||p*_n - p_n|| <= epsilon, else T_n (the size: p*_n keeps p_n's)
        if math.hypot(float(a_star[0] - alpha[0]), float(a_star[1] - alpha[1])) > eps or a_star[3] != alpha[3]:
            return st
        pts = template_at(obs.edges, a_star, size, params.max_points)
        if pts is None:
            return st
        anchor = st.anchor
        if anchor is not None and params.template_anchor and obs.channels is not None and st.first_anchor is not None:
            feat = obs.channels()
            peak, step = anchor_peak(feat, st.first_anchor, anchor.size, a_star, reach)
            # the same test for the anchor: ||q*_n - p*_n|| <= epsilon, q*_n the first anchor's peak
            if math.hypot(float(peak[0] - a_star[0]), float(peak[1] - a_star[1])) > max(eps, step):
                return st
            anchor = replace(anchor, channels=anchor_region(feat, anchor.res, anchor.size, a_star))
        return replace(st, model=k1_model(pts, params.lam), template=pts, anchor=anchor, template_clock=t)

    # -- the estimate ---------------------------------------------------------------------------
    def box(self, params: ContourParams, st: ContourState, alpha: np.ndarray, k: int) -> Box:
        """The estimate's box of the state (alpha, k) (the box policy)."""
        learned = st.setup.learned
        if learned is not None and params.box == "reference":
            # the reference box under alpha (its centre u and size s * ref_size; theta is left out)
            w, h = learned.ref_size * alpha[3]
            return (float(alpha[0] - (w - 1) / 2.0), float(alpha[1] - (h - 1) / 2.0), float(w), float(h))
        if learned is not None:
            # the bounding box of the MAP exemplar under its transform, T_alpha x~_k
            return curve_box(similarity.apply(alpha, st.model.curves[k, : st.model.n_points[k]]))
        # the initial box carried by T_alpha: centre u, size s * (w0, h0)
        w, h = st.setup.ref_size * alpha[3]
        return (float(alpha[0] - (w - 1) / 2.0), float(alpha[1] - (h - 1) / 2.0), float(w), float(h))

    def estimate(self, params: ContourParams, st: ContourState, t: int, alpha: np.ndarray, k: int, mean: np.ndarray,
                 std: np.ndarray, ess: float, log_ev: float, phase: str) -> Estimate:
        """The estimate of frame ``t``: frame 0's box is the initial box (with a learned model placed
        by alpha_0; the posterior of frame 0 only chooses the exemplar). ``extras``: ``alpha`` (4,),
        ``k``, ``mean``, ``std`` (4,) of the posterior, ``ess``, ``log_evidence``, ``n`` the number of
        particles, ``contour`` (P, 2) float32, the MAP exemplar under alpha."""
        learned = st.setup.learned
        if phase == "init" and learned is not None:
            alpha = learned.alpha_from_box(st.setup.init)
        b = tuple(float(v) for v in st.setup.init) if phase == "init" else self.box(params, st, alpha, k)
        contour = similarity.apply(alpha, st.model.curves[k, : st.model.n_points[k]]).astype(np.float32)
        confidence, target_state = (1.0, "tracked") if phase == "init" or not params.lost_guard else st.judged
        extras = {"alpha": tuple(float(v) for v in alpha), "k": int(k), "mean": tuple(float(v) for v in mean),
                  "std": tuple(float(v) for v in std), "ess": float(ess), "n": int(params.particles),
                  "log_evidence": float(log_ev), "contour": contour}
        return Estimate(frame=int(t), box=(b[0], b[1], b[2], b[3]), confidence=float(confidence),
                        target_state=target_state, phase=phase, extras=extras)


#: the one instance (it keeps no state)
FILTER = ContourFilter()


def restore_model(setup_: ContourSetup, params: ContourParams, template: np.ndarray | None,
                  sigma: np.ndarray | None, app_sigma: np.ndarray | None
                  ) -> tuple[ContourExemplars, AppearanceKernels | None]:
    """The model and appearance kernels of a saved state: the K = 1 template's, or the learned
    model's with the calibrated widths ``sigma`` and ``app_sigma``."""
    if template is not None:
        return k1_model(template, params.lam), None
    model = setup_.learned_ex
    assert model is not None
    if sigma is not None:
        model = replace(model, sigma=sigma)
    app0 = setup_.app0
    return model, replace(app0, sigma=app_sigma) if app0 is not None and app_sigma is not None else app0

