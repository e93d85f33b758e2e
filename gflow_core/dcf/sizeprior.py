"""The scale filter's pick under a prior on the target's size (``scale_prior``).

DSST takes the peak of its 1-D scale filter's response (Danelljan et al., BMVC 2014, sec. 3.2). Its
response is broad over the 17 scales 2 % apart: neighbouring sizes often score within a few percent
of each other, and the peak's side decides each step. On twinnings and tiger1 such steps took the box
to 1.3-1.55 times its first size; the frozen first-frame filter and a pixel check agree that the
target itself looked that much larger, while those labels keep one size (docs/dcf-development.md), so
the prior trades the targets that change size for the labels that do not. Here the response is read
as a likelihood over the target's log size, p(z | s) ~ exp(kappa y) (as the particles read the
translation response), and a Gaussian prior log s ~ N(0, ``scale_prior``^2) on the size relative to the first
box joins it; the pick is the posterior's mode (:func:`.scale.size_posterior`).

Departures: DSST and fDSST have no prior on the size; the prior here is the one chamfer places on
log s (``scale_prior`` there), and as a likelihood term, not a bound: a clear preference of the
response still moves the box (``max_log_scale`` remains the bound).
"""

from __future__ import annotations

import numpy as np

from .model import Geometry, TargetModel, scale_anchor
from .params import DCFParams
from .scale import detect_scale

__all__ = ["scale_change"]


def scale_change(model: TargetModel, grey: np.ndarray, centre: tuple[float, float], log_s: float, geom: Geometry,
                 p: DCFParams) -> float:
    """The log-scale change the scale filter picks at ``centre`` for a box of log size ``log_s`` (relative to
    the first box) under the prior of std ``p.scale_prior`` (0 without a scale filter)."""
    if model.scale is None:
        return 0.0
    s = float(np.exp(log_s))
    d, _ = detect_scale(model.scale, grey, centre, (geom.size0[0] * s, geom.size0[1] * s), p.scale_step, p.cell,
                        p.scale_lam, prior=(log_s, p.scale_prior, p.kappa), anchor=scale_anchor(p), refine=p.scale_refine)
    return d
