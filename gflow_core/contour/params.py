"""The contour trackers' parameters: :class:`ChamferParams` and :class:`M2Params`, the only place their
defaults live, over :class:`ContourParams`, the filter's.

The filter is :mod:`gflow_core.contour.tracker` (Toyama & Blake, IJCV 2002, with the departures
listed there). Each tracker's stages (``chamfer.proposal`` / ``chamfer.filter``, ``m2.proposal`` /
``m2.filter``: ``stages/particle_proposal.py``, ``stages/particle_filter.py``) take every field of
its dataclass, so the graph files (``pipeline/graphs/chamfer.yaml``, ``m2.yaml``) name none and are
validated against it; ``gflow track``'s ``--particles``, ``gflow info chamfer`` / ``gflow info m2``
and the help derive from it. The generic stages ``particle.proposal`` / ``particle.filter`` (graphs
of your own, ``gflow demo``) take :class:`ContourParams` and the random walk's deviations.

This module imports no mathematics, so the command line reads it at no cost.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

from ..params import Memory, check_memory, param

__all__ = ["ContourParams", "ChamferParams", "M2Params", "EdgeParams", "BOX_POLICIES"]

#: how the estimate's box is made from the MAP state with a learned model
BOX_POLICIES = ("reference", "exemplar")


@dataclass(frozen=True)
class ContourParams:
    """Every setting of the contour particle filter. Each field's help text is in its declaration.
    Raises ``ValueError`` naming the first parameter it refuses."""

    # memory: the peak resident memory of `gflow track caviar1 --tracker chamfer --inline --stop 4` grows by 449
    # bytes a particle (--particles 1e6 to 2e6), 2026-12-05
    particles: int = param(500, "number of particles N", memory=Memory(440, "particle"))
    lam: float = param(0.5, "lambda of the K = 1 chamfer likelihood exp(-lambda rho) (no learned model)")
    max_points: int = param(200, "template points kept from the edges inside the box (no learned model)")
    init_spread: tuple[float, float, float, float] = param((2.0, 2.0, 0.01, 0.01), "std of (ux, uy, theta, log s) "
                                                                                   "of the initial cloud")
    min_edges: int = param(1, "a frame with fewer edge pixels is blank: no evidence, the particles coast on the "
                              "dynamics (sec. 5.1.2)")
    appearance: bool = param(True, "with a learned model that has appearance exemplars, multiply the chamfer kernel "
                                   "by the appearance kernel")
    online: int = param(6, "bound of the online appearance exemplar bank (0: no online exemplars)")
    online_every: int = param(5, "at most one online exemplar added every this many frames")
    confident_r: float = param(0.6, "the estimate is confident (its region may become an online exemplar) when its "
                                    "appearance correlation with the nearest exemplar is at least this")
    calibrate: bool = param(True, "widen the learned kernels so the initial box is a typical match on frame 0")
    scale_prior: float = param(0.0, "std of a prior N(0, .) on log s of the K = 1 chamfer tracker (0: none)")
    lost_guard: bool = param(True, "verify the estimate against the initial box and hold, search and re-detect a "
                                   "lost target (false: the paper's filter)")
    lost_window: float = param(1.5, "half-width of the hold window and of the first re-detection window, in box "
                                    "sizes")
    lost_growth: float = param(0.1, "the re-detection window widens by this many box sizes a lost frame")
    lost_scales: tuple[float, ...] = param((1.0,), "sizes (multiples of the held size) searched when re-detecting "
                                                   "(1.0 first)")
    lost_colour: bool = param(True, "the lost guard weighs the box's colour histogram too, against the initial "
                                    "box's (on colour frames; gflow_core.m2.lost)")
    fit_shape: bool = param(True, "stretch a learned model's item frame to the initial box's aspect ratio")
    box: str = param("reference", "the estimate's box with a learned model: reference (the reference box under "
                                  "alpha) or exemplar (bounding box of T_alpha x~_k)")

    def __post_init__(self) -> None:
        if not self.lost_window > 0 or self.lost_growth < 0 or not self.lost_scales or min(self.lost_scales) <= 0:
            raise ValueError(f"lost_window must be positive, lost_growth >= 0 and lost_scales positive, got "
                             f"{self.lost_window}, {self.lost_growth}, {self.lost_scales}")
        if self.online < 0 or self.online_every < 1:
            raise ValueError(f"online must be >= 0 and online_every >= 1, got {self.online}, {self.online_every}")
        if not -1.0 <= self.confident_r <= 1.0:
            raise ValueError(f"confident_r must be a correlation in [-1, 1], got {self.confident_r}")
        if self.particles < 1:
            raise ValueError(f"particles must be >= 1, got {self.particles}")
        if not self.lam > 0:
            raise ValueError(f"lam must be positive, got {self.lam}")
        if self.min_edges < 0:
            raise ValueError(f"min_edges must be >= 0, got {self.min_edges}")
        if self.box not in BOX_POLICIES:
            raise ValueError(f"box must be 'reference' or 'exemplar', got {self.box!r}")
        if not (math.isfinite(self.scale_prior) and self.scale_prior >= 0):
            raise ValueError(f"scale_prior must be finite and >= 0, got {self.scale_prior}")
        check_memory(self)


@dataclass(frozen=True)
class ChamferParams(ContourParams):
    """The chamfer tracker (M2 with K = 1, the template from the edges inside the initial box): the
    filter's settings with the chamfer tracker's values, and the proposal's random walk (M2 sec. 4.3,
    A = I) on beta = (ux, uy, theta, log s)."""

    lam: float = param(0.2, "lambda of the chamfer likelihood exp(-lambda rho)")
    scale_prior: float = param(0.3, "std of a prior N(0, .) on log s (0: none; the directed chamfer distance alone "
                                    "favours a template shrunk onto dense edges)")
    std_xy: float = param(1.5, "random walk of the centre per frame, px")
    std_theta: float = param(0.02, "random walk of the angle per frame, radians")
    std_log_s: float = param(0.02, "random walk of log s per frame")
    template_every: int = param(5, "take the template again (with drift correction) after this many frames in a row "
                                   "judged found (0: the first box's template throughout)")
    template_gain: float = param(5.0, "the template is taken again only where the first template fits the target "
                                      "this many times worse than on the first template_every frames")
    template_drift: float = param(0.2, "epsilon of the drift correction: the first template, aligned again from the "
                                        "estimate, must land within this many box sizes of it")
    template_reach: float = param(0.25, "the first template is aligned again over translations within this many box "
                                        "sizes of the estimate")
    template_scale: float = param(0.0, "the first template is aligned again at log s changed by this much too, and the "
                                        "template is kept where it fits better at another size (0: size not checked)")
    lost_follow: bool = param(True, "while the lost guard holds the last found box, report the filter's estimate "
                                    "(kept within the hold window) where the template still fits the edges there, "
                                    "within template_gain times its fit on the first frames (false: the last found box)")
    template_anchor: bool = param(True, "the lost guard's anchor is taken again with the template (where the first "
                                        "anchor agrees as well)")

    def __post_init__(self) -> None:
        super().__post_init__()
        positive = (self.template_drift, self.template_reach, self.template_gain)
        if self.template_every < 0 or not (math.isfinite(self.template_scale) and self.template_scale >= 0) or \
                not all(math.isfinite(v) and v > 0 for v in positive):
            raise ValueError(f"template_every and template_scale must be >= 0, template_gain, template_drift and "
                             f"template_reach positive, got {self.template_every}, {self.template_scale}, "
                             f"{self.template_gain}, {self.template_drift}, {self.template_reach}")
        if not all(math.isfinite(v) and v >= 0 for v in (self.std_xy, self.std_theta, self.std_log_s)):
            raise ValueError(f"std_xy, std_theta and std_log_s must be finite and >= 0, got {self.std_xy}, "
                             f"{self.std_theta}, {self.std_log_s}")


@dataclass(frozen=True)
class M2Params(ContourParams):
    """The M2 tracker with a learned contour model (``gflow learn m2``): the filter's settings with the
    values chosen on all four shared sequences at once (docs/accuracy.md, m2). The proposal's dynamics
    are the model's (its Markov matrix and AR(1) process)."""

    init_spread: tuple[float, float, float, float] = param((2.0, 2.0, 0.01, 0.02), "std of (ux, uy, theta, log s) "
                                                                                   "of the initial cloud")
    online: int = param(12, "bound of the online appearance exemplar bank (0: no online exemplars)")
    confident_r: float = param(0.5, "the estimate is confident (its region may become an online exemplar) when its "
                                    "appearance correlation with the nearest exemplar is at least this")
    lost_window: float = param(2.5, "half-width of the hold window and of the first re-detection window, in box "
                                    "sizes")
    lost_scales: tuple[float, ...] = param((1.0, 0.93, 1.07), "sizes (multiples of the held size) searched when "
                                                              "re-detecting (1.0 first)")


