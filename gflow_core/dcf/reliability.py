"""CSR-DCF's spatial reliability map: the cells of the window the filter may use, from the colour models.

The masked filter (:mod:`.constrained`) is held to a box of the target's size; in a box that is partly
background (a small toy among leaves, a walker's legs apart) it still learns the background inside the
box. Lukezic, Vojir, Cehovin, Matas & Kristan ("Discriminative correlation filter with channel and
spatial reliability", CVPR 2017, sec. 3.1; OpenCV's CSRT) make the mask m the pixels that look like the
target. Each pixel x of colour y gets the posterior (CSR-DCF sec. 3.1)

    p(m = 1 | y, x)  ~  p(y | m = 1, x) p(x | m = 1) p(m = 1),

normalised against the same of m = 0:

* appearance: p(y | m = 1) = rho_O(b_y), p(y | m = 0) = rho_B(b_y), the target's and its surroundings'
  colour histograms (Staple's, :mod:`.histogram`: 32^3 colour bins, or 32 grey levels of grey video);
* class prior: p(m = 1) = |O| / (|O| + |B|), the box's share of the window's pixels in the frame (the
  regions the histograms are drawn from);
* spatial prior: p(x | m = 1) = k(r), a modified Epanechnikov kernel k(r) = 1 - (r / sigma)^2 clipped
  to [0.5, 0.9] (0.9 about the centre, an indifferent 0.5 from the box's edge out), r the distance from
  the box's centre and sigma = min(w, h) / sqrt(2) (OpenCV's CSRT; k = 0.5 on the box's edge along its
  minor axis); p(x | m = 0) = 1 - k(r).

So, with L_O = p(m = 1) rho_O k and L_B = (1 - p(m = 1)) rho_B (1 - k),

    P(x) = L_O / (L_O + L_B)                         (Bayes' rule; 0 for a colour neither histogram has),

then regularised, thresholded at ``threshold`` times its largest value on the box (OpenCV's CSRT: 0.5),
dilated by one cell (a 3 x 3 cross, as CSRT's 3 x 3 ellipse) and replaced by the plain box when it
covers less than ``cover`` of the box (CSRT: 5 %; ``segment_cover``). The filter is solved under the
map of the frame it learns from or, with ``segment_rate`` (:func:`gflow_core.dcf.model.learn`), under
the cells where the running average of the maps is at least 1/2: CSR-DCF averages filters, each solved
under its own frame's map (h <- (1 - eta) h + eta h_t, as OpenCV's CSRT), so a cell one frame's map
leaves out keeps the weight earlier frames gave it, while here the running sample is solved again
every frame under one mask.

Departures:

* the map is on the filter's cells (the posterior's mean over each cell of template pixels), not on
  pixels resampled to 1000 as in CSRT, and it is regularised by a Gaussian of one cell (``SMOOTH``)
  instead of CSR-DCF's Markov random field (Kristan et al., ACCV 2014);
* the map is kept within the box of the masked filter (:func:`.constrained.box_mask`) before the
  dilation: pixels beyond it that share the target's colours (leaves about a green toy) would otherwise
  become support, the very clutter the map is meant to shed; CSR-DCF takes them too;
* grey footage keeps the box unless ``segment_grey`` (as CSR-DCF's own MATLAB code, which turns
  segmentation off on grey images; measured, 32 grey levels cost tiger1, jumping and twinnings);
* the threshold is relative to the map's largest value on the box (as OpenCV's CSRT), and the map
  falls back to the box when it covers less than half of it by default (CSRT: 5 %);
* a map is uninformative -- the box is used -- when the colour alone (the posterior without the
  spatial prior) varies by less than ``FLAT`` over the box's cells: a target whose colours differ
  nowhere in its box from its surroundings' (grey video of a target of its background's grey levels:
  the map would be the spatial prior's disc), or that is of one colour throughout (the map is the box).
"""

from __future__ import annotations

import cv2
import numpy as np

from .histogram import ColourModel

__all__ = ["spatial_prior", "posterior", "reliability", "SMOOTH", "FLAT"]

#: std of the Gaussian that regularises the posterior on cells, in cells (in place of CSR-DCF's MRF)
SMOOTH = 0.75
#: a colour posterior whose range over the box's cells is below this says nothing: the box is used
FLAT = 0.1
#: the spatial prior's clip, CSR-DCF's [0.5, 0.9]
PRIOR_LOW, PRIOR_HIGH = 0.5, 0.9


