"""The target model of the correlation-filter tracker: its window, its filters, its colour and scale
models, and the response they give a new frame.

* :class:`Geometry` -- the filter's window: the target plus ``padding`` times its mean side (as
  Staple pads), resampled to ``template``^2 template pixels in cells of ``cell`` pixels, an odd
  number of cells a side; the cosine window and the Gaussian label (sigma = ``label_sigma``
  sqrt(w h), Henriques et al. 2015 sec. 6.1) on those cells.
* :class:`TargetModel` -- the running filter (DSST eq. 5), the first frame's filter (the anchor,
  never updated), Staple's colour model (:mod:`.histogram`) and the scale filter (:mod:`.scale`;
  with ``scale_anchor``, off by default, it keeps its own first frame's filter as its anchor).
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

from . import channels as ch
from . import filter as cf
from ..remap import remap_points
from .augment import first_sample
from .constrained import box_mask, solve_masked
from .features import colour_bins, colour_names, cosine_window, hog, intensity, sample, N_COLOUR_BINS, N_GREY_BINS
from .histogram import ColourModel, colour_score, histograms, learn_colour
from .params import DCFParams
from .reliability import reliability
from .scale import ScaleFilter, detect_scale, init_scale, learn_scale

__all__ = ["Geometry", "geometry", "TargetModel", "Response", "Window", "window", "respond", "upright", "init_model", "learn",
           "search", "Candidate", "scale_change", "scale_anchor", "respond_region"]


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
    mask: np.ndarray | None = None

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
    mask = box_mask((wc, hc), box_cells, p.mask) if p.mask > 0 else None
    return Geometry(size0=(w, h), win0=win, cells=(wc, hc), cell=p.cell, k0=k0, window=cosine_window(hc, wc),
                    label_hat=label_hat, box_cells=box_cells, mask=mask)


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


def _valid(shape: tuple[int, int], size: tuple[int, int], centre: tuple[float, float], k: tuple[float, float],
           angle: float = 0.0) -> np.ndarray:
    """(h, w) bool: template pixel (u, v) of a window of ``size`` (w, h) rolled by ``angle``
    (:func:`.features.sample`) shows a point inside a frame of ``shape`` (H, W)."""
    H, W = shape
    u = (np.arange(size[0]) - (size[0] - 1) / 2.0) / k[0]
    v = (np.arange(size[1]) - (size[1] - 1) / 2.0) / k[1]
    if angle:
        # (x, y) = centre + R(angle) (u, v)
        c, s = np.cos(angle), np.sin(angle)
        x = centre[0] + c * u[None, :] - s * v[:, None]
        y = centre[1] + s * u[None, :] + c * v[:, None]
        return (y >= -0.5) & (y <= H - 0.5) & (x >= -0.5) & (x <= W - 0.5)
    u, v = centre[0] + u, centre[1] + v
    return ((v >= -0.5) & (v <= H - 0.5))[:, None] & ((u >= -0.5) & (u <= W - 0.5))[None, :]


def cells_of(patch: np.ndarray, cell: int, names: np.ndarray | None = None) -> np.ndarray:
    """(h / cell, w / cell, 32) float32: fHOG and intensity cells of a grey patch (h, w) float32; with the
    colour names' cells ``names`` (h / cell, w / cell, 11) between them, 43 (the intensity stays the last
    channel, which :mod:`.channels` leaves out of its weighting)."""
    parts = [hog(patch, cell)] + ([] if names is None else [names]) + [intensity(patch, cell)]
    return np.concatenate(parts, axis=-1)


def window(image: np.ndarray, grey: np.ndarray, centre: tuple[float, float], size: tuple[int, int],
           k: tuple[float, float], cell: int, colour: str | None, angle: float = 0.0, names: bool = False) -> Window:
    """The window of ``size`` (w, h) template px at ``centre``, sampled at ``k`` and rolled by ``angle``
    radians (:func:`.features.sample`): its cells and, with ``colour`` (``"colour"``: ``image`` is BGR;
    ``"grey"``: the grey levels), its colour bins; with ``names`` (``image`` BGR) the cells hold the colour
    names too (:func:`.features.colour_names`)."""
    bins: np.ndarray | None = None
    if colour == "colour" or names:
        patch = sample(image, centre, size, k, angle)
        g = cv2.cvtColor(patch, cv2.COLOR_BGR2GRAY).astype(np.float32)
        if colour == "colour":
            bins = colour_bins(patch, grey=False)
    else:
        g = sample(grey, centre, size, k, angle)
        bins = colour_bins(np.clip(g, 0, 255).astype(np.uint8), grey=True) if colour == "grey" else None
    valid = _valid(grey.shape, size, centre, k, angle) if bins is not None else None
    x = cells_of(g, cell, colour_names(patch, cell) if names else None)
    return Window(x, bins, valid, (float(centre[0]), float(centre[1])), k)


def names_of(mode: str | None, p: DCFParams) -> bool:
    """Whether the filter's cells hold the colour names: ``colour_names`` on a colour frame."""
    return p.colour_names and mode == "colour"