@dataclass(frozen=True)
class EdgeParams:
    """What the contour trackers read of a frame: the Canny edges and their chamfer image (the
    preprocess stage's settings; the defaults are the ``chamfer`` graph's). An M2 model brings its
    own (:func:`gflow_core.contour.protocol.m2_edge_params`)."""

    profile: Literal["quadratic", "truncated", "linear"] = param("truncated", "chamfer profile g(u): quadratic u^2, "
                                                                              "truncated min(u^2, g0), linear u")
    g0: float = param(100.0, "truncation level of the truncated profile, squared pixels")
    canny_low: float | None = param(None, "fixed low Canny threshold (None, with canny_high: calibrated on the "
                                          "initial box in the first frame)")
    canny_high: float | None = param(None, "fixed high Canny threshold")
    canny_percentile: float = param(80.0, "percentile of the gradient magnitude in the box that calibrates the "
                                          "high threshold")
    blur: float = param(1.0, "std of the Gaussian pre-blur, px (0: none)")
    match_resolution: bool = param(False, "compute the edges and the chamfer image on the frame resampled by "
                                          "model_scale (an image pyramid's level), so a target larger than a learned "
                                          "model's training targets is matched at the model's resolution")
    model_scale: float = param(1.0, "a learned model's reference size over the tracked target's first box where the "
                                    "target is larger than the model's largest training target, else 1 (gflow track "
                                    "--tracker m2 sets it from the model file and --init)")

    def __post_init__(self) -> None:
        if not (math.isfinite(self.model_scale) and self.model_scale > 0):
            raise ValueError(f"model_scale must be finite and positive, got {self.model_scale}")

    @property
    def resample(self) -> float:
        """The factor the frame is resampled by before its edges are read (1: none)."""
        return self.model_scale if self.match_resolution else 1.0
