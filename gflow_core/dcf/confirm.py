"""A new track is tentative until its own frames outweigh the prior (``confirm``).

The visibility model (:mod:`gflow_core.visibility`) judges the estimate's distance rho = 1 - y against
the target's learnt distance distribution and the clutter's. Before any frame the target's
distribution is a prior of ``prior_count`` pseudo-frames (rho 0.55 +- 0.15); after the user's box and
one or two frames it is still mostly that prior. A target that does not look as the prior guessed --
on tiger1 from frame 55 a toy in fast, blurred motion, whose distance is 0.83-0.89 on frames 3-5
against the prior's 0.55 -- is then judged hidden on its third frame in doubt and never taken back
(``docs/dcf-development.md``): what was tested there was the prior, not the target.

Multi-target trackers keep a new track *tentative* until it is confirmed by its first frames (track
initiation by M of N hits, Blackman & Popoli 1999; SORT's ``min_hits``; DeepSORT's ``n_init``, Wojke
et al. 2017), and judge a confirmed track's misses only. Here the user's box confirms the target's
existence; what its first frames must confirm is the model of how it scores. So while the target's distance distribution has
learnt fewer than ``confirm`` frames beyond the prior's pseudo-frames, a frame in doubt is taken as
the target's: the box follows the estimate and the velocity its motion, the target's distance
distribution and the clutter's learn the frame (so the distribution comes to be the target's own, as
a Bayesian posterior over its mean and spread moves from the prior to the data once the data
outnumber the prior's pseudo-count), and it cannot be judged hidden. The filter, the colour model and
the scale still learn on confident frames only (P(visible) >= 1/2), and the confidence reported is
P(visible) as judged: a tentative frame in doubt says so.

Departures: the trackers cited delete a tentative track that misses (its existence was in doubt);
here existence is given by the user and only the judgement of "hidden" waits. The length measured is
``confirm`` = 10, as many as the priors' pseudo-frames (``prior_count``): the point where the learnt
frames weigh as much as the prior in the distribution's moments.

Evidence beyond the filter's scores (``confirm_flow``, on with ``confirm``): tiger1's blurred toy and
random noise score alike (P(visible) 0.40, 0.31, 0.28 on the toy's frames 3-5; 0.0-0.5 on noise), so a
frame in doubt is taken only when the points of the last frame's box moved coherently to this one
(the forward-backward check of Kalal et al. 2010, :mod:`.coherence`). Noise, which has no motion, and a
flat occluder, which has no texture, are refused and judged as without ``confirm``; without that
evidence the frames in doubt taught the target's distribution the noise's, and noise was reported
``tracked`` at confidence 0.9 by frame 20. The last frame's grey levels are kept in the state
(``last_grey``) while the track is tentative.

Off by default (0): the frames in doubt teach a wide distribution (tiger1's toy 0.73 +- 0.12), which a
still occluder later fits (jumping's ``occlude-150`` on seed 3, tiger1's ``occlude-25``); the flow
check does not change that, since a blurred target that moves is what it takes
(``docs/dcf-development.md``, "A new track tentative for its first frames" and "Evidence that the box
moved").
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..visibility import ChiSquare
from .coherence import coherent, flow
from .params import DCFParams
from .state import DCFObservation, DCFState

__all__ = ["tentative", "taken", "remember"]


def tentative(target: ChiSquare, p: DCFParams) -> bool:
    """Whether the track is still tentative: its distance distribution ``target`` (whose ``n`` counts the
    prior's ``prior_count`` pseudo-frames and the frames the target was taken as present on) has learnt
    fewer than ``p.confirm`` frames of its own (module docstring); never with ``confirm`` 0."""
    return target.n - p.prior_count < p.confirm


def _grey8(obs: DCFObservation) -> np.ndarray:
    """The frame's grey levels as (H, W) uint8 (what Lucas-Kanade reads)."""
    return np.clip(np.rint(obs.grey), 0, 255).astype(np.uint8)


def taken(st: DCFState, obs: DCFObservation, p: DCFParams) -> bool:
    """Whether a frame in doubt is taken as the target's: only while the track is tentative, and with
    ``confirm_flow`` only when the points of the last frame's box moved coherently to this frame
    (:func:`.coherence.coherent`): noise, which has no motion, and a flat occluder, which has no texture,
    are refused and judged as the visibility model says."""
    if not tentative(st.target, p):
        return False
    if not p.confirm_flow:
        return True
    if st.last_grey is None or st.last_grey.shape != obs.grey.shape:
        return False
    s = float(np.exp(st.log_s))
    size = (st.geom.size0[0] * s, st.geom.size0[1] * s)
    box = (float(st.centre[0] - (size[0] - 1) / 2.0), float(st.centre[1] - (size[1] - 1) / 2.0), size[0], size[1])
    return coherent(flow(st.last_grey, _grey8(obs), box))


def remember(target: ChiSquare, obs: DCFObservation, p: DCFParams) -> Any:
    """The frame's grey levels for the next frame's flow while the track (whose target distribution is now
    ``target``) is still tentative and ``confirm_flow`` asks for it; None otherwise."""
    return _grey8(obs) if p.confirm_flow and tentative(target, p) else None
