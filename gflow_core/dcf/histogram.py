"""Staple's colour model: histograms of the target and of its surroundings, learnt online.

Bertinetto, Valmadre, Golodetz, Miksik & Torr (CVPR 2016, sec. 4-5) complement a correlation
filter, which is precise but rigid, with a colour model that ignores where in the box a colour
is and so holds a target that deforms or turns. From the colour histograms rho_O of the
target's box and rho_B of the ring around it in the filter's window (both running averages at
rate ``colour_rate``), every pixel u of a new window gets

    beta(u) = rho_O(b_u) / (rho_O(b_u) + rho_B(b_u)),                (Staple eq. 11 / sec. 5)

the probability that a pixel of that colour belongs to the target, and the colour score of a
displacement is the mean of beta over the target's box there (an integral image, Staple eq.
13). The tracker merges it with the filter's response, (1 - alpha) y_cf + alpha y_hist
(Staple eq. 2, alpha = 0.3).

Grey video: the bins are 32 grey levels (as Staple's grey-sequence mode); a target of the same
grey levels as its surroundings then gives beta near 1/2 everywhere, a flat score that moves
nothing.

Departures: the score is computed on the filter's cells (the mean of beta over each cell, then
over the box rounded to an odd number of cells), so that it adds to the filter's response cell
for cell and is upsampled with it; pixels outside the frame count for neither histogram.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

__all__ = ["ColourModel", "box_mask", "histograms", "learn_colour", "colour_score"]


@dataclass(frozen=True)
class ColourModel:
    """rho_O and rho_B, (n_bins,) float64 each, normalised to sum 1 (a histogram with no pixel: zeros)."""

    fg: np.ndarray
    bg: np.ndarray


def box_mask(shape: tuple[int, int], box: tuple[float, float]) -> np.ndarray:
    """(h, w) bool: the centred box of (bw, bh) pixels in a window of ``shape`` (rows, cols)."""
    h, w = shape
    bw, bh = box
    x0, x1 = int(round((w - bw) / 2.0)), int(round((w + bw) / 2.0))
    y0, y1 = int(round((h - bh) / 2.0)), int(round((h + bh) / 2.0))
    m = np.zeros((h, w), dtype=bool)
    m[max(0, y0):max(0, y1), max(0, x0):max(0, x1)] = True
    return m


def histograms(bins: np.ndarray, valid: np.ndarray, box: tuple[float, float], n_bins: int) -> ColourModel:
    """The histograms of one window: ``bins`` (h, w) int32 bin of every pixel, ``valid`` (h, w) bool
    (the pixel lies in the frame), ``box`` (bw, bh) the target's size in window pixels, centred."""
    inside = box_mask(bins.shape, box)
    fg = np.bincount(bins[inside & valid], minlength=n_bins).astype(np.float64)
    bg = np.bincount(bins[~inside & valid], minlength=n_bins).astype(np.float64)
    return ColourModel(fg / max(fg.sum(), 1.0), bg / max(bg.sum(), 1.0))


def learn_colour(model: ColourModel, new: ColourModel, rate: float) -> ColourModel:
    """rho <- (1 - eta) rho + eta rho_new for both histograms (Staple eq. 7-8)."""
    return ColourModel((1.0 - rate) * model.fg + rate * new.fg, (1.0 - rate) * model.bg + rate * new.bg)


def colour_score(model: ColourModel, bins: np.ndarray, cell: int, box_cells: tuple[float, float]) -> np.ndarray:
    """(h / cell, w / cell) float64: the mean of beta (module docstring) over the target's box centred
    on each cell, ``box_cells`` (bw, bh) its size in cells (rounded to odd whole cells); 0 outside."""
    den = model.fg + model.bg
    # beta(b) = rho_O(b) / (rho_O(b) + rho_B(b)), 0 for a colour neither histogram has seen
    beta = np.divide(model.fg, den, out=np.zeros_like(model.fg), where=den > 0)
    p = beta[bins].astype(np.float32)
    h, w = bins.shape
    cells = p.reshape(h // cell, cell, w // cell, cell).mean(axis=(1, 3))
    kw = max(1, int(round((box_cells[0] - 1) / 2.0)) * 2 + 1)
    kh = max(1, int(round((box_cells[1] - 1) / 2.0)) * 2 + 1)
    # mean of beta over the box centred on each cell (Staple eq. 13, by a box filter)
    return cv2.boxFilter(cells, cv2.CV_32F, (kw, kh), normalize=True, borderType=cv2.BORDER_CONSTANT).astype(np.float64)
