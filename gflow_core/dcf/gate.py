"""Which frames may teach the adaptive model: updates gated by how well the target was seen.

A correlation filter learns every frame it is told the target is there, so an occluder that comes in
slowly (a patch sweeping across the target, another skater passing in front) is learnt a little a
frame until the filter is a filter of the occluder and follows it away: on the stress benchmark's
skating1 ``sweep-40`` (seed 1) the target's learnt distance drifted from 0.66 to 0.78 as the patch
came in, the estimate stayed "confident", and the box left with the patch. The learnt distance
follows the target on every present frame (so a lasting change of look becomes the usual look), so
the confidence of :mod:`gflow_core.visibility` cannot by itself refuse such frames.

The trackers that survive this gate their update on the quality of the frame's response: MOSSE's
peak-to-sidelobe ratio (Bolme et al. CVPR 2010, sec. 3.5), LMCF's peak and APCE against their
historical means (Wang, Liu & Huang CVPR 2017, sec. 3.3), LCT's threshold on the long-term filter's
peak (Ma et al. CVPR 2015, sec. 3.3). Here the historical distribution is the one the tracker
already keeps -- the target's distance rho = 1 - y on present frames -- and a frame teaches the
filter, the colour model and the scale filter only when its distance is within ``learn_level``
standard deviations above that distribution's mean (judged before the frame counts), the rule
:func:`.longterm.reliable` applies to the long-term filter.

Departure: the papers' gates are fixed fractions of a historical mean of the peak; this one is a level
of the learnt distribution's spread, so a target whose response is noisy from the start is not
refused more often than a steady one.
"""

from __future__ import annotations

import math

from ..visibility import ChiSquare

__all__ = ["within"]


def within(d: ChiSquare, rho: float, level: float, min_std: float) -> bool:
    """Whether the distance ``rho`` is at most the mean of ``d`` plus ``level`` of its standard deviations
    (the deviation at least ``min_std``)."""
    var = max(d.m2 - d.m1 * d.m1, min_std * min_std)
    # rho <= E[rho] + level sd[rho]
    return rho <= d.mean() + level * math.sqrt(var)