@dataclass(frozen=True)
class TargetModel:
    """What the tracker knows of the target.

    train : the running average the filter is solved from -- the numerator and denominator (DSST eq. 5)
        without a mask, the windowed samples' spectra (BACF sec. 3.3) with one; det : the filter as
        detection applies it (:func:`.filter.detector`), (hc, wc // 2 + 1, C) complex; anchor : the first
        frame's, never updated; colour : Staple's histograms (None: no colour model); colour_mode :
        ``"colour"``, ``"grey"`` or None; scale : the scale filter (None: fixed size); support : with
        ``segment`` and ``segment_rate``, the running average of the reliability maps (hc, wc) float64
        (:func:`_support`), else None; channels : with ``channel_weights``, the running channel weights (C,)
        float64 summing to 1 (:mod:`.channels`; the anchor holds the first frame's weights, multiplied in),
        else None.
    """

    train: cf.Spectrum | np.ndarray
    det: np.ndarray
    anchor: np.ndarray
    colour: ColourModel | None
    colour_mode: str | None
    scale: ScaleFilter | None
    support: np.ndarray | None = None
    channels: np.ndarray | None = None


def _n_bins(mode: str | None) -> int:
    return N_COLOUR_BINS if mode == "colour" else N_GREY_BINS


def _solve(train: cf.Spectrum | np.ndarray, geom: Geometry, p: DCFParams, mask: np.ndarray | None = None) -> np.ndarray:
    """The detection filter of the running average: closed form (DSST eq. 3) or under the mask (ADMM):
    ``mask`` (hc, wc) if given (the frame's reliability map), else the box."""
    if isinstance(train, cf.Spectrum):
        return cf.detector(train, p.lam)
    assert geom.mask is not None
    return solve_masked(train, geom.label_hat, geom.mask if mask is None else mask, p.lam, p.mu, p.admm_iterations)


def _support(colour: ColourModel | None, mode: str | None, win: Window, geom: Geometry, p: DCFParams,
             running: np.ndarray | None) -> tuple[np.ndarray | None, np.ndarray | None]:
    """With ``segment``, the mask the filter is solved under and the running average of the maps: the
    spatial reliability map of ``win`` from the histograms ``colour`` (:func:`.reliability.reliability`;
    the box when the map is uninformative or too small) or, with ``segment_rate``, the cells where the
    running average s <- (1 - segment_rate) s + segment_rate m (``running`` s; None: the first frame, s = m)
    is at least 1/2. (None, None) without ``segment``, without colour bins, or on grey footage (``mode``
    ``"grey"``) without ``segment_grey``: the box."""
    if p.segment <= 0 or colour is None or win.bins is None or win.valid is None or geom.mask is None:
        return None, None
    if mode == "grey" and not p.segment_grey:
        return None, None
    box = (geom.size0[0] * geom.k0[0], geom.size0[1] * geom.k0[1])
    m = reliability(colour, win.bins, win.valid, box, geom.cell, geom.mask, p.segment, p.segment_cover)
    if p.segment_rate <= 0:
        return m, None
    m = geom.mask if m is None else m
    # s <- (1 - segment_rate) s + segment_rate m; the support: the cells with s >= 1/2
    s = m.copy() if running is None else (1.0 - p.segment_rate) * running + p.segment_rate * m
    return (s >= 0.5).astype(np.float64), s


