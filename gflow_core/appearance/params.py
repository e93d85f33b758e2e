"""The appearance tracker's parameters: :class:`AppearanceParams`, the only place their defaults live.

The tracker is :mod:`gflow_core.appearance.filter` (M2 with online exemplars;
its docstring gives each parameter's role and the measurements behind the defaults, chosen on
all four shared sequences together). Everything else derives from this dataclass: the stages'
parameter structs (``stages/spec_box.py``), the
validation of ``pipeline/graphs/appearance.yaml``, ``gflow track``'s options and their help,
``gflow info appearance`` and the keywords of ``gflow.Tracker("appearance", ...)``.

Two presets name other settings in one place (``gflow track --track-scale`` / ``--fixed-size``):

* :data:`TRACK_SCALE` -- scale in the particle state (3 observed scales, a random walk on
  log s) instead of the scale search at the peak;
* :data:`FIXED_SIZE` -- the box keeps the size of the initial box.

This module imports no mathematics, so the command line reads it at no cost.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any, Mapping

from ..params import Memory, check_memory, param

__all__ = ["AppearanceParams", "TRACK_SCALE", "FIXED_SIZE"]


@dataclass(frozen=True)
class AppearanceParams:
    """Every setting of the appearance tracker, with the shipped defaults (chosen on all four shared
    sequences together). Each field's help text is in its declaration; ``gflow info appearance``
    prints them all. Raises ``ValueError`` naming the first parameter it refuses."""

    # memory: the peak resident memory of `gflow track caviar1 --tracker appearance --inline --stop 4` grows by 397
    # bytes a particle (--particles 1e6 to 2e6), 2026-12-05
    particles: int = param(300, "number of particles N", option="--particles", memory=Memory(390, "particle"))
    lam: float = param(30.0, "lambda = 1 / (2 sigma^2) of the likelihood exp(-lambda rho) (eq. 7)")
    max_area: int = param(1000, "exemplar resolution: at most this many pixels")
    update_rate: float = param(0.02, "rate of the running exemplar's update on every frame the target is present")
    n_scales: int = param(1, "scales observed per frame (1: the scale is searched at the peak, or fixed; 3: scale "
                             "in the particle state)")
    scale_step: float = param(0.03, "log-scale spacing of the observed scales")
    std_log_s: float = param(0.0, "random walk of log s per frame (0.01 with n_scales = 3)")
    detect_fraction: float = param(0.3, "fraction of the particles drawn at the peak of the response")
    detect_std: float = param(1.0, "spread of the particles drawn at the response peak, px")
    motion_prior: float = param(1.0, "std of the motion prior about the prediction, in box sizes")
    search: float = param(0.8, "search margin around the prediction, in box sizes, plus 2 |v| + 10 px")
    velocity_memory: float = param(0.5, "m of the velocity v <- m v + (1 - m) (c_t - c_{t-1})")
    hidden_prior: float = param(0.2, "std of the motion prior while the target is judged hidden, in box sizes ...")
    hidden_speed: float = param(1.0, "... plus this many times the speed |v| (px / frame) the target had")
    scale_from_recent: bool = param(True, "with n_scales = 3: the scale weighed by the running exemplar alone")
    adapt_max: float = param(3.0, "the running exemplar learns up to this many times faster while r's level is low")
    slow_rate: float = param(0.005, "rate of the slow running exemplar, on confident frames (0: none)")
    max_log_scale: float = param(1.3862943611198906, "bound on |log s|: the box stays within [1/4, 4] times its "
                                                     "first size")
    scale_search: int = param(3, "J: after the position, scale searched at 2J + 1 log-scales (0: off)")
    scale_search_step: float = param(0.02, "log-scale spacing of the searched scales")
    scale_change_std: float = param(0.05, "prior on the log-scale change per frame: N(0, std^2)")
    scale_anchor_weight: float = param(0.7, "weight of the anchor in the scale score (the rest: the running "
                                            "exemplars)")
    scale_lam: float = param(30.0, "lambda of the scale score")
    scale_refine: int = param(2, "translation freedom (exemplar pixels) at each searched scale")
    scale_gain: float = param(1.0, "log s <- log s + gain * (searched change)")
    refine_position: bool = param(True, "move the centre to the refined peak at the chosen scale")
    scale_consistency: float = param(1.0, "a scale change is kept only if neither the anchor's nor the running "
                                          "exemplars' r falls by more than this")
    scale_min_score: float = param(0.7, "scale searched only while r >= this (an absolute confidence)")
    scale_gate: float = param(1.0, "scale searched only while r >= its running level - scale_gate")
    warmup: int = param(5, "frames after the first on which a target judged present is taken as confident (its "
                           "distribution is learnt)")
    min_std: float = param(0.05, "floor on the spread of rho in the target's and the clutter's distributions")
    target_rate: float = param(0.05, "forgetting rate of the target's distance moments (frames it is present)")
    clutter_rate: float = param(0.05, "forgetting rate of the clutter's distance moments (frames the target is "
                                      "present)")
    clutter_while_hidden: bool = param(False, "learn the clutter's moments on frames the target is in doubt or "
                                              "hidden too (the best match away from a held box may be the target)")
    search_start: float = param(1.0, "the search for a target in doubt starts this many box sizes beyond the "
                                     "window ...")
    search_growth: float = param(0.1, "... and widens by this many box sizes a frame")
    search_scales: tuple[float, ...] = param((0.0, -0.15, 0.15), "log-sizes searched for a hidden target (0 "
                                                                 "first)")
    search_area: int = param(150, "exemplar pixels of the coarse pass of that search")
    hidden_after: int = param(3, "frames in a row that clutter explains the estimate before the target is judged "
                                 "hidden")
    reappear: float = param(0.001, "prior probability a frame that a target judged hidden is back")
    hidden_filter: bool = param(True, "while the target is hidden, carry the probability it is present from "
                                      "frame to frame (forward filtering) instead of the prior `reappear` alone, "
                                      "so frames of moderate evidence add up")
    colour: bool = param(True, "weigh the colour histogram of the box as a second cue, with its own target and "
                               "clutter distributions, and search a hidden target by colour too")
    colour_lam: float = param(20.0, "lambda_c of the colour likelihood exp(-lambda_c (1 - BC)) (Perez et al. 2002); "
                                    "0: colour only judges the estimate and searches")
    colour_rate: float = param(0.02, "rate of the running colour histogram's update on confident frames")
    std_xy_rel: float = param(0.08, "random walk of the centre per frame (the proposal), in units of sqrt(w h) of "
                                    "the initial box")

    def __post_init__(self) -> None:
        if self.particles < 1:
            raise ValueError(f"particles must be >= 1, got {self.particles}")
        if not self.lam > 0:
            raise ValueError(f"lam must be positive, got {self.lam}")
        if self.n_scales < 1 or self.n_scales % 2 == 0:
            raise ValueError(f"n_scales must be odd and >= 1, got {self.n_scales}")
        if not 0 <= self.detect_fraction < 1:
            raise ValueError(f"detect_fraction must be in [0, 1), got {self.detect_fraction}")
        if not 0 <= self.update_rate <= 1:
            raise ValueError(f"update_rate must be in [0, 1], got {self.update_rate}")
        if not 0 <= self.slow_rate <= 1:
            raise ValueError(f"slow_rate must be in [0, 1], got {self.slow_rate}")
        if not self.adapt_max >= 1:
            raise ValueError(f"adapt_max must be >= 1, got {self.adapt_max}")
        if self.scale_search < 0 or self.scale_refine < 0:
            raise ValueError(f"scale_search and scale_refine must be >= 0, got {self.scale_search}, {self.scale_refine}")
        if not 0 <= self.scale_anchor_weight <= 1:
            raise ValueError(f"scale_anchor_weight must be in [0, 1], got {self.scale_anchor_weight}")
        if not (self.scale_search_step > 0 and self.scale_change_std > 0 and self.scale_lam > 0):
            raise ValueError("scale_search_step, scale_change_std and scale_lam must be positive")
        if not (self.hidden_prior > 0 and self.hidden_speed >= 0):
            raise ValueError(f"hidden_prior must be positive and hidden_speed >= 0, got {self.hidden_prior}, {self.hidden_speed}")
        if self.warmup < 1 or not self.min_std > 0 or not (0 < self.target_rate <= 1 and 0 < self.clutter_rate <= 1):
            raise ValueError(f"warmup must be >= 1, min_std positive and the rates in (0, 1], got {self.warmup}, "
                             f"{self.min_std}, {self.target_rate}, {self.clutter_rate}")
        if not self.colour_lam >= 0:
            raise ValueError(f"colour_lam must be >= 0, got {self.colour_lam}")
        if not 0 <= self.colour_rate <= 1:
            raise ValueError(f"colour_rate must be in [0, 1], got {self.colour_rate}")
        if self.hidden_after < 1 or not 0 < self.reappear < 1:
            raise ValueError(f"hidden_after must be >= 1 and reappear in (0, 1), got {self.hidden_after}, {self.reappear}")
        if self.search_growth < 0 or not self.search_scales or self.search_area < 16:
            raise ValueError(f"search_growth must be >= 0, search_scales not empty and search_area >= 16, got "
                             f"{self.search_growth}, {self.search_scales}, {self.search_area}")
        if not (math.isfinite(self.std_xy_rel) and self.std_xy_rel >= 0):
            raise ValueError(f"std_xy_rel must be finite and >= 0, got {self.std_xy_rel}")
        if self.max_area < 36:
            raise ValueError(f"max_area must be >= 36 pixels, got {self.max_area}")
        check_memory(self)

    def walk_std(self, box: tuple[float, float, float, float]) -> float:
        """The std (px) of the proposal's random walk of the centre for the initial ``box`` (x, y, w, h):
        ``std_xy_rel * sqrt(w h)`` (w h at least 1 px^2)."""
        return self.std_xy_rel * math.sqrt(max(box[2] * box[3], 1.0))


#: scale in the particle state (``gflow track --track-scale``)
TRACK_SCALE: Mapping[str, Any] = MappingProxyType({"n_scales": 3, "std_log_s": 0.01, "scale_search": 0})
#: the box keeps the size of the initial box (``gflow track --fixed-size``)
FIXED_SIZE: Mapping[str, Any] = MappingProxyType({"scale_search": 0})
