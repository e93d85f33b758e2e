"""A long-term correlation filter kept beside the adaptive one (``longterm``), in the manner of LCT.

Ma, Yang, Zhang & Yang (LCT, CVPR 2015, sec. 3.2-3.3) keep two filters: the translation filter,
learnt on every frame, and a long-term "appearance" filter learnt only on frames whose response
peak is above a threshold (their T_a). The second filter changes slowly and only on frames where
the target is clearly itself, so it is what the tracker trusts when it must say whether it still
holds the target (their detection confidence, the peak of that filter), and it is the template
that an online detector looks for over the frame once the tracker has lost the target.

Here, beside the adaptive filter of :mod:`.model`:

* the long-term filter is solved as the adaptive one is (:func:`.model.learn`, the same window,
  features and mask), from the first frame's sample, and then learnt at ``longterm_rate`` on frames
  that the tracker judges present and confident *and* on which the long-term filter itself scores
  the estimate as it usually scores the target: its distance rho_lt = 1 - y_lt at the estimate no
  more than ``longterm_level`` standard deviations above its running mean on present frames (LCT's
  fixed T_a on the peak, here a level learnt from the run);
* its distance at the estimate is a third cue of the visibility judgement, the detection
  confidence's witness (``longterm_witness``), with its own learnt target and clutter distributions
  (the clutter's from its best response half a box away, as the adaptive filter's), mixed with an
  outlier density of weight ``longterm_outlier`` (:mod:`.cues`) because it shares its features with
  the adaptive filter and may not be counted as wholly independent evidence;
* while the target is hidden, the search slides the long-term filter over the area searched after
  the adaptive one (:func:`.model.search` on :func:`view`), and its candidate is accepted by the
  likelihood ratio of its long-term distance under the long-term target's distribution against the
  clutter the window showed (the best of as many draws as both searches covered) and the search's
  own best long-term placements while the target stayed hidden (``search_clutter``), with the
  colour score and the place term as before. The adaptive filter alone took jumping's face back
  within a few frames after a blur where the long-term one alone took thirty: it follows a target
  that changes fast; the long-term one keeps the look a drifting or polluted filter has lost.

Departures from LCT: LCT's re-detector is a random-fern classifier trained on the tracker's
positives and negatives, and its confidence threshold T_r and update threshold T_a are fixed; here
the re-detector is the long-term filter slid over the region, and both decisions are likelihood
ratios and levels learnt from the run. LCT's long-term filter is on HOG of the target alone (no
padding); here it shares the adaptive filter's window and mask.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..visibility import ChiSquare
from . import filter as cf
from .gate import within
from .model import Geometry, TargetModel, learn
from .params import DCFParams

__all__ = ["LongTerm", "init_longterm", "view", "reliable", "learn_longterm"]


@dataclass(frozen=True)
class LongTerm:
    """The long-term filter and what the run has shown of its scores.

    train : its running average (as :class:`.model.TargetModel`'s); det : its detection filter,
        (hc, wc // 2 + 1, C) complex; target : distribution of its distance rho_lt = 1 - y_lt at the
        estimate on frames the target was present; clutter : of its best distance half a box away or
        more on those frames; sclutter : of the search's best placement while the target stayed hidden
        (empty while it is seen); updates : frames it has learnt on after the first.
    """

    train: cf.Spectrum | np.ndarray
    det: np.ndarray
    target: ChiSquare
    clutter: ChiSquare
    sclutter: ChiSquare = ChiSquare()
    updates: int = 0


def init_longterm(model: TargetModel, target: ChiSquare, clutter: ChiSquare) -> LongTerm:
    """The long-term filter of the first frame's model (its running average and filter), with the prior
    distributions ``target`` and ``clutter`` of its distance."""
    return LongTerm(model.train, model.det, target, clutter)


def view(model: TargetModel, lt: LongTerm) -> TargetModel:
    """``model`` with the long-term filter as its detection filter (its own anchor, so the anchor's
    weight leaves it as it is), the adaptive model's colour histograms and scale filter; unweighted by the
    adaptive filter's channel weights (``channel_weights``, :mod:`.channels`)."""
    return replace(model, train=lt.train, det=lt.det, anchor=lt.det, channels=None)


def reliable(lt: LongTerm, rho: float, p: DCFParams) -> bool:
    """Whether a present, confident frame whose long-term distance at the estimate is ``rho`` may teach
    the long-term filter: rho at most the mean of that distance on present frames plus ``longterm_level``
    of its standard deviations (LCT's fixed T_a on the peak, here a level learnt from the run)."""
    return within(lt.target, rho, p.longterm_level, p.min_std)


def learn_longterm(lt: LongTerm, model: TargetModel, image: np.ndarray, grey: np.ndarray,
                   centre: tuple[float, float], log_s: float, geom: Geometry, p: DCFParams) -> LongTerm:
    """The long-term filter after the sample of the box at ``centre``, scale exp(``log_s``), at
    ``longterm_rate`` (:func:`.model.learn` on :func:`view`; the colour and scale it returns are the
    adaptive model's concern and are dropped)."""
    q = replace(p, colour_rate=0.0)
    m = learn(view(model, lt), image, grey, centre, log_s, geom, q, p.longterm_rate, scale=False)
    return replace(lt, train=m.train, det=m.det, updates=lt.updates + 1)