def init_model(image: np.ndarray, grey: np.ndarray, is_grey: bool, centre: tuple[float, float], geom: Geometry,
               p: DCFParams) -> TargetModel:
    """The model of the first frame's box centred at ``centre``: the filter of its window (DSST eq. 3,
    or under the mask), which is also the anchor, the colour histograms and the scale filter."""
    mode = None if p.colour_weight <= 0 else ("grey" if is_grey else "colour")
    win = window(image, grey, centre, geom.template, geom.k(0.0), geom.cell, mode, names=names_of(mode, p))
    x_hat = cf.spectrum(win.x, geom.window)
    train: cf.Spectrum | np.ndarray = cf.train(x_hat, geom.label_hat) if geom.mask is None else x_hat
    if p.augment > 0:
        # the first sample with warped copies of the window averaged in (module .augment); with the colour names
        # the copies are of the colour frame, so that their cells hold the names as the window's do
        names = names_of(mode, p)

        def copy_spectrum(c: np.ndarray) -> np.ndarray:
            if not names:
                return cf.spectrum(cells_of(c, geom.cell), geom.window)
            c8 = np.clip(np.rint(c), 0, 255).astype(np.uint8)  # the colour copy's own levels, as the window's
            g = cv2.cvtColor(c8, cv2.COLOR_BGR2GRAY).astype(np.float32)
            return cf.spectrum(cells_of(g, geom.cell, colour_names(c8, geom.cell)), geom.window)

        train = first_sample(x_hat, image if names else grey, centre, geom.template,
                             geom.k(0.0), geom.label_hat if geom.mask is None else None, copy_spectrum, p)
    colour = None
    if mode is not None:
        assert win.bins is not None and win.valid is not None
        colour = histograms(win.bins, win.valid, (geom.size0[0] * geom.k0[0], geom.size0[1] * geom.k0[1]),
                            _n_bins(mode))
    # with segment, the first filter (the anchor too) is solved under the first frame's reliability map
    mask, support = _support(colour, mode, win, geom, p, None)
    det = _solve(train, geom, p, mask)
    scale = None
    if p.scales > 1:
        scale = init_scale(grey, centre, geom.size0, p.scales, p.scale_step, p.scale_area, p.cell,
                           p.scale_upsample, p.scale_anchor)
    if not p.channel_weights:
        return TargetModel(train, det, det, colour, mode, scale, support)
    # with channel_weights, the first weights: the learning reliability alone (CSR-DCF; .channels), which the
    # anchor keeps
    w0 = ch.combine(ch.learning(ch.responses(det, x_hat, (geom.cells[1], geom.cells[0]))))
    return TargetModel(train, det, ch.scaled(det, w0, p.channel_intensity), colour, mode, scale, support, w0)


def detection_filter(model: TargetModel, w: float, intensity: bool) -> np.ndarray:
    """The filter detection uses: (1 - w) the running filter + w the anchor; with channel weights, the
    running filter's channels weighted by them (:func:`.channels.scaled`, the intensity channel too with
    ``intensity``, ``channel_intensity``; the anchor holds its own)."""
    det = model.det if model.channels is None else ch.scaled(model.det, model.channels, intensity)
    if w <= 0:
        return det
    return (1.0 - w) * det + w * model.anchor


