"""Is it the target? A re-detection checked against the first frame's filter before it is taken (``verify``).

Two ways the tracker takes a placement it did not track to: the search for a hidden target
(:func:`gflow_core.dcf.tracker.step`, over several sizes with ``search_sizes``) and the roll searched
at detection (``roll_detect``, :func:`.rotation.detect`). Both judge the candidate by the adaptive
filter, learnt on every confident frame: its score says the placement looks like what the filter has
lately learnt, and that may be a neighbour, the target at another size, or the occluder. On the stress
cases each option got cases back and lost others that way: with ``search_sizes=5`` a placement off the
surfer, at another size, was taken back; with ``roll_detect`` a rolled window of the patch covering the
target was taken while the target was judged hidden behind it.

TLD (Kalal, Mikolajczyk & Matas, PAMI 2012, sec. 5: its object model and integrator) keeps two
similarities of a patch to the object model: the relative one, to every positive exemplar, and the
*conservative* one, to the earliest half of them only, and it lets the detector re-initialise the
tracker -- and a patch teach the model -- only on the conservative similarity, because the early
exemplars were added before any drift could enter the model. Here the conservative model is the first
frame's filter, the anchor (never updated; :class:`.model.TargetModel`), and its response is the
similarity:

* on every confident frame (the frames the model learns from) the anchor's response to the window at
  the estimate, rolled by the held roll (:func:`conservative`), gives two distances, each learnt into
  its own distribution, rho ~ sigma^2 chi^2_d by running moments (Toyama & Blake eq. 10,
  :class:`gflow_core.visibility.ChiSquare`), from the priors of the filter's: the target's,
  rho_c = 1 - y_a at the response's best within ``roll_reach`` cells of the centre, and the clutter's,
  its best half a box or more away (TLD's negatives, the patches about the target);
* a candidate the adaptive filter has judged the target -- a search placement at another size than the
  held one (``search_sizes``), a rolled window at its peak (``roll_detect``) -- is taken only when the anchor's distance there is within ``verify`` standard
  deviations above the target's mean *and* at least as likely under the target's distribution as under
  the clutter's (:func:`accepted`; both densities one-sided, as the visibility judgement's). The level
  alone is lax where the anchor has always scored the target poorly: on crossing's ``occlude-25`` (seed
  3, ``roll_detect``) the anchor's distance at the pedestrian was 0.71 +- 0.11, so the rolled window of
  the patch covering him (0.84) was within two deviations; the clutter's (0.90 +- 0.06) explains it
  better. Refused, the search goes on to its next candidate (or reports the target still hidden), and
  the roll at detection keeps the held roll.

Departures from TLD: TLD's object model is a set of normalised patches compared by normalised
cross-correlation, its conservative set the first half of the positives added, and its decision a fixed
threshold on a similarity; here the conservative model is the first frame's filter alone, its score a
correlation filter's response, and the decision a level of that score's learnt distribution at the
target and a likelihood ratio against its clutter's, so a target that the anchor has always scored
poorly (a changing look) is not refused more often than a steady one. TLD's relative similarity weighs
the negatives patch by patch; here the clutter is one distribution of the anchor's best score about the
target. TLD also picks between the tracker and the detector by the conservative similarity; here only
what the two options add is checked, and the tracked estimate and the search's placements at the held
size are judged as before: the first filter refuses a target come back looking otherwise as readily as
an impostor. On surfer's ``occlude-25`` (seed 1, ``search_sizes=5``) the surfer back at the held size
scored 0.69 under the anchor, refused at two deviations (0.48 +- 0.08), and the case was lost -- as
high as the placement off the surfer, at another size, that the check refused on its ``occlude-60``
(0.68-0.69).
"""

from __future__ import annotations

import math

import numpy as np

from ..visibility import ChiSquare
from . import filter as cf
from .gate import within
from .model import Geometry, TargetModel, names_of, window
from .params import DCFParams

__all__ = ["conservative", "accepted", "recognised", "learn_conservative"]


def conservative(model: TargetModel, image: np.ndarray, grey: np.ndarray, centre: tuple[float, float], log_s: float,
                 angle: float, geom: Geometry, p: DCFParams) -> tuple[float, float]:
    """(rho_c, rho_away): the anchor's distance 1 - y_a at the box of scale exp(``log_s``) centred at ``centre``
    (x, y), the window rolled by ``angle`` radians -- y_a the anchor's response to that window, upsampled to
    template pixels (:func:`.model.respond`'s map), at its best within ``roll_reach`` cells of the window's
    centre (a candidate's centre is a cell's, not the target's to the pixel) -- and its best distance half a
    box or more from the centre (in x or y)."""
    k = geom.k(log_s)
    wc, hc = geom.cells
    win = window(image, grey, centre, geom.template, k, geom.cell, None, float(angle), names_of(model.colour_mode, p))
    # Y_a = sum_l conj(A_l) Z_l / (B + lambda), the first frame's filter                 (DSST eq. 6)
    y = cf.centred(cf.upsample(cf.respond(model.anchor, cf.spectrum(win.x, geom.window)), (hc, wc), geom.cell))
    h, w = y.shape
    r, ic, jc = max(p.roll_reach, 0) * geom.cell, h // 2, w // 2
    near = float(y[ic - r: ic + r + 1, jc - r: jc + r + 1].max())
    hx = max(int(math.ceil(0.5 * geom.box_cells[0] * geom.cell)), r + 1)
    hy = max(int(math.ceil(0.5 * geom.box_cells[1] * geom.cell)), r + 1)
    away = (np.abs(np.arange(h) - ic) >= hy)[:, None] | (np.abs(np.arange(w) - jc) >= hx)[None, :]
    return 1.0 - near, 1.0 - float(y[away].max())


def accepted(vt: ChiSquare, vc: ChiSquare, rho_c: float, p: DCFParams) -> bool:
    """Whether a candidate whose anchor distance is ``rho_c`` may be taken: without ``verify``, always; with
    it, rho_c <= E[rho_c] + ``verify`` sd[rho_c] of the target's distribution ``vt`` and
    p_t(max(rho_c, mode_t)) >= p_c(min(rho_c, mode_c)) against the clutter's ``vc`` (one-sided densities)."""
    return p.verify <= 0 or recognised(vt, vc, rho_c, p.verify, p.min_std)


def recognised(vt: ChiSquare, vc: ChiSquare, rho: float, level: float, min_std: float) -> bool:
    """Whether the first frame's filter sees the target where its distance is ``rho``: rho <= E[rho] +
    ``level`` sd[rho] under the target's distribution ``vt`` and p_t(max(rho, mode_t)) >= p_c(min(rho, mode_c))
    against the clutter's ``vc`` (one-sided densities)."""
    if not within(vt, rho, level, min_std):
        return False
    # log p_t(max(rho, mode_t)) >= log p_c(min(rho, mode_c)): the target at least as likely as clutter
    return vt.log_pdf(max(rho, vt.mode(min_std)), min_std) >= vc.log_pdf(min(rho, vc.mode(min_std)), min_std)


def learn_conservative(vt: ChiSquare, vc: ChiSquare, seen: tuple[float, float], p: DCFParams
                       ) -> tuple[ChiSquare, ChiSquare]:
    """(``vt``, ``vc``) after a confident frame whose anchor distances (:func:`conservative`) are ``seen``:
    the target's at rate ``target_rate``, the clutter's at ``clutter_rate``."""
    return vt.update(seen[0], p.target_rate), vc.update(seen[1], p.clutter_rate)
