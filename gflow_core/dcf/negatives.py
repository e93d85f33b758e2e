"""Where the search kept finding clutter while the target was hidden: the places of its negatives.

While the target is hidden the search for it (:func:`gflow_core.dcf.tracker._search`) still puts a best
placement somewhere on every frame, and on a frame the target stays hidden that placement is clutter.
``search_clutter`` keeps the distribution of those placements' filter distances (their scores); this
module keeps *where* they were: a few places, each the running mean of the centres of the best
placements that fell within half a box of it, with the distribution of the filter's distance there.
A still look-alike (another skater, a second bill, a walker at the frame's edge) the search picked
frame after frame while the target was hidden becomes such a place, and a later candidate at that
place whose distance is what it was there is likely that clutter again; a target back somewhere
else, or back at the place but scoring otherwise than the clutter did there, is judged as before.

The literature: TLD (Kalal, Mikolajczyk & Matas, PAMI 2012, sec. 5.2-5.3) keeps its negative examples
as patches -- appearances cut from places in the frame where the object was not -- and its nearest-
neighbour classifier refuses a candidate close to a negative patch; P-N learning adds as negatives
the detections that are not the tracked object (the N-expert, sec. 5.2). MUSTer's and LCT's
re-detection likewise learn what the background's detections look like.

Departures: the negatives here are not patches but places with a score distribution -- the place
stands for the appearance, since the filter that would compare patches is the one whose score is
recorded; a place's distribution is a sigma^2 chi^2_d of the distance (Toyama & Blake's eq. 10, as
every other distribution of the tracker), and it enters the judgement as one more density under
"hidden": a candidate within half a box of a place that holds at least ``search_negatives`` frames is
judged under "hidden" by the larger of the search's density (:func:`tracker._hidden_log_pdf`) and
that place's, so the memory can only make a candidate likelier clutter, never likelier the target.
The memory is emptied when the target is seen or taken back (TLD keeps its negatives for the whole
run; here the places are frame coordinates, which a moving camera does not keep).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..visibility import ChiSquare

__all__ = ["Place", "learn", "log_pdf", "to_array", "from_array", "MAX_PLACES"]

MAX_PLACES = 8
"""Places kept at most: a new one replaces the place with fewest frames (the oldest of equal ones)."""


@dataclass(frozen=True)
class Place:
    """A place the search's best placement kept falling at while the target was hidden.

    centre : (x, y) px, the running mean of the placements' centres; rho : the distribution of the
    filter's distance at those placements (``rho.n`` the frames the place holds).
    """

    centre: tuple[float, float]
    rho: ChiSquare


def _nearest(places: tuple[Place, ...], c: np.ndarray, half: tuple[float, float]) -> int | None:
    """Index of the place nearest ``c`` (x, y) among those within ``half`` (half-width, half-height) px
    of it in each axis, or None."""
    best, best_d = None, float("inf")
    for i, pl in enumerate(places):
        dx, dy = abs(float(c[0]) - pl.centre[0]), abs(float(c[1]) - pl.centre[1])
        if dx <= half[0] and dy <= half[1]:
            # distance in half boxes, so a wide box and a tall one weigh their axes alike
            d = (dx / max(half[0], 1e-9)) ** 2 + (dy / max(half[1], 1e-9)) ** 2
            if d < best_d:
                best, best_d = i, d
    return best


def learn(places: tuple[Place, ...], c: np.ndarray, rho: float, half: tuple[float, float],
          rate: float) -> tuple[Place, ...]:
    """The places after a hidden frame whose search put its best placement at ``c`` (x, y) with the filter's
    distance ``rho``: the nearest place within ``half`` px in each axis learns it (its centre and its
    distribution, forgetting at ``rate`` after the first 1 / rate frames), or a new place starts there."""
    i = _nearest(places, c, half)
    if i is None:
        new = Place((float(c[0]), float(c[1])), ChiSquare().update(rho, rate))
        if len(places) < MAX_PLACES:
            return places + (new,)
        # the place of fewest frames makes way (the first of equal ones: the oldest)
        j = min(range(len(places)), key=lambda k: places[k].rho.n)
        return places[:j] + places[j + 1:] + (new,)
    pl = places[i]
    a = max(rate, 1.0 / (pl.rho.n + 1))
    # centre <- (1 - a) centre + a c  (the weights of ChiSquare.update)
    centre = ((1.0 - a) * pl.centre[0] + a * float(c[0]), (1.0 - a) * pl.centre[1] + a * float(c[1]))
    return places[:i] + (Place(centre, pl.rho.update(rho, rate)),) + places[i + 1:]


def log_pdf(places: tuple[Place, ...], c: np.ndarray, rho: float, half: tuple[float, float], count: int,
            min_std: float) -> float:
    """log p(rho | the clutter at the place of ``c``): the density of the nearest place within ``half`` px
    that holds at least ``count`` frames, or -inf where there is none."""
    kept = tuple(pl for pl in places if pl.rho.n >= count)
    i = _nearest(kept, c, half)
    return -float("inf") if i is None else kept[i].rho.log_pdf(rho, min_std)


def to_array(places: tuple[Place, ...]) -> np.ndarray:
    """The places as a float64 (K, 5) array of rows (x, y, m1, m2, n)."""
    return np.array([[pl.centre[0], pl.centre[1], pl.rho.m1, pl.rho.m2, pl.rho.n] for pl in places],
                    dtype=np.float64).reshape(len(places), 5)


def from_array(a: np.ndarray) -> tuple[Place, ...]:
    """The inverse of :func:`to_array` (``ValueError`` for an array not of shape (K, 5))."""
    a = np.asarray(a, dtype=np.float64)
    if a.ndim != 2 or a.shape[1] != 5:
        raise ValueError(f"negative places must be (K, 5) = (x, y, m1, m2, n), got {a.shape}")
    return tuple(Place((float(r[0]), float(r[1])), ChiSquare(float(r[2]), float(r[3]), int(r[4]))) for r in a)