@dataclass(frozen=True)
class Response:
    """A response map over target positions.

    y : (h, w) float64; index (i, j) is the target centred at image point ``origin + (j / q_x, i / q_y)``
    (``q`` map px per image px). cubic : read between map positions by bicubic interpolation (a map on
    cells) rather than bilinear (a map upsampled to template px).
    """

    y: np.ndarray
    origin: tuple[float, float]
    q: tuple[float, float]
    cubic: bool = False
    cf: np.ndarray | None = None
    colour: np.ndarray | None = None
    lt: np.ndarray | None = None
    an: np.ndarray | None = None

    def at(self, xy: np.ndarray, part: str = "y") -> np.ndarray:
        """(N,) the response (``part`` "y"; "cf": the filter's alone; "colour": the colour score; "lt": the
        long-term filter's, :mod:`.longterm`; "an": the anchor's alone, :mod:`.drift`) at image points ``xy``
        (N, 2); the map's minimum outside it."""
        m = {"y": self.y, "cf": self.cf, "colour": self.colour, "lt": self.lt, "an": self.an}[part]
        assert m is not None
        u = ((xy[:, 0] - self.origin[0]) * self.q[0]).astype(np.float32).reshape(-1, 1)
        v = ((xy[:, 1] - self.origin[1]) * self.q[1]).astype(np.float32).reshape(-1, 1)
        lo = float(m.min())
        out = remap_points(m.astype(np.float32), u, v, cv2.INTER_CUBIC if self.cubic else cv2.INTER_LINEAR,
                           cv2.BORDER_CONSTANT, lo).astype(np.float64)
        # bicubic interpolation overshoots a little between samples: keep it within the map's range
        return np.clip(out, lo, float(m.max())) if self.cubic else out

    def point(self, i: int, j: int) -> np.ndarray:
        """(x, y) image point of map index (i, j)."""
        return np.array([self.origin[0] + j / self.q[0], self.origin[1] + i / self.q[1]])

    def peak(self) -> tuple[np.ndarray, float]:
        """The image point of the response's maximum and its value."""
        i, j, v = cf.peak(self.y)
        return self.point(i, j), v

    def area(self) -> float:
        """The image area (px^2) of the positions the map covers."""
        return float(self.y.size) / (self.q[0] * self.q[1])

    def best_away(self, xy: np.ndarray, half: tuple[float, float], part: str = "y") -> tuple[float, float] | None:
        """The best response (``part`` as :meth:`at`) at centres farther than ``half`` (hx, hy) image px from
        ``xy`` in x or y (the best look-alike away from the estimate), and the image area (px^2) of those
        centres; None when fewer than 16 map positions are left."""
        m = {"y": self.y, "cf": self.cf, "colour": self.colour, "lt": self.lt}[part]
        assert m is not None
        h, w = m.shape
        xs = self.origin[0] + np.arange(w) / self.q[0]
        ys = self.origin[1] + np.arange(h) / self.q[1]
        mask = (np.abs(ys - xy[1]) >= half[1])[:, None] | (np.abs(xs - xy[0]) >= half[0])[None, :]
        n = int(mask.sum())
        if n < 16:
            return None
        return float(m[mask].max()), n / (self.q[0] * self.q[1])


def _colour_cells(model: TargetModel, win: Window, geom: Geometry) -> np.ndarray | None:
    """The colour score on the window's cells (:func:`.histogram.colour_score`), or None."""
    if model.colour is None or win.bins is None:
        return None
    return colour_score(model.colour, win.bins, geom.cell, geom.box_cells)


