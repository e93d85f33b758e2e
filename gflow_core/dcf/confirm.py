"""A new track is tentative until its own frames outweigh the prior (``confirm``).

The visibility model (:mod:`gflow_core.visibility`) judges the estimate's distance rho = 1 - y against
the target's learnt distance distribution and the clutter's. Before any frame the target's
distribution is a prior of ``prior_count`` pseudo-frames (rho 0.55 +- 0.15); after the user's box and
one or two frames it is still mostly that prior. A target that does not look as the prior guessed --
on tiger1 from frame 55 a toy in fast, blurred motion, whose distance is 0.83-0.89 on frames 3-5
against the prior's 0.55 -- is then judged hidden on its third frame in doubt and never taken back
(``docs/trackers.md``): what was tested there was the prior, not the target.

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

Off by default (0): the frames in doubt teach a wide distribution (tiger1's toy 0.73 +- 0.12), which a
still occluder later fits, a target hidden during its first frames is learnt as the target, and
on frames of random noise the frames in doubt teach the target's distribution the noise's, so noise
is reported ``tracked`` at confidence 0.9 by frame 20
(``docs/trackers.md``, dcf, "A new track tentative for its first frames").
"""

from __future__ import annotations

from ..visibility import ChiSquare
from .params import DCFParams

__all__ = ["tentative"]


def tentative(target: ChiSquare, p: DCFParams) -> bool:
    """Whether the track is still tentative: its distance distribution ``target`` (whose ``n`` counts the
    prior's ``prior_count`` pseudo-frames and the frames the target was taken as present on) has learnt
    fewer than ``p.confirm`` frames of its own (module docstring); never with ``confirm`` 0."""
    return target.n - p.prior_count < p.confirm
