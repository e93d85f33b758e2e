"""The target model of the correlation-filter tracker: its window, its filters, its colour and scale
models, and the response they give a new frame.

* :class:`Geometry` -- the filter's window: the target plus ``padding`` times its mean side (as
  Staple pads), resampled to ``template``^2 template pixels in cells of ``cell`` pixels, an odd
  number of cells a side; the cosine window and the Gaussian label (sigma = ``label_sigma``
  sqrt(w h), Henriques et al. 2015 sec. 6.1) on those cells.
* :class:`TargetModel` -- the running filter (DSST eq. 5), the first frame's filter (the anchor,
  never updated), Staple's colour model (:mod:`.histogram`) and the scale filter (:mod:`.scale`).
* :func:`respond` -- the response over a window centred on a prediction: the filter detection
  uses, (1 - w) the running one + w the anchor (numerators and denominators alike), applied to
  the window's fHOG and intensity cells (DSST eq. 6), merged with the colour score
  ((1 - alpha) y_cf + alpha y_hist, Staple eq. 2) and upsampled by zero-padding its spectrum to
  template pixels, so every particle reads it by bilinear interpolation (:class:`Response`).
* :func:`learn` -- the running averages with the sample at the estimate.
* :func:`search` -- the filter and the colour score over a region up to the whole frame, for a
  target judged hidden: the window's filter times its cosine window, correlated with the region's
  cells (:func:`.filter.correlate_full`), scores at every cell the window centred there as
  :func:`respond` scores the window's centre.

Coordinates are image (x, y) pixels with the origin at the top-left pixel centre.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from . import filter as cf
from .features import colour_bins, cosine_window, hog, intensity, sample, N_COLOUR_BINS, N_GREY_BINS
from .histogram import ColourModel, colour_score, histograms, learn_colour
from .params import DCFParams
from .scale import ScaleFilter, detect_scale, init_scale, learn_scale

__all__ = ["Geometry", "geometry", "TargetModel", "Response", "Window", "window", "respond", "init_model", "learn",
           "search", "Candidate", "scale_change"]


@dataclass(frozen=True)
class Geometry:
    """The filter's window.

    size0 : (w0, h0) the first box's size, px; win0 : (w, h) the window at scale 1, px.
    cells : (wc, hc) odd numbers of cells; cell : px a cell; k0 : (kx, ky) template px per image px at
    scale 1 (the window spans cells * cell template px). window : (hc, wc) cosine window;
    label_hat : (hc, wc // 2 + 1) rfft2 of the Gaussian label. box_cells : (bw, bh) the target in cells.
    """

    size0: tuple[float, float]
    win0: tuple[float, float]
    cells: tuple[int, int]
    cell: int
    k0: tuple[float, float]
    window: np.ndarray
    label_hat: np.ndarray
    box_cells: tuple[float, float]

    @property
    def template(self) -> tuple[int, int]:
        """(w, h) of the window in template px."""
        return self.cells[0] * self.cell, self.cells[1] * self.cell

    def k(self, log_s: float) -> tuple[float, float]:
        """(kx, ky) template px per image px at scale exp(log_s)."""
        s = float(np.exp(log_s))
        return self.k0[0] / s, self.k0[1] / s


def _odd(x: float) -> int:
    """The nearest odd integer >= 5 to x."""
    return max(5, int(round((x - 1.0) / 2.0)) * 2 + 1)


def geometry(size0: tuple[float, float], p: DCFParams) -> Geometry:
    """The window of a target of size ``size0`` (w, h) px."""
    w, h = float(size0[0]), float(size0[1])
    pad = p.padding * 0.5 * (w + h)
    win = (w + pad, h + pad)
    f = p.template / float(np.sqrt(win[0] * win[1]))
    wc, hc = _odd(win[0] * f / p.cell), _odd(win[1] * f / p.cell)
    k0 = (wc * p.cell / win[0], hc * p.cell / win[1])
    box_cells = (w * k0[0] / p.cell, h * k0[1] / p.cell)
    # sigma = label_sigma sqrt(w h) in cells (KCF's output_sigma_factor 0.1 / cell size)
    sigma = p.label_sigma * float(np.sqrt(box_cells[0] * box_cells[1]))
    label_hat = np.fft.rfft2(cf.gaussian_label(hc, wc, sigma))
    return Geometry(size0=(w, h), win0=win, cells=(wc, hc), cell=p.cell, k0=k0, window=cosine_window(hc, wc),
                    label_hat=label_hat, box_cells=box_cells)


@dataclass(frozen=True)
class Window:
    """One window of a frame: ``x`` (hc, wc, C) float32 cells (fHOG and intensity), ``bins`` (h, w) int32
    colour bins of its template pixels or None (no colour model), ``valid`` (h, w) bool (the pixel is
    in the frame), ``centre`` (x, y) and ``k`` (kx, ky) of its sampling."""

    x: np.ndarray
    bins: np.ndarray | None
    valid: np.ndarray | None
    centre: tuple[float, float]
    k: tuple[float, float]


def _valid(shape: tuple[int, int], size: tuple[int, int], centre: tuple[float, float], k: tuple[float, float]
           ) -> np.ndarray:
    """(h, w) bool: template pixel (u, v) of a window of ``size`` (w, h) shows a point inside a frame of
    ``shape`` (H, W)."""
    H, W = shape
    u = centre[0] + (np.arange(size[0]) - (size[0] - 1) / 2.0) / k[0]
    v = centre[1] + (np.arange(size[1]) - (size[1] - 1) / 2.0) / k[1]
    return ((v >= -0.5) & (v <= H - 0.5))[:, None] & ((u >= -0.5) & (u <= W - 0.5))[None, :]


def cells_of(patch: np.ndarray, cell: int) -> np.ndarray:
    """(h / cell, w / cell, 32) float32: fHOG and intensity cells of a grey patch (h, w) float32."""
    return np.concatenate([hog(patch, cell), intensity(patch, cell)], axis=-1)


def window(image: np.ndarray, grey: np.ndarray, centre: tuple[float, float], size: tuple[int, int],
           k: tuple[float, float], cell: int, colour: str | None) -> Window:
    """The window of ``size`` (w, h) template px at ``centre``, sampled at ``k``: its cells and, with
    ``colour`` (``"colour"``: ``image`` is BGR; ``"grey"``: the grey levels), its colour bins."""
    if colour == "colour":
        patch = sample(image, centre, size, k)
        g = cv2.cvtColor(patch, cv2.COLOR_BGR2GRAY).astype(np.float32)
        bins: np.ndarray | None = colour_bins(patch, grey=False)
    else:
        g = sample(grey, centre, size, k)
        bins = colour_bins(np.clip(g, 0, 255).astype(np.uint8), grey=True) if colour == "grey" else None
    valid = _valid(grey.shape, size, centre, k) if bins is not None else None
    return Window(cells_of(g, cell), bins, valid, (float(centre[0]), float(centre[1])), k)


@dataclass(frozen=True)
class TargetModel:
    """filt : the running filter; anchor : the first frame's; colour : Staple's histograms (None: no
    colour model); colour_mode : ``"colour"``, ``"grey"`` or None; scale : the scale filter (None: fixed size)."""

    filt: cf.Spectrum
    anchor: cf.Spectrum
    colour: ColourModel | None
    colour_mode: str | None
    scale: ScaleFilter | None


def _n_bins(mode: str | None) -> int:
    return N_COLOUR_BINS if mode == "colour" else N_GREY_BINS


def init_model(image: np.ndarray, grey: np.ndarray, is_grey: bool, centre: tuple[float, float], geom: Geometry,
               p: DCFParams) -> TargetModel:
    """The model of the first frame's box centred at ``centre``: the filter of its window (DSST eq. 3),
    which is also the anchor, the colour histograms and the scale filter."""
    mode = None if p.colour_weight <= 0 else ("grey" if is_grey else "colour")
    win = window(image, grey, centre, geom.template, geom.k(0.0), geom.cell, mode)
    filt = cf.train(cf.spectrum(win.x, geom.window), geom.label_hat)
    colour = None
    if mode is not None:
        assert win.bins is not None and win.valid is not None
        colour = histograms(win.bins, win.valid, (geom.size0[0] * geom.k0[0], geom.size0[1] * geom.k0[1]),
                            _n_bins(mode))
    scale = None
    if p.scales > 1:
        scale = init_scale(grey, centre, geom.size0, p.scales, p.scale_step, p.scale_area, p.cell)
    return TargetModel(filt, filt, colour, mode, scale)


def detection_filter(model: TargetModel, w: float) -> cf.Spectrum:
    """The filter detection uses: (1 - w) the running filter + w the anchor, numerators and denominators."""
    if w <= 0:
        return model.filt
    return cf.Spectrum((1.0 - w) * model.filt.num + w * model.anchor.num,
                       (1.0 - w) * model.filt.den + w * model.anchor.den)


@dataclass(frozen=True)
class Response:
    """The merged response over a window, upsampled to template px.

    y : (h, w) float64, centred: index (h // 2, w // 2) is the target at the window's centre, index
    (i, j) the target at ``centre + ((j, i) - (w // 2, h // 2)) / k``. y_cf : the filter's part alone.
    """

    y: np.ndarray
    centre: tuple[float, float]
    k: tuple[float, float]

    def at(self, xy: np.ndarray) -> np.ndarray:
        """(N,) the response at image points ``xy`` (N, 2), bilinear; the map's minimum outside it."""
        h, w = self.y.shape
        u = ((xy[:, 0] - self.centre[0]) * self.k[0] + w // 2).astype(np.float32).reshape(-1, 1)
        v = ((xy[:, 1] - self.centre[1]) * self.k[1] + h // 2).astype(np.float32).reshape(-1, 1)
        return cv2.remap(self.y.astype(np.float32), u, v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                         borderValue=float(self.y.min())).ravel().astype(np.float64)

    def point(self, i: int, j: int) -> np.ndarray:
        """(x, y) image point of map index (i, j)."""
        h, w = self.y.shape
        return np.array([self.centre[0] + (j - w // 2) / self.k[0], self.centre[1] + (i - h // 2) / self.k[1]])

    def peak(self) -> tuple[np.ndarray, float]:
        """The image point of the response's maximum and its value."""
        i, j, v = cf.peak(self.y)
        return self.point(i, j), v

    def best_away(self, xy: np.ndarray, half: tuple[float, float]) -> tuple[float, float] | None:
        """The best response at centres farther than ``half`` (hx, hy) image px from ``xy`` in x or y (the
        best look-alike away from the estimate), and the image area (px^2) of those centres; None when
        fewer than 16 map positions are left."""
        h, w = self.y.shape
        xs = self.centre[0] + (np.arange(w) - w // 2) / self.k[0]
        ys = self.centre[1] + (np.arange(h) - h // 2) / self.k[1]
        mask = (np.abs(ys - xy[1]) >= half[1])[:, None] | (np.abs(xs - xy[0]) >= half[0])[None, :]
        n = int(mask.sum())
        if n < 16:
            return None
        return float(self.y[mask].max()), n / (self.k[0] * self.k[1])


def _colour_cells(model: TargetModel, win: Window, geom: Geometry) -> np.ndarray | None:
    """The colour score on the window's cells (:func:`.histogram.colour_score`), or None."""
    if model.colour is None or win.bins is None:
        return None
    return colour_score(model.colour, win.bins, geom.cell, geom.box_cells)


def respond(model: TargetModel, image: np.ndarray, grey: np.ndarray, centre: tuple[float, float], log_s: float,
            geom: Geometry, p: DCFParams) -> Response:
    """The response over the window centred at ``centre`` at scale exp(``log_s``) (module docstring)."""
    k = geom.k(log_s)
    win = window(image, grey, centre, geom.template, k, geom.cell, model.colour_mode)
    # Y_cf = sum_l conj(A_l) Z_l / (B + lambda)                                  (DSST eq. 6)
    y_hat = cf.respond(detection_filter(model, p.anchor_weight), cf.spectrum(win.x, geom.window), p.lam)
    col = _colour_cells(model, win, geom)
    if col is not None:
        # y = (1 - alpha) y_cf + alpha y_hist                                  (Staple eq. 2)
        y_hat = (1.0 - p.colour_weight) * y_hat + p.colour_weight * np.fft.rfft2(np.fft.ifftshift(col))
    wc, hc = geom.cells
    y = cf.centred(cf.upsample(y_hat, (hc, wc), geom.cell))
    return Response(y, win.centre, k)


def learn(model: TargetModel, image: np.ndarray, grey: np.ndarray, centre: tuple[float, float], log_s: float,
          geom: Geometry, p: DCFParams, rate: float, scale: bool = True) -> TargetModel:
    """The model after the sample of the box at ``centre``, scale exp(``log_s``): the running filter at
    ``rate`` (DSST eq. 5), the colour histograms at ``colour_rate`` (Staple eq. 7-8) and, with ``scale``,
    the scale filter at ``scale_rate``. The anchor is never changed."""
    k = geom.k(log_s)
    win = window(image, grey, centre, geom.template, k, geom.cell, model.colour_mode)
    filt = cf.blend(model.filt, cf.train(cf.spectrum(win.x, geom.window), geom.label_hat), rate)
    colour = model.colour
    if colour is not None and win.bins is not None and win.valid is not None and p.colour_rate > 0:
        box = (geom.size0[0] * geom.k0[0], geom.size0[1] * geom.k0[1])
        colour = learn_colour(colour, histograms(win.bins, win.valid, box, _n_bins(model.colour_mode)),
                              p.colour_rate)
    sf = model.scale
    if sf is not None and scale and p.scale_rate > 0:
        s = float(np.exp(log_s))
        sf = learn_scale(sf, grey, centre, (geom.size0[0] * s, geom.size0[1] * s), p.scale_step, p.cell,
                         p.scale_rate)
    return TargetModel(filt, model.anchor, colour, model.colour_mode, sf)


def scale_change(model: TargetModel, grey: np.ndarray, centre: tuple[float, float], log_s: float, geom: Geometry,
                 p: DCFParams) -> float:
    """The log-scale change the scale filter finds at ``centre`` (0 without one)."""
    if model.scale is None:
        return 0.0
    s = float(np.exp(log_s))
    d, _ = detect_scale(model.scale, grey, centre, (geom.size0[0] * s, geom.size0[1] * s), p.scale_step, p.cell,
                        p.scale_lam)
    return d


@dataclass(frozen=True)
class Candidate:
    """A detection of :func:`search`: the response ``r`` at its centre (x, y), its log-size change
    ``log_f`` from the searched size, and ``area``, the image area (px^2) of the centres searched
    (summed over the sizes)."""

    r: float
    centre: np.ndarray
    log_f: float
    area: float


def search(model: TargetModel, image: np.ndarray, grey: np.ndarray, hold: np.ndarray, margin: tuple[float, float],
           log_s: float, geom: Geometry, p: DCFParams, log_sizes: tuple[float, ...] = (0.0,)) -> list[Candidate]:
    """The best placement of the target with its centre within ``margin`` (mx, my) px of ``hold`` (and in
    the frame), at each log-size change in ``log_sizes``.

    At placement c, the window centred at c scores sum_l sum_u h_l(u) w(u) x_l(c + u), h the detection
    filter in the spatial domain and w the cosine window: the correlation of h w with the region's
    cells (:func:`.filter.correlate_full`), merged with the colour score as :func:`respond` merges them."""
    Hh, Ww = grey.shape
    x0, x1 = max(0.0, hold[0] - margin[0]), min(Ww - 1.0, hold[0] + margin[0])
    y0, y1 = max(0.0, hold[1] - margin[1]), min(Hh - 1.0, hold[1] + margin[1])
    filt = detection_filter(model, p.anchor_weight)
    wc, hc = geom.cells
    # h w: the filter times the cosine window, so that a placement is scored as a windowed sample is
    hw = cf.spatial(filt, p.lam, (hc, wc)) * geom.window[..., None]
    out = []
    area = 0.0
    for lf in log_sizes:
        kx, ky = geom.k(log_s + lf)
        # the region's template pixels: the centres searched plus half a window each side, whole cells
        cw = int(np.ceil(((x1 - x0) * kx + wc * geom.cell) / geom.cell))
        ch = int(np.ceil(((y1 - y0) * ky + hc * geom.cell) / geom.cell))
        centre = (0.5 * (x0 + x1), 0.5 * (y0 + y1))
        win = window(image, grey, centre, (cw * geom.cell, ch * geom.cell), (kx, ky), geom.cell, model.colour_mode)
        y = cf.correlate_full(hw, win.x)
        col = _colour_cells(model, win, geom)
        if col is not None:
            # y = (1 - alpha) y_cf + alpha y_hist                              (Staple eq. 2)
            y = (1.0 - p.colour_weight) * y + p.colour_weight * col
        # cell (i, j)'s centre in the image
        xs = centre[0] + ((np.arange(cw) + 0.5) * geom.cell - 0.5 - (cw * geom.cell - 1) / 2.0) / kx
        ys = centre[1] + ((np.arange(ch) + 0.5) * geom.cell - 0.5 - (ch * geom.cell - 1) / 2.0) / ky
        inside = ((ys >= y0 - 0.5 * geom.cell / ky) & (ys <= y1 + 0.5 * geom.cell / ky))[:, None] & \
                 ((xs >= x0 - 0.5 * geom.cell / kx) & (xs <= x1 + 0.5 * geom.cell / kx))[None, :]
        if not inside.any():
            continue
        yv = np.where(inside, y, -np.inf)
        i, j, v = cf.peak(yv)
        area += float(inside.sum()) * (geom.cell / kx) * (geom.cell / ky)
        out.append(Candidate(v, np.array([xs[j], ys[i]]), float(lf), 0.0))
    return [Candidate(c.r, c.centre, c.log_f, area) for c in out]