def upright(y: np.ndarray, k: tuple[float, float], angle: float) -> np.ndarray:
    """A centred response map ``y`` (h, w) of a window rolled by ``angle`` (index (h // 2, w // 2) the
    window's centre, index offset t the image offset R(angle) K^-1 t, K = diag(kx, ky)) resampled onto
    the unrolled window's grid (index offset t' the image offset K^-1 t'); positions the rolled window
    did not cover take the map's minimum."""
    if not angle:
        return y
    c, s = np.cos(angle), np.sin(angle)
    kx, ky = k
    # t = K R(angle)^T K^-1 t'
    a = np.array([[c, s * kx / ky], [-s * ky / kx, c]])
    o = np.array([y.shape[1] // 2, y.shape[0] // 2], dtype=np.float64)
    m = np.column_stack([a, o - a @ o])
    return cv2.warpAffine(y.astype(np.float32), m, (y.shape[1], y.shape[0]), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                          borderMode=cv2.BORDER_CONSTANT, borderValue=float(y.min())).astype(np.float64)


def respond(model: TargetModel, image: np.ndarray, grey: np.ndarray, centre: tuple[float, float], log_s: float,
            geom: Geometry, p: DCFParams, second: np.ndarray | None = None, angle: float = 0.0,
            anchor: bool = False) -> Response:
    """The response over the window centred at ``centre`` at scale exp(``log_s``) (module docstring);
    with ``second``, a second detection filter (hc, wc // 2 + 1, C) complex, its response on the same
    window as the map ``lt``; with ``anchor``, the first frame's filter's alone as the map ``an``
    (:mod:`.drift`). With ``angle``, the window is rolled by it (the target's roll, :mod:`.rotation`)
    and the maps are turned back onto the unrolled window's grid (:func:`upright`)."""
    k = geom.k(log_s)
    win = window(image, grey, centre, geom.template, k, geom.cell, model.colour_mode, angle,
                 names_of(model.colour_mode, p))
    z_hat = cf.spectrum(win.x, geom.window)
    # Y_cf = sum_l conj(A_l) Z_l / (B + lambda)                                  (DSST eq. 6)
    y_hat = cf.respond(detection_filter(model, p.anchor_weight, p.channel_intensity), z_hat)
    wc, hc = geom.cells
    y_cf = cf.centred(cf.upsample(y_hat, (hc, wc), geom.cell))
    y_lt = None if second is None else cf.centred(cf.upsample(cf.respond(second, z_hat), (hc, wc), geom.cell))
    y_an = cf.centred(cf.upsample(cf.respond(model.anchor, z_hat), (hc, wc), geom.cell)) if anchor else None
    col = _colour_cells(model, win, geom)
    y_col = None if col is None else cf.centred(cf.upsample(np.fft.rfft2(np.fft.ifftshift(col)), (hc, wc), geom.cell))
    # y = (1 - alpha) y_cf + alpha y_hist                                      (Staple eq. 2)
    if angle:
        # the maps of the rolled window on the unrolled window's grid
        y_cf = upright(y_cf, k, angle)
        y_lt = None if y_lt is None else upright(y_lt, k, angle)
        y_an = None if y_an is None else upright(y_an, k, angle)
        y_col = None if y_col is None else upright(y_col, k, angle)
    y = y_cf if y_col is None else (1.0 - p.colour_weight) * y_cf + p.colour_weight * y_col
    # index (h // 2, w // 2) is displacement 0: the target at the window's centre
    origin = (win.centre[0] - (y.shape[1] // 2) / k[0], win.centre[1] - (y.shape[0] // 2) / k[1])
    return Response(y, origin, k, cf=y_cf, colour=y_col, lt=y_lt, an=y_an)


def learn(model: TargetModel, image: np.ndarray, grey: np.ndarray, centre: tuple[float, float], log_s: float,
          geom: Geometry, p: DCFParams, rate: float, scale: bool = True, angle: float = 0.0) -> TargetModel:
    """The model after the sample of the box at ``centre``, scale exp(``log_s``), rolled by ``angle`` (so
    the filter learns the target upright, :mod:`.rotation`): the running filter at ``rate`` (DSST eq. 5),
    the colour histograms at ``colour_rate`` (Staple eq. 7-8) and, with ``scale``, the scale filter at
    ``scale_rate``. The anchor is never changed."""
    k = geom.k(log_s)
    win = window(image, grey, centre, geom.template, k, geom.cell, model.colour_mode, angle,
                 names_of(model.colour_mode, p))
    x_hat = cf.spectrum(win.x, geom.window)
    train: cf.Spectrum | np.ndarray
    if isinstance(model.train, cf.Spectrum):
        # A <- (1 - eta) A + eta conj(G) F,  B <- (1 - eta) B + eta sum |F|^2           (DSST eq. 5)
        train = cf.blend(model.train, cf.train(x_hat, geom.label_hat), rate)
    else:
        # x_model <- (1 - eta) x_model + eta x                                        (BACF sec. 3.3)
        train = (1.0 - rate) * model.train + rate * x_hat
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
    # with segment, the running average is solved under this frame's reliability map (CSR-DCF sec. 3.1)
    mask, support = _support(colour, model.colour_mode, win, geom, p, model.support)
    det = _solve(train, geom, p, mask)
    return TargetModel(train, det, model.anchor, colour, model.colour_mode, sf, support,
                       _channels(model, det, x_hat, geom, rate))


def _channels(model: TargetModel, det: np.ndarray, x_hat: np.ndarray, geom: Geometry, rate: float) -> np.ndarray | None:
    """The running channel weights after the sample of spectrum ``x_hat`` (None without them): the detection
    reliability of the filter before the update, ``model.det``, and the learning reliability of the one
    after it, ``det``, both on the sample (:mod:`.channels`), their product averaged in at ``rate``."""
    if model.channels is None:
        return None
    shape = (geom.cells[1], geom.cells[0])
    frame = ch.combine(ch.learning(ch.responses(det, x_hat, shape)), ch.detection(ch.responses(model.det, x_hat, shape)))
    return ch.blend(model.channels, frame, rate)


def scale_anchor(p: DCFParams) -> float:
    """The first frame's weight in the scale filter's detection: ``anchor_weight`` with ``scale_anchor``,
    as in the translation filter's (:mod:`.scale`), else 0."""
    return p.anchor_weight if p.scale_anchor else 0.0


def scale_change(model: TargetModel, grey: np.ndarray, centre: tuple[float, float], log_s: float, geom: Geometry,
                 p: DCFParams) -> float:
    """The log-scale change the scale filter finds at ``centre`` (0 without one)."""
    if model.scale is None:
        return 0.0
    s = float(np.exp(log_s))
    d, _ = detect_scale(model.scale, grey, centre, (geom.size0[0] * s, geom.size0[1] * s), p.scale_step, p.cell,
                        p.scale_lam, anchor=scale_anchor(p), refine=p.scale_refine)
    return d


def respond_region(model: TargetModel, image: np.ndarray, grey: np.ndarray, hold: np.ndarray,
                   margin: tuple[float, float], log_s: float, geom: Geometry, p: DCFParams) -> Response | None:
    """The response at every cell of centres within ``margin`` (mx, my) px of ``hold`` whose box lies in
    the frame (or whose centre does, for a box larger than the frame), at scale exp(``log_s``): a map on
    cells, read by bicubic interpolation; None when no centre is left. (Outside the frame the window's
    pixels repeat its border, whose stripes can look like anything.)

    At placement c, the window centred at c scores sum_l sum_u h_l(u) w(u) x_l(c + u), h the detection
    filter in the spatial domain and w the cosine window -- what :func:`respond` gives the window's
    centre -- by sliding h w over the region's cells (:func:`.filter.correlate_valid`); the colour score
    of the box at c beside it, and the two merged as :func:`respond` merges them."""
    Hh, Ww = grey.shape
    s = float(np.exp(log_s))
    # the centres whose box (w, h) lies in the frame: [(w - 1) / 2, W - 1 - (w - 1) / 2]
    hw_, hh_ = min(0.5 * (geom.size0[0] * s - 1.0), 0.5 * (Ww - 1.0)), min(0.5 * (geom.size0[1] * s - 1.0), 0.5 * (Hh - 1.0))
    x0, x1 = max(hw_, hold[0] - margin[0]), min(Ww - 1.0 - hw_, hold[0] + margin[0])
    y0, y1 = max(hh_, hold[1] - margin[1]), min(Hh - 1.0 - hh_, hold[1] + margin[1])
    if x1 < x0 or y1 < y0:
        return None
    wc, hc = geom.cells
    kx, ky = geom.k(log_s)
    # centres on a grid of cells: n cells each way of the region's middle, the windows around them
    nx = int(np.ceil(0.5 * (x1 - x0) * kx / geom.cell))
    ny = int(np.ceil(0.5 * (y1 - y0) * ky / geom.cell))
    cw, ch = wc + 2 * nx, hc + 2 * ny
    centre = (0.5 * (x0 + x1), 0.5 * (y0 + y1))
    win = window(image, grey, centre, (cw * geom.cell, ch * geom.cell), (kx, ky), geom.cell, model.colour_mode,
                 names=names_of(model.colour_mode, p))
    # h w: the filter times the cosine window, so that a placement is scored as a windowed sample is
    hw = cf.spatial(detection_filter(model, p.anchor_weight, p.channel_intensity), (hc, wc)) * geom.window[..., None]
    y_cf = cf.correlate_valid(hw, win.x)
    col = _colour_cells(model, win, geom)
    y_col = None if col is None else col[hc // 2: hc // 2 + 2 * ny + 1, wc // 2: wc // 2 + 2 * nx + 1]
    # y = (1 - alpha) y_cf + alpha y_hist                                      (Staple eq. 2)
    y = y_cf if y_col is None else (1.0 - p.colour_weight) * y_cf + p.colour_weight * y_col
    # map index (i, j): the window centred on region cell (i + hc // 2, j + wc // 2), whose centre is
    # (j - nx) cells from the region's middle
    origin = (centre[0] - nx * geom.cell / kx, centre[1] - ny * geom.cell / ky)
    return Response(y, origin, (kx / geom.cell, ky / geom.cell), cubic=True, cf=y_cf, colour=y_col)


@dataclass(frozen=True)
class Candidate:
    """A detection of :func:`search`: the filter's response ``r`` at its centre (x, y) and the colour score
    ``r_colour`` there (None without a colour model), its log-size change ``log_f`` from the searched size,
    and ``area``, the image area (px^2) of the centres searched (summed over the sizes)."""

    r: float
    centre: np.ndarray
    log_f: float
    area: float
    r_colour: float | None = None


def search(model: TargetModel, image: np.ndarray, grey: np.ndarray, hold: np.ndarray, margin: tuple[float, float],
           log_s: float, geom: Geometry, p: DCFParams, log_sizes: tuple[float, ...] = (0.0,)) -> list[Candidate]:
    """The best placement of the target by the filter alone (Staple's colour model is a model of the target
    against its surroundings, not against the whole frame) with its centre within ``margin`` (mx, my) px of
    ``hold`` (and its box in the frame) at each log-size change in ``log_sizes`` (:func:`respond_region`),
    with the colour score there; ``area`` sums the areas searched over the sizes."""
    out = []
    area = 0.0
    for lf in log_sizes:
        r = respond_region(model, image, grey, hold, margin, log_s + lf, geom, p)
        if r is None:
            continue
        assert r.cf is not None
        i, j, v = cf.peak(r.cf)
        xy = r.point(i, j)
        area += r.area()
        c = Candidate(v, xy, float(lf), 0.0, None if r.colour is None else float(r.colour[i, j]))
        out.append(refine(model, image, grey, c, log_s, geom, p) if p.search_refine else c)
    return [Candidate(c.r, c.centre, c.log_f, area, c.r_colour) for c in out]


def refine(model: TargetModel, image: np.ndarray, grey: np.ndarray, c: "Candidate", log_s: float, geom: Geometry,
           p: DCFParams) -> "Candidate":
    """``c`` moved to the best of the placements half a cell about it, each scored by a window of its own.

    The search scores placements on the lattice of its region's cells, so the target lies up to half a cell
    from the nearest one, and its HOG cells straddle the filter's: the response falls, where a tracked frame's
    window is read at the target. Each of the 8 placements half a cell away (each way, both axes) is scored
    by a window centred on it (:func:`respond_region` with no margin), and the best of the 9 is kept: a
    coarse-to-fine search (the refinement of a detector's peak)."""
    kx, ky = geom.k(log_s + c.log_f)
    step = np.array([0.5 * geom.cell / kx, 0.5 * geom.cell / ky])
    best = c
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            if dx == 0 and dy == 0:
                continue
            at = c.centre + step * np.array([dx, dy])
            r = respond_region(model, image, grey, at, (0.0, 0.0), log_s + c.log_f, geom, p)
            if r is None or r.cf is None or r.cf.shape != (1, 1):
                continue
            v = float(r.cf[0, 0])
            if v > best.r:
                best = Candidate(v, r.point(0, 0), c.log_f, c.area, None if r.colour is None else float(r.colour[0, 0]))
    return best
