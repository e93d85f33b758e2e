"""The correlation-filter tracker's parameters: :class:`DCFParams`, the only place their defaults live.

The tracker is :mod:`gflow_core.dcf` (a particle filter whose likelihood is a discriminative
correlation filter learnt online; its docstring gives each part's role, the papers and the
departures). Everything else derives from this dataclass: the stages' parameter structs (made
from the tracker's spec by ``stages/spec_box.py``), the validation of
``pipeline/graphs/dcf.yaml``, ``gflow track --tracker dcf``'s options and their help, ``gflow info
dcf`` and the keywords of ``gflow.Tracker("dcf", ...)``. The defaults follow the papers where they
give one (lambda 1e-4, a Gaussian label of 0.1 the target's size, cells of 4 pixels: Henriques et
al. 2015; 17 scales 2 % apart, their rate and lambda: Danelljan et al. 2014 and 2017; the colour
model's rate and weight: Bertinetto et al. 2016); the rest were chosen on all nine shared
sequences and their stress cases together (``docs/trackers.md``).

This module imports no mathematics, so the command line reads it at no cost.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..params import Memory, check_memory, param

__all__ = ["DCFParams"]


@dataclass(frozen=True)
class DCFParams:
    """Every setting of the correlation-filter tracker. Each field's help text is in its declaration;
    ``gflow info dcf`` prints them all. Raises ``ValueError`` naming the first parameter it refuses."""

    # memory: the peak resident memory of `gflow track caviar1 --inline --stop 4` grows by 442 bytes a particle
    # (--particles 2e6 to 4e6) and 365 a template pixel (--set tracker.template=1200 to 2400), 2026-12-05
    particles: int = param(200, "number of particles N over (x, y, log s)", memory=Memory(440, "particle"))
    cell: int = param(4, "HOG cell size in pixels")
    padding: float = param(3.0, "the filter's window: the target plus this many times its mean side")
    template: int = param(150, "sqrt of the window's area in template pixels (the window is resampled to it)",
                          memory=Memory(360, "template pixel", power=2))
    mask: float = param(1.0, "the filter's support: a box of the target's size times this (0: the whole window, "
                             "closed form)")
    mu: float = param(0.03, "the ADMM penalty mu of the masked filter at its first iteration, relative to the "
                           "sample's mean energy per frequency")
    admm_iterations: int = param(2, "ADMM iterations of the masked filter a frame")
    lam: float = param(1e-4, "lambda, the ridge regression's regulariser")
    label_sigma: float = param(0.1, "std of the Gaussian desired response, in units of sqrt(w h) of the target")
    rate: float = param(0.02, "eta, the filter's learning rate on confident frames")
    anchor_weight: float = param(0.2, "weight of the first frame's filter in the filter detection uses")
    colour_weight: float = param(0.3, "alpha: the response is (1 - alpha) filter + alpha colour model (0: no "
                                      "colour model)")
    colour_rate: float = param(0.04, "learning rate of the colour model's histograms")
    # memory: `gflow track caviar1 --inline --stop 4` grows by 2605 bytes a pixel of scale_area with 17 scales, 153 a
    # pixel of each scale's sample (--set tracker.scale_area=1e6 to 4e6), 2026-12-05
    scales: int = param(17, "scales of the 1-D scale filter (odd; 1: the box keeps its first size)",
                        memory=Memory(150, "pixel of a scale's sample", times=("scale_area",)))
    scale_step: float = param(1.02, "ratio between neighbouring scales of the scale filter")
    scale_rate: float = param(0.025, "learning rate of the scale filter")
    scale_lam: float = param(0.01, "lambda of the scale filter")
    scale_area: int = param(1024, "pixels of the scale filter's sample at most",
                            memory=Memory(150, "pixel of a scale's sample", times=("scales",)))
    scale_anchor: bool = param(False, "the scale filter detects with the first frame's scale filter mixed in at "
                                      "anchor_weight, as the translation filter does, so the box's size stays tied to "
                                      "the first box's (gflow_core.dcf.scale; false: DSST's running filter alone)")
    scale_refine: bool = param(False, "the scale filter's peak is refined between its scales by the parabola through it "
                                      "and its neighbours, as fDSST interpolates its scale response (false: the best of "
                                      "the scales, steps of scale_step; gflow_core.dcf.scale)")
    scale_upsample: bool = param(True, "a target smaller than scale_area pixels is resampled up to it for the scale "
                                       "filter's sample, as larger ones are resampled down (false: sampled at its own "
                                       "size, DSST's rule)", before=False)
    max_log_scale: float = param(1.3862943611198906, "bound on |log s|: the box stays within [1/4, 4] times its "
                                                     "first size")
    kappa: float = param(30.0, "sharpness of the likelihood p(z | X) ~ exp(kappa y(X)), y the response")
    detect_fraction: float = param(0.3, "fraction of the particles drawn at the peak of the response")
    detect_std: float = param(1.0, "spread of the particles drawn at the response peak, px")
    std_xy_rel: float = param(0.05, "random walk of the centre per frame (the proposal), in units of sqrt(w h) "
                                    "of the initial box")
    speed_noise: float = param(0.5, "the centre's noise grows by this many times the speed |v| (px / frame)")
    velocity_memory: float = param(0.5, "m of the velocity v <- m v + (1 - m) (c_t - c_{t-1}) / dt")
    motion_fit: float = param(0.0, "the motion's gain g of the prediction c + g v dt is learnt from the tracked "
                                   "displacements at this rate, by regression with the prior g ~ N(1, 1) "
                                   "(gflow_core.dcf.motion_fit; 0: g = 1, constant velocity)")
    flow_mix: float = param(0.0, "the motion prior is a mixture of the constant-velocity prediction and the last box's "
                                 "displacement to this frame, matched by NCC (when flow_ratio accepts the match), the "
                                 "mode switching with this probability a frame and the likelihood picking it "
                                 "(gflow_core.dcf.flowpred; 0: constant velocity only; not with motion_switch)")
    flow_ratio: float = param(0.64, "with flow_mix, the last box's match is used only when its 1 - NCC is at most this "
                                   "times the runner-up's (Lowe's ratio test on squared distances; 0.64 is Lowe's 0.8 "
                                   "on distances)")
    motion_prior: float = param(0.25, "std of the motion prior about the prediction, in box sizes, plus the speed's share")
    motion_tail: float = param(0.0, "degrees of freedom nu of a Student-t motion prior of the same scale, whose cost "
                                    "grows as the log of the distance from the prediction, not its square, so a "
                                    "target that turned is not outweighed by clutter at the prediction "
                                    "(gflow_core.dcf.heavytail; 0: the Gaussian)")
    motion_tail_weight: float = param(1.0, "with motion_tail, the prior is (1 - pi) the Gaussian + pi the t, pi this "
                                           "weight (1: the t alone); with motion_tail_rate, the weight it starts at")
    motion_tail_rate: float = param(0.0, "with motion_tail, the t's weight is learnt from the tracked frames' "
                                         "innovations by online EM at this rate (gflow_core.dcf.heavytail; 0: held)")
    target_rate: float = param(0.05, "rate of the running moments of the target's score distribution")
    clutter_rate: float = param(0.05, "rate of the running moments of the clutter's score distribution")
    min_std: float = param(0.02, "floor on the spread of both score distributions")
    prior_target: tuple[float, float] = param((0.55, 0.15), "mean and std of the target's distance rho = 1 - y (y "
                                                            "the filter's response) before any frame")
    prior_clutter: tuple[float, float] = param((0.8, 0.08), "mean and std of the clutter's distance before any frame")
    prior_colour_target: tuple[float, float] = param((0.3, 0.1), "the same of the colour score: the target's ...")
    prior_colour_clutter: tuple[float, float] = param((0.45, 0.1), "... and the clutter's")
    prior_count: int = param(10, "pseudo-samples the two prior distributions count for")
    hidden_after: int = param(3, "frames in a row that clutter explains the estimate before the target is "
                                 "judged hidden")
    reappear: float = param(0.001, "prior probability a frame that a target judged hidden is back")
    search_growth: float = param(0.1, "while the target is unseen its place spreads by this many mean sides a "
                                      "frame (the search covers three standard deviations)")
    search_clutter: bool = param(True, "judge a hidden target's search candidate also against the distances of the "
                                        "search's own best placements on the frames it stayed hidden (TLD's negatives)")
    colour_outlier: float = param(0.01, "probability the colour cue fails: its densities are mixed with a uniform "
                                        "one, so it alone cannot outvote the filter (0: never)", before=0.0)
    search_min: int = param(10, "searches the search's own clutter must hold before it counts (as many as the "
                                "priors' pseudo-samples: a few placements give too narrow a distribution)", before=3)
    coast_velocity: float = param(0.5, "while the target is unseen its velocity decays by this factor a frame")
    search_sizes: int = param(1, "sizes the search for a hidden target may try at most (odd): the held size and, "
                                 "each way, up to (search_sizes - 1) / 2 more, search_size_step apart in log size, "
                                 "within three standard deviations of the size's prior")
    search_size_track: bool = param(False, "with search_sizes, a placement at another size than the held one is "
                                           "never taken on one frame's evidence: only as a candidate track judged "
                                           "over its frames (search_track)")
    search_size_step: float = param(0.2, "log-size step between the sizes the search tries")
    search_size_growth: float = param(0.005, "while the target is unseen the std of its log size grows by this "
                                             "much a frame (the search tries the sizes within three of it)")
    search_size_volume: bool = param(False, "with search_sizes, clutter's place and size are uniform over the volume "
                                            "searched (the areas summed over the sizes times search_size_step); "
                                            "off: the number of sizes is counted twice, once in the area and once "
                                            "in the size's term", before=False)
    search_track: float = param(0.95, "with search_clutter, the search's best placements on the frames a target is "
                                       "hidden are a candidate track, taken as the target when the evidence of all "
                                       "its frames, its scores and its motion as one object, gives it this "
                                       "probability or more (in [0.5, 1); Wald's upper threshold 1 - alpha; a track "
                                       "score, gflow_core.dcf.trackscore; 0: off, each frame judged alone)", before=0.0)
    search_track_wald: bool = param(True, "with search_track, a candidate track is dropped when its score falls to "
                                          "Wald's lower threshold for equal error rates, the upper one mirrored "
                                          "(-(logit(search_track) - logit(reappear))); false: as soon as its score "
                                          "is below 0, the prior's odds", before=False)
    longterm: bool = param(False, "keep a long-term filter beside the adaptive one, learnt only on reliable frames, "
                                  "and search for a hidden target with it (LCT; gflow_core.dcf.longterm)")
    longterm_rate: float = param(0.01, "learning rate of the long-term filter on reliable frames")
    longterm_level: float = param(1.0, "a frame may teach the long-term filter when its distance at the estimate is at "
                                       "most its mean on present frames plus this many standard deviations")
    longterm_witness: bool = param(False, "with longterm, the long-term filter's distance at the estimate is a cue of "
                                         "whether the target is there")
    longterm_outlier: float = param(0.05, "probability the long-term filter's cue fails (its densities mixed with a "
                                          "uniform one, as colour_outlier)")
    search_peaks: int = param(1, "separate placements of each size the search for a hidden target judges (1: its "
                                 "best only; gflow_core.dcf.reacquire)")
    search_truncate: bool = param(False, "judge a search candidate's place by the motion prior conditioned on the "
                                         "region searched (gflow_core.dcf.reacquire)")
    learn_level: float = param(0.0, "a confident frame teaches the filter, colour and scale only when its distance at "
                                    "the estimate is at most the target's mean plus this many standard deviations "
                                    "(0: every confident frame; gflow_core.dcf.gate)")
    search_colour_outlier: float = param(0.1, "probability the colour cue fails on a search candidate, if above "
                                              "colour_outlier: the colour model is learnt against the target's "
                                              "surroundings, not the places the search looks", before=0.0)
    search_refine: bool = param(False, "the search's best placement of each size moved to the best of the 8 half a "
                                       "cell about it, each scored by a window of its own (gflow_core.dcf.model.refine)")
    redetect_speed: bool = param(True, "after the search finds a target judged hidden its velocity is unknown: "
                                       "the next frame's motion prior is widened by the target's typical speed, "
                                       "learnt on the frames it was tracked", before=False)
    augment: float = param(0.0, "weight of warped copies of the first window (rolled, resized, blurred) in the first "
                                "filter's sample (MOSSE, UPDT; gflow_core.dcf.augment; 0: the first window alone)")
    augment_roll: float = param(30.0, "the copies roll the first window by up to this many degrees each way (at a "
                                      "third, two thirds and all of it)")
    augment_scale: float = param(0.1, "the copies resize the first window by exp(+-this) (0: none)")
    augment_blur: float = param(2.0, "a copy blurs the first window by a Gaussian of this sigma, template pixels "
                                     "(0: none)")
    young: float = param(0.0, "while the running filter is young its rate is max(rate, 1 / (young + n + 1)), n the frames "
                              "the target was seen on before: the mean of the frames seen, the first counting for "
                              "this many (gflow_core.dcf.rates; 0: rate from the first frame)")
    confirm: int = param(10, "a new track is tentative until the target's distance distribution has learnt this many "
                             "frames beyond the prior's: until then a frame in doubt is taken as the target's and "
                             "it cannot be judged hidden (gflow_core.dcf.confirm; 0: judged from the first frame)",
                         before=0)
    search_negatives: int = param(0, "with search_clutter, a place the search's best placement fell at on this many "
                                     "frames while the target stayed hidden is remembered, and a candidate there is "
                                     "judged also as that place's clutter (TLD's negatives as places; "
                                     "gflow_core.dcf.negatives; 0: no memory of places)")
    confirm_flow: bool = param(True, "with confirm, a tentative track takes a frame in doubt only when the box's points "
                                     "move coherently from the frame before to where the filter put it (the "
                                     "forward-backward check of Median Flow; gflow_core.dcf.coherence)", before=False)
    roll_step: float = param(10.0, "the target's roll is searched at this many degrees each way of the held one, on a "
                                  "confirmed track's frames where the target looks unusual (roll_gate), and the filter "
                                  "sees the window rolled by it (gflow_core.dcf.rotation; 0: the window stays upright)",
                             before=0.0)
    roll_steps: int = param(1, "rolls tried each way of the held one, roll_step apart")
    roll_max: float = param(60.0, "the target's roll stays within this many degrees of upright")
    roll_reach: int = param(1, "a roll's score is its response's best within this many cells of the window's centre")
    roll_prior: float = param(0.02, "a roll's score is lowered by this times its squared angle (radians): the prior "
                                    "that the target is upright")
    roll_gate: float = param(1.5, "the roll is searched only on a frame whose distance at the estimate exceeds the "
                                  "target's mean by this many standard deviations (0: every present frame)")
    roll_margin: float = param(0.02, "the held roll is kept unless another scores more than this above it (response units)")
    roll_return: bool = param(False, "while the held roll is not upright it is searched on every present frame (the gate "
                                     "holds an upright window only)")
    roll_explain: float = param(2.0, "a new roll is taken only when the held one's distance is above the target's mean "
                                     "plus this many standard deviations and the new one's is within it (the roll "
                                     "explains the unusual look; gflow_core.dcf.rotation.explained; 0: the best roll)",
                                before=0.0)
    roll_relax: float = param(10.0, "with roll_explain, on a frame no roll explains the held roll moves this many degrees "
                                    "towards upright", before=0.0)
    detect_peaks: int = param(1, "the particles drawn at the response are shared among this many separate peaks of it, "
                                 "each half a box from every better one (a boosted particle filter's proposal, "
                                 "Okuma et al. 2004; gflow_core.dcf.proposal; 1: the best peak only)")
    roll_best: bool = param(False, "with roll_explain, the roll is the best scoring of those that explain the frame, the "
                                   "held one among them (by more than roll_margin), not the held one whenever it explains "
                                   "it (gflow_core.dcf.rotation.explained)")
    roll_detect: bool = param(True, "the roll is searched also when the target is detected, before its presence is "
                                    "judged, on frames its score at the response's peak is unusual (roll_gate): a "
                                    "rolled window that explains the look gives the particles their response "
                                    "(SAMF's joint search over the roll; gflow_core.dcf.rotation.detect)", before=False)
    motion_switch: float = param(0.0, "the motion model switches between constant velocity and a manoeuvre (the target "
                                      "turned or stopped: no mean velocity, its speed as the noise) with this "
                                      "probability a frame, the likelihood picking the mode (a mixed-state particle "
                                      "filter, Isard & Blake 1998; gflow_core.dcf.modes; 0: constant velocity only)")
    rate_adapt: float = param(0.0, "the filter's rate rises while the target's distance runs above its mean: "
                                   "max(rate, 1 - (1 - rate) mean / S), S the distance's running mean at this rate "
                                   "(the adaptive Kalman gain of innovation matching; gflow_core.dcf.rates; 0: rate)")
    scale_prior: float = param(0.0, "std of a Gaussian prior on the box's log size about the first box's: the scale "
                                    "filter's pick maximises kappa times its response plus the prior's log-density "
                                    "(gflow_core.dcf.scale.size_posterior; 0: the response's peak alone)")
    colour_names: bool = param(True, "the filter's cells hold the 11 colour names of a colour frame beside fHOG and "
                                     "the intensity (the CN tracker's and CSRT's feature, by prototypes in CIELab; "
                                     "needs colour_weight > 0; gflow_core.dcf.features.colour_names)", before=False)
    verify: float = param(0.0, "a re-detection the search found at another size, or a rolled window at detection, is taken "
                               "only when the first frame's filter scores it within this many standard deviations of its "
                               "distance at the target on confident frames and likelier the target than clutter (TLD's "
                               "conservative similarity; gflow_core.dcf.verify; 0: not checked)")
    camera_motion: bool = param(False, "the camera's own motion from the last frame, a similarity fitted to the "
                                       "background's corners tracked by Lucas-Kanade, moves the prediction, the "
                                       "particles, the size, the velocity and the roll before the frame is weighed "
                                       "(BoT-SORT's camera motion compensation; gflow_core.dcf.camera)")
    segment: float = param(0.0, "the masked filter's support is CSR-DCF's spatial reliability map within the box: the "
                                "cells whose colour posterior (the colour model's histograms times a spatial prior) "
                                "is at least this times its largest on the box, recomputed on every frame the filter "
                                "learns (gflow_core.dcf.reliability; CSRT: 0.5; 0: the box)")
    segment_cover: float = param(0.5, "with segment, a map covering less than this fraction of the box is replaced "
                                      "by the box (CSRT: 0.05)")
    segment_rate: float = param(0.02, "with segment, the filter is solved under the cells where the running average "
                                      "of the maps at this rate is at least 1/2 (the support of CSR-DCF's running "
                                      "average of filters, each solved under its frame's map; 0: this frame's map)")
    segment_grey: bool = param(False, "with segment, grey footage too is segmented, on its 32 grey levels (false: grey "
                                      "footage keeps the box, as CSR-DCF's own code turns segmentation off on grey "
                                      "images)")
    channel_weights: bool = param(False, "each feature channel's response is weighted at detection by CSR-DCF's channel "
                                         "reliability: the largest value of its response on the sample it was learnt from "
                                         "times 1 - min(second peak / first, 1/2) of its response on the frame, averaged at "
                                         "the filter's rate (gflow_core.dcf.channels; false: every channel counts alike)")
    channel_intensity: bool = param(False, "with channel_weights, the intensity channel is weighted too, as CSR-DCF weights "
                                           "every channel (false: it keeps a weight of 1 and the 31 fHOG channels share "
                                           "theirs; its largest response is on another scale than theirs)")
    lookalike_doubt: bool = param(False, "a frame whose best response half a box or more from the estimate is likelier "
                                         "the target's distance than the clutter's (a look-alike beside the target) "
                                         "teaches nothing: the filters, colour model, size, clutter and velocity are not "
                                         "updated from it (LMCF's multimodal response; gflow_core.dcf.lookalike)")
    drift_correct: float = param(0.0, "template update with drift correction (Matthews et al. 2004): on a confident "
                                      "frame the estimate moves to the first frame's filter's peak when that lies "
                                      "within this many sqrt(w h) of it (0: off; gflow_core.dcf.drift)")
    drift_gate: float = param(0.0, "with drift_correct, the first frame's filter's peak is taken only where its distance "
                                   "is within this many standard deviations of the target's under it and likelier the "
                                   "target's than clutter's (its distributions learnt on confident frames, as verify's; "
                                   "0: always)")
    estimate_mode: bool = param(False, "the estimate the model learns at (and the box) is the posterior's mode read on "
                                       "the response map, the maximum of kappa y(x) + log prior(x), not the particles' "
                                       "weighted mean, which carries their Monte Carlo noise into what the model learns "
                                       "(gflow_core.dcf.tracker._mode)")
    estimate_mean: bool = param(False, "the estimate the model learns at (and the box) is the posterior's mean computed "
                                       "over the response map's positions (quadrature), not by the particles' weighted "
                                       "sum: the same MMSE estimate without the sampler's noise "
                                       "(gflow_core.dcf.tracker._map_mean; not with estimate_mode)")
    estimate_learn: bool = param(False, "with estimate_mode, the mode is only where the model learns; the box, the "
                                        "velocity and the judgement of the frame stay at the particles' mean")
    estimate_local: bool = param(False, "with estimate_mode, the mode is the local maximum reached by climbing the map from "
                                        "the particles' mean (a mean-shift step), not the map's global maximum")
    estimate_reach: float = param(0.0, "with estimate_local, the climb's end is the estimate only when it lies within this "
                                       "many of the particles' standard deviations of their mean (each axis; a posterior "
                                       "too broad for its mode to mean much keeps the mean; 0: always)")
    drift_hold: bool = param(False, "with drift_correct, a confident frame whose first-frame peak lies farther "
                                    "teaches the filter nothing (the paper's rule)")

    def __post_init__(self) -> None:
        self._check_sizes()
        if not (math.isfinite(self.mask) and self.mask >= 0) or not self.mu > 0 or self.admm_iterations < 1:
            raise ValueError(f"mask must be >= 0, mu positive and admm_iterations >= 1, got {self.mask}, {self.mu}, "
                             f"{self.admm_iterations}")
        if not (self.lam > 0 and self.scale_lam > 0):
            raise ValueError(f"lam and scale_lam must be positive, got {self.lam}, {self.scale_lam}")
        if not self.label_sigma > 0:
            raise ValueError(f"label_sigma must be positive, got {self.label_sigma}")
        for name in ("rate", "anchor_weight", "colour_weight", "colour_rate", "scale_rate"):
            v = getattr(self, name)
            if not 0 <= v <= 1:
                raise ValueError(f"{name} must be in [0, 1], got {v}")
        if self.scales < 1 or self.scales % 2 == 0:
            raise ValueError(f"scales must be odd and >= 1, got {self.scales}")
        if not self.scale_step > 1:
            raise ValueError(f"scale_step must be > 1, got {self.scale_step}")
        if self.scale_area < 64:
            raise ValueError(f"scale_area must be >= 64 pixels, got {self.scale_area}")
        if not self.max_log_scale > 0:
            raise ValueError(f"max_log_scale must be positive, got {self.max_log_scale}")
        if not self.kappa > 0:
            raise ValueError(f"kappa must be positive, got {self.kappa}")
        if not 0 <= self.detect_fraction < 1:
            raise ValueError(f"detect_fraction must be in [0, 1), got {self.detect_fraction}")
        for name in ("detect_std", "std_xy_rel", "speed_noise", "search_growth", "verify"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"{name} must be finite and >= 0, got {v}")
        if not 0 <= self.coast_velocity <= 1:
            raise ValueError(f"coast_velocity must be in [0, 1], got {self.coast_velocity}")
        if not 0 <= self.velocity_memory < 1:
            raise ValueError(f"velocity_memory must be in [0, 1), got {self.velocity_memory}")
        if not self.motion_prior > 0:
            raise ValueError(f"motion_prior must be positive, got {self.motion_prior}")
        if not (0 < self.target_rate <= 1 and 0 < self.clutter_rate <= 1):
            raise ValueError(f"target_rate and clutter_rate must be in (0, 1], got {self.target_rate}, "
                             f"{self.clutter_rate}")
        if not self.min_std > 0:
            raise ValueError(f"min_std must be positive, got {self.min_std}")
        for name in ("prior_target", "prior_clutter", "prior_colour_target", "prior_colour_clutter"):
            v = getattr(self, name)
            if len(v) != 2 or not all(x > 0 and math.isfinite(x) for x in v):
                raise ValueError(f"{name} must be two positive numbers (mean, std), got {v}")
        if self.prior_count < 1:
            raise ValueError(f"prior_count must be >= 1, got {self.prior_count}")
        if not 0 <= self.search_colour_outlier < 1:
            raise ValueError(f"search_colour_outlier must be in [0, 1), got {self.search_colour_outlier}")
        if not 0 <= self.colour_outlier < 1:
            raise ValueError(f"colour_outlier must be in [0, 1), got {self.colour_outlier}")
        if not (0 < self.longterm_rate <= 1 and 0 <= self.longterm_outlier < 1 and math.isfinite(self.longterm_level)):
            raise ValueError(f"longterm_rate must be in (0, 1], longterm_outlier in [0, 1) and longterm_level finite, "
                             f"got {self.longterm_rate}, {self.longterm_outlier}, {self.longterm_level}")
        if self.search_sizes < 1 or self.search_sizes % 2 == 0 or not (math.isfinite(self.search_size_step)
                                                                     and self.search_size_step > 0):
            raise ValueError(f"search_sizes must be odd and >= 1 and search_size_step positive, got "
                             f"{self.search_sizes}, {self.search_size_step}")
        if not (math.isfinite(self.search_size_growth) and self.search_size_growth >= 0):
            raise ValueError(f"search_size_growth must be finite and >= 0, got {self.search_size_growth}")
        if not (math.isfinite(self.learn_level) and self.learn_level >= 0):
            raise ValueError(f"learn_level must be finite and >= 0, got {self.learn_level}")
        if self.search_peaks < 1:
            raise ValueError(f"search_peaks must be >= 1, got {self.search_peaks}")
        if self.search_min < 1:
            raise ValueError(f"search_min must be >= 1, got {self.search_min}")
        if not (0 <= self.augment <= 1 and 0 <= self.augment_roll <= 90 and math.isfinite(self.augment_scale)
                and 0 <= self.augment_scale <= 1 and math.isfinite(self.augment_blur) and self.augment_blur >= 0):
            raise ValueError(f"augment must be in [0, 1], augment_roll in [0, 90] degrees, augment_scale in [0, 1] and "
                             f"augment_blur finite and >= 0, got {self.augment}, {self.augment_roll}, "
                             f"{self.augment_scale}, {self.augment_blur}")
        if not (math.isfinite(self.young) and self.young >= 0):
            raise ValueError(f"young must be finite and >= 0, got {self.young}")
        if not (self.search_track == 0 or 0.5 <= self.search_track < 1):
            raise ValueError(f"search_track must be 0 (off) or in [0.5, 1), got {self.search_track}")
        if self.search_negatives < 0:
            raise ValueError(f"search_negatives must be >= 0, got {self.search_negatives}")
        if self.confirm < 0:
            raise ValueError(f"confirm must be >= 0, got {self.confirm}")
        if not (math.isfinite(self.roll_step) and 0 <= self.roll_step <= 45 and self.roll_steps >= 1
                and 0 < self.roll_max <= 90 and self.roll_reach >= 0 and math.isfinite(self.roll_prior)
                and self.roll_prior >= 0 and math.isfinite(self.roll_gate) and self.roll_gate >= 0
                and math.isfinite(self.roll_margin) and self.roll_margin >= 0
                and math.isfinite(self.roll_explain) and self.roll_explain >= 0
                and math.isfinite(self.roll_relax) and self.roll_relax >= 0):
            raise ValueError(f"roll_step must be in [0, 45] degrees, roll_steps >= 1, roll_max in (0, 90], roll_reach "
                             f">= 0, roll_prior, roll_gate, roll_margin, roll_explain and roll_relax finite and >= 0, got "
                             f"{self.roll_step}, "
                             f"{self.roll_steps}, {self.roll_max}, {self.roll_reach}, {self.roll_prior}, {self.roll_gate}, "
                             f"{self.roll_margin}, {self.roll_explain}, {self.roll_relax}")
        self._check_motion_size_and_support()
        if self.hidden_after < 1 or not 0 < self.reappear < 1:
            raise ValueError(f"hidden_after must be >= 1 and reappear in (0, 1), got {self.hidden_after}, "
                             f"{self.reappear}")

    def _check_sizes(self) -> None:
        """The cloud's and the window's sizes: ``particles`` >= 1, ``cell`` >= 1, ``padding`` finite and >= 0,
        ``template`` at least 8 cells, and the memory ``particles``, ``template`` and the scale filter's samples
        (``scales`` x ``scale_area``) need within the machine's (:func:`gflow_core.params.check_memory`)."""
        if self.particles < 1:
            raise ValueError(f"particles must be >= 1, got {self.particles}")
        if self.cell < 1:
            raise ValueError(f"cell must be >= 1, got {self.cell}")
        if not (math.isfinite(self.padding) and self.padding >= 0):
            raise ValueError(f"padding must be finite and >= 0, got {self.padding}")
        if self.template < 8 * self.cell:
            raise ValueError(f"template must be at least 8 cells ({8 * self.cell} px), got {self.template}")
        check_memory(self)

    def _check_motion_size_and_support(self) -> None:
        """``detect_peaks`` >= 1, ``motion_switch``, ``motion_fit``, ``motion_tail_rate`` and ``flow_mix`` in [0, 1)
        (``motion_tail`` finite and >= 0, ``motion_tail_weight`` in [0, 1]; not both
        ``flow_mix`` and ``motion_switch``), ``rate_adapt`` a rate in [0, 1],
        ``scale_prior`` (gflow_core.dcf.sizeprior) a std and ``drift_correct``, ``drift_gate`` (gflow_core.dcf.drift):
        finite and >= 0 (0: off), the filter's
        support (:meth:`_check_segment`) and ``channel_weights`` and ``channel_intensity`` bools."""
        self._check_segment()
        for name in ("channel_weights", "channel_intensity"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"{name} must be true or false, got {getattr(self, name)!r}")
        if self.detect_peaks < 1:
            raise ValueError(f"detect_peaks must be >= 1, got {self.detect_peaks}")
        if not 0 <= self.motion_switch < 1:
            raise ValueError(f"motion_switch must be in [0, 1), got {self.motion_switch}")
        if not 0 <= self.motion_fit < 1:
            raise ValueError(f"motion_fit must be in [0, 1), got {self.motion_fit}")
        if not 0 <= self.motion_tail < float("inf"):
            raise ValueError(f"motion_tail must be 0 (a Gaussian prior) or a positive number of degrees of freedom, "
                             f"got {self.motion_tail}")
        if not 0 <= self.motion_tail_weight <= 1:
            raise ValueError(f"motion_tail_weight must be in [0, 1], got {self.motion_tail_weight}")
        if not 0 <= self.motion_tail_rate < 1:
            raise ValueError(f"motion_tail_rate must be in [0, 1), got {self.motion_tail_rate}")
        if self.motion_tail > 0 and (self.motion_switch > 0 or self.flow_mix > 0):
            raise ValueError("motion_tail shapes the one-mode prior; with motion_switch or flow_mix the prior is their "
                             "mixture of Gaussians: set one of them")
        if not 0 <= self.flow_mix < 1:
            raise ValueError(f"flow_mix must be in [0, 1), got {self.flow_mix}")
        if not 0 < self.flow_ratio <= 1:
            raise ValueError(f"flow_ratio must be in (0, 1], got {self.flow_ratio}")
        if self.flow_mix > 0 and self.motion_switch > 0:
            raise ValueError("flow_mix and motion_switch are two uses of one second motion mode: set one of them")
        if not 0 <= self.rate_adapt <= 1:
            raise ValueError(f"rate_adapt must be in [0, 1], got {self.rate_adapt}")
        if not (math.isfinite(self.scale_prior) and self.scale_prior >= 0):
            raise ValueError(f"scale_prior must be finite and >= 0, got {self.scale_prior}")
        for name in ("estimate_local", "estimate_learn"):
            if getattr(self, name) and not self.estimate_mode:
                raise ValueError(f"{name} needs estimate_mode (it changes how the mode is used)")
        if self.estimate_reach > 0 and not self.estimate_local:
            raise ValueError("estimate_reach needs estimate_local (it bounds the climb)")
        if self.estimate_mean and self.estimate_mode:
            raise ValueError("estimate_mean and estimate_mode are two estimates: set one of them")
        for name in ("drift_correct", "drift_gate", "estimate_reach"):
            if not (math.isfinite(getattr(self, name)) and getattr(self, name) >= 0):
                raise ValueError(f"{name} must be finite and >= 0, got {getattr(self, name)}")

    def _check_segment(self) -> None:
        """``segment`` and ``segment_cover`` fractions in [0, 1]; the map needs the masked filter and the colour
        model it is made from (gflow_core.dcf.reliability)."""
        if not (0 <= self.segment <= 1 and 0 <= self.segment_cover <= 1 and 0 <= self.segment_rate <= 1):
            raise ValueError(f"segment, segment_cover and segment_rate must be in [0, 1], got {self.segment}, "
                             f"{self.segment_cover}, {self.segment_rate}")
        if self.segment > 0 and not (self.mask > 0 and self.colour_weight > 0):
            raise ValueError(f"segment needs the masked filter and the colour model (mask and colour_weight > 0), "
                             f"got mask {self.mask}, colour_weight {self.colour_weight}")

    def walk_std(self, box: tuple[float, float, float, float]) -> float:
        """The std (px) of the proposal's random walk of the centre for the initial ``box`` (x, y, w, h):
        ``std_xy_rel * sqrt(w h)`` (w h at least 1 px^2)."""
        return self.std_xy_rel * math.sqrt(max(box[2] * box[3], 1.0))
