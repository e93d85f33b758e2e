"""A look-alike beside the target puts the frame in doubt (``lookalike_doubt``).

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

and a frame with one is in doubt, as a frame clutter explains: the box holds the prediction, the
velocity decays, nothing is learnt, and after ``hidden_after`` such frames the target is judged
hidden and searched for. So the model and the velocity are not taken along by a look-alike, and the
clutter's distribution does not learn it either (clutter is learnt on present frames only).

Departures: LMCF measures multimodality by the ratio of a secondary peak to the main one with a
fixed threshold, and keeps tracking the main peak; here the secondary peak is judged against the
learnt distances and the frame is not tracked, as the tracker's other frames in doubt are not.
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
