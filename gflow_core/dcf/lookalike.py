"""A look-alike beside the target: the frame teaches nothing (``lookalike_doubt``).

The filter's response has one peak where the target is alone. Where a second object scores as the
target does -- another skater, a copy of the target walking past -- the response has two, and the
particle filter follows whichever the likelihood and the motion prior favour on that frame: when the
look-alike passes in front, the estimate and the velocity take up its pace and the filter leaves with
it (the stress case ``distract-40``), while every frame is judged present, since the estimate does
look like the target. Wang, Liu & Huang's LMCF (CVPR 2017) reads such a multimodal response as
unreliable and does not update its model on it. Here the second mode is judged as the estimate is,
by the learnt distributions of :mod:`gflow_core.visibility`: the best response half a box or more from
the estimate (the sample the clutter's distribution learns from on present frames) is a look-alike
when its distance ``rho = 1 - y`` is likelier under the target's distribution than the clutter's,

    log p(rho | target) > log p(rho | clutter),

and a frame with one teaches nothing: the box is the particles' estimate, as on any tracked frame, but
the filters, the colour model, the size, the clutter's distribution and the velocity are not updated
from it. A look-alike that stays beside the target (a second skater) is then never learnt into the
model or into the clutter, and the velocity is not updated while one is near.

Departures: LMCF judges the response by its peak and its average peak-to-correlation energy against
their running means, with fixed ratios; here the secondary peak is judged against the learnt distances. Holding the box
as well, as a frame clutter explains holds it, kept a standing target from a copy walking across it
(``distract-40``) but lost dollar's note to its twin beside it on one seed (docs/dcf-development.md).
"""

from __future__ import annotations

from ..visibility import ChiSquare

__all__ = ["beside"]


def beside(target: ChiSquare, clutter: ChiSquare, seen: tuple[float, float] | None, min_std: float) -> bool:
    """Whether the best response away from the estimate, ``seen`` = (its value y, the area it was taken
    over) or None, is a look-alike: its distance 1 - y likelier the target's than the clutter's. False
    before the target's distribution has a sample."""
    if seen is None or target.n <= 0:
        return False
    rho = 1.0 - seen[0]
    # log p(rho | target) > log p(rho | clutter)
    return target.log_pdf(rho, min_std) > clutter.log_pdf(rho, min_std)