def spatial_prior(shape: tuple[int, int], box: tuple[float, float]) -> np.ndarray:
    """(h, w) float64 p(x | m = 1): the modified Epanechnikov kernel about the centre of a window of
    ``shape`` (rows, cols), clipped to [0.5, 0.9]; ``box`` (bw, bh) the target's size in the window's
    pixels."""
    h, w = shape
    sigma = max(min(box) / np.sqrt(2.0), 1e-6)
    y = (np.arange(h) - (h - 1) / 2.0)[:, None]
    x = (np.arange(w) - (w - 1) / 2.0)[None, :]
    # k(r) = 1 - (r / sigma)^2, clipped to [0.5, 0.9]                               (CSR-DCF sec. 3.1)
    return np.clip(1.0 - (x * x + y * y) / (sigma * sigma), PRIOR_LOW, PRIOR_HIGH)


def posterior(colour: ColourModel, bins: np.ndarray, valid: np.ndarray, box: tuple[float, float],
              prior: np.ndarray | None) -> np.ndarray:
    """(h, w) float64 p(m = 1 | y, x) of every pixel of a window (module docstring): ``bins`` (h, w) int
    colour bins, ``valid`` (h, w) bool (the pixel is in the frame; 0 elsewhere), ``box`` (bw, bh) the
    target's size in pixels, ``prior`` (h, w) p(x | m = 1) (None: the colour alone, k = 1/2)."""
    n_valid = max(int(valid.sum()), 1)
    # p(m = 1) = |O| / (|O| + |B|), the box's share of the window's pixels in the frame
    p_o = min(box[0] * box[1], float(n_valid)) / n_valid
    k = 0.5 if prior is None else prior
    # L_O = p(m = 1) rho_O(y) k(x),  L_B = (1 - p(m = 1)) rho_B(y) (1 - k(x))      (CSR-DCF sec. 3.1)
    lo = p_o * colour.fg[bins] * k
    lb = (1.0 - p_o) * colour.bg[bins] * (1.0 - k)
    den = lo + lb
    p = np.divide(lo, den, out=np.zeros_like(lo), where=den > 0)
    return np.where(valid, p, 0.0)


def _cells(p: np.ndarray, cell: int) -> np.ndarray:
    """(h / cell, w / cell) the mean of ``p`` (h, w) over each cell."""
    h, w = p.shape
    return p.reshape(h // cell, cell, w // cell, cell).mean(axis=(1, 3))


def reliability(colour: ColourModel, bins: np.ndarray, valid: np.ndarray, box: tuple[float, float], cell: int,
                box_cells: np.ndarray, threshold: float, cover: float) -> np.ndarray | None:
    """The spatial reliability map of a window on its cells, or None when the box should be used.

    Parameters
    ----------
    colour : the running histograms rho_O, rho_B.
    bins : (h, w) int32 colour bins of the window's template pixels; h, w multiples of ``cell``.
    valid : (h, w) bool, the pixel lies in the frame.
    box : (bw, bh) the target's size in template pixels, centred in the window.
    cell : template pixels a cell.
    box_cells : (h / cell, w / cell) float 0 / 1, the masked filter's box on the cells.
    threshold : a cell is reliable when its regularised posterior is at least this times the largest on
        the box (CSRT 0.5).
    cover : the map must cover at least this fraction of the box's cells, else None.

    Returns
    -------
    (h / cell, w / cell) float64 0 / 1, or None (the colour says nothing, or the map covers too little).
    """
    inside = box_cells > 0
    if not inside.any():
        return None
    # the colour alone: flat over the box, the map would be the spatial prior's (or the box itself)
    alone = _cells(posterior(colour, bins, valid, box, None), cell)[inside]
    if float(alone.max() - alone.min()) < FLAT:
        return None
    p = _cells(posterior(colour, bins, valid, box, spatial_prior(bins.shape, box)), cell)
    # regularisation: a Gaussian of SMOOTH cells (in place of CSR-DCF's MRF)
    p = cv2.GaussianBlur(p, (0, 0), SMOOTH, borderType=cv2.BORDER_REPLICATE)
    top = float(p[inside].max())
    m0 = ((p >= threshold * top) & inside).astype(np.uint8)
    # dilated by one cell (CSRT: a 3 x 3 ellipse)
    m = np.asarray(cv2.dilate(m0, cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3))))
    if top <= 0 or float(m[inside].sum()) < cover * float(inside.sum()):
        return None
    return m.astype(np.float64)
