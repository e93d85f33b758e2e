"""Features of the correlation-filter tracker: HOG cells, cell intensity, colour bins, the window.

* :func:`hog` -- Felzenszwalb et al.'s HOG variant (PAMI 2010, sec. 6.1 and 6.2, "fHOG", the
  feature of KCF, DSST, Staple and CSRT) on cells of ``cell`` x ``cell`` pixels: 18
  contrast-sensitive and 9 contrast-insensitive orientation channels, each normalised by the
  energy of the four 2 x 2-cell blocks around its cell and truncated at 0.2, plus 4 texture
  channels (the gradient energy under each of those normalisations): 31 channels. Departures:
  each pixel's vote goes to its own cell (no bilinear spatial interpolation), and the
  gradient is that of the grey levels (fHOG takes the colour channel of largest gradient).
  It works on a batch of patches at once (the scale filter samples 17 of them a frame).
* :func:`intensity` -- the cell means of the grey levels, centred (KCF and CSRT add it to HOG).
* :func:`colour_names` -- the cell means of each pixel's membership of the 11 basic colour names,
  centred (the CN tracker's and CSRT's colour feature; with ``colour_names``, off by default, on
  colour frames), by soft nearness to a prototype of each name in CIELab (a departure: those
  trackers use van de Weijer et al.'s table learnt from images).
* :func:`colour_bins` -- per-pixel histogram bins for Staple's colour model: 32 levels per
  channel of a colour frame (32^3 bins), 32 grey levels of a grey one.
* :func:`is_grey` -- whether a frame is grey (one channel, or three equal ones: JPEG frames of
  grey video).
* :func:`cosine_window` -- the Hann window that tapers a sample's borders (Bolme et al. 2010;
  Henriques et al. 2015, sec. 6.1).
* :func:`sample` -- a window of the frame around a centre, resampled so that ``k`` output pixels
  span one image pixel (anti-aliased when shrinking), rolled by an angle about the centre if asked.

Images are indexed (row, col); points are (x, y) pixels with the origin at the top-left pixel
centre.
"""

from __future__ import annotations

import functools
import math

import cv2
import numpy as np

__all__ = ["N_HOG", "N_ORIENT", "N_NAMES", "hog", "intensity", "colour_names", "colour_bins", "is_grey", "cosine_window", "sample",
           "N_COLOUR_BINS", "N_GREY_BINS", "GREY_TOLERANCE"]

#: contrast-sensitive orientations of fHOG (over 2 pi); the insensitive ones are half as many
N_ORIENT = 18
#: channels of :func:`hog`: 18 sensitive + 9 insensitive + 4 texture
N_HOG = 31
#: fHOG's truncation of the normalised orientation energy
_TRUNC = 0.2
#: colour bins of a colour frame (32 levels per channel) and of a grey one
N_COLOUR_BINS = 32 ** 3
N_GREY_BINS = 32
#: three channels that differ by at most this many grey levels are taken as grey (JPEG of grey frames)
GREY_TOLERANCE = 2


def hog(patches: np.ndarray, cell: int) -> np.ndarray:
    """fHOG cells of grey patches.

    Parameters
    ----------
    patches : (..., H, W) float32 or uint8
        Grey levels 0-255; H and W multiples of ``cell``.
    cell : int
        Cell size in pixels (4 in KCF, DSST, CSRT).

    Returns
    -------
    (..., H / cell, W / cell, 31) float32
        Per cell: 18 contrast-sensitive orientation channels, 9 insensitive ones, 4 texture channels.
    """
    g = np.asarray(patches, dtype=np.float32)
    *lead, H, W = g.shape
    if H % cell or W % cell or H < 2 * cell or W < 2 * cell:
        raise ValueError(f"hog needs patches of at least two cells whose sides are multiples of {cell}, "
                         f"got {H}x{W}")
    hc, wc = H // cell, W // cell
    # centred differences [-1, 0, 1], one-sided at the border
    gx = np.empty_like(g)
    gy = np.empty_like(g)
    gx[..., 1:-1] = g[..., 2:] - g[..., :-2]
    gx[..., 0] = 2.0 * (g[..., 1] - g[..., 0])
    gx[..., -1] = 2.0 * (g[..., -1] - g[..., -2])
    gy[..., 1:-1, :] = g[..., 2:, :] - g[..., :-2, :]
    gy[..., 0, :] = 2.0 * (g[..., 1, :] - g[..., 0, :])
    gy[..., -1, :] = 2.0 * (g[..., -1, :] - g[..., -2, :])
    mag = np.sqrt(gx * gx + gy * gy)
    # signed orientation in bin units: t = (atan2(gy, gx) mod 2 pi) * 18 / (2 pi), linear vote to the two nearest bins
    t = np.arctan2(gy, gx) * np.float32(N_ORIENT / (2.0 * np.pi))
    t[t < 0] += np.float32(N_ORIENT)
    b0 = np.floor(t)
    w1 = t - b0
    b0i = b0.astype(np.int64) % N_ORIENT
    b1i = (b0i + 1) % N_ORIENT
    # the index of every pixel's cell, over the batch: ((batch * hc + row // cell) * wc + col // cell)
    nb = int(np.prod(lead)) if lead else 1
    rows = np.arange(H) // cell
    cols = np.arange(W) // cell
    cell_id = (np.arange(nb)[:, None, None] * hc + rows[None, :, None]) * wc + cols[None, None, :]
    cell_id = cell_id.reshape(-1) * N_ORIENT
    m = mag.reshape(-1)
    n_cells = nb * hc * wc
    w1f = w1.reshape(-1)
    # h(cell, b) = sum over the cell's pixels of |g| times the vote to bin b
    votes = (np.bincount(cell_id + b0i.reshape(-1), weights=m * (1.0 - w1f), minlength=n_cells * N_ORIENT)
             + np.bincount(cell_id + b1i.reshape(-1), weights=m * w1f, minlength=n_cells * N_ORIENT))
    hist = votes.astype(np.float64).reshape(nb, hc, wc, N_ORIENT) / float(cell * cell)
    half = N_ORIENT // 2
    insens = hist[..., :half] + hist[..., half:]
    # block energy: E(i, j) = sum_b h_insensitive(i, j, b)^2, padded by replication
    energy = np.pad((insens * insens).sum(-1), ((0, 0), (1, 1), (1, 1)), mode="edge")
    out = np.zeros((nb, hc, wc, N_HOG), dtype=np.float64)
    for k, (dy, dx) in enumerate(((-1, -1), (-1, 1), (1, -1), (1, 1))):
        # N_k(i, j) = (E(i, j) + E(i + dy, j) + E(i, j + dx) + E(i + dy, j + dx) + eps)^(-1/2)   (fHOG sec. 6.1)
        e = energy[:, 1:-1, 1:-1]
        ey = energy[:, 1 + dy:hc + 1 + dy, 1:-1]
        ex = energy[:, 1:-1, 1 + dx:wc + 1 + dx]
        exy = energy[:, 1 + dy:hc + 1 + dy, 1 + dx:wc + 1 + dx]
        norm = 1.0 / np.sqrt(e + ey + ex + exy + 1e-4)
        s = np.minimum(hist * norm[..., None], _TRUNC)
        u = np.minimum(insens * norm[..., None], _TRUNC)
        # the 27 orientation channels sum the four normalisations (x 0.5, fHOG's analytic projection)
        out[..., :N_ORIENT] += 0.5 * s
        out[..., N_ORIENT:N_ORIENT + half] += 0.5 * u
        # texture channel k: 0.2357 sum_b of the sensitive channels under normalisation k
        out[..., N_ORIENT + half + k] = 0.2357 * s.sum(-1)
    return out.reshape(*lead, hc, wc, N_HOG).astype(np.float32)


def intensity(patches: np.ndarray, cell: int) -> np.ndarray:
    """Cell means of grey levels, in [-0.5, 0.5]: (..., H / cell, W / cell, 1) float32 of (..., H, W)."""
    g = np.asarray(patches, dtype=np.float32)
    *lead, H, W = g.shape
    m = g.reshape(*lead, H // cell, cell, W // cell, cell).mean(axis=(-3, -1))
    return (m / np.float32(255.0) - np.float32(0.5))[..., None]


#: the 11 basic colour terms (Berlin & Kay 1969) as sRGB prototypes: black, blue, brown, grey, green, orange,
#: pink, purple, red, white, yellow
_NAME_RGB = np.array([[0, 0, 0], [40, 70, 200], [130, 80, 40], [128, 128, 128], [40, 160, 60], [245, 135, 30],
                      [245, 165, 195], [130, 50, 160], [215, 30, 35], [255, 255, 255], [240, 220, 40]], np.float32)
N_NAMES = len(_NAME_RGB)
#: the spread of a name about its prototype (Lab units)
_NAME_SIGMA = 20.0


@functools.cache
def _name_table() -> np.ndarray:
    """(32^3, 11) float32: each colour bin's membership of the names (:func:`colour_bins`' bins of a colour frame,
    the bin's centre colour), centred -- a table as the CN tracker's, indexed by 32 levels a channel. Made on
    first use, not at import: OpenCV's colour conversion of 32^3 colours starts its worker threads, and a
    process that imports this module before it forks (the stage processes' zygote, pipeline/runtime/zygote.py)
    must have none."""
    # the prototypes in CIELab (L 0-100)
    name_lab = cv2.cvtColor((_NAME_RGB[None, :, ::-1] / 255.0).astype(np.float32), cv2.COLOR_BGR2Lab)[0]
    q = (np.arange(32, dtype=np.float32) * 8.0 + 3.5) / 255.0
    b, g, r = np.meshgrid(q, q, q, indexing="ij")  # bin (B >> 3) * 1024 + (G >> 3) * 32 + (R >> 3)
    lab = cv2.cvtColor(np.stack([b, g, r], axis=-1).reshape(1, -1, 3), cv2.COLOR_BGR2Lab)[0]
    # d2_n = |lab - lab_n|^2, p_n = exp(-d2_n / 2 sigma^2) / sum_m exp(-d2_m / 2 sigma^2)
    d2 = ((lab[:, None, :] - name_lab[None, :, :]) ** 2).sum(-1)
    e = np.exp(-(d2 - d2.min(-1, keepdims=True)) / (2.0 * _NAME_SIGMA ** 2))
    return (e / e.sum(-1, keepdims=True) - 1.0 / N_NAMES).astype(np.float32)


def colour_names(patch: np.ndarray, cell: int) -> np.ndarray:
    """Cell means of each pixel's membership of the 11 basic colour names, centred: (h / cell, w / cell, 11)
    float32 of a BGR patch (h, w, 3) uint8. A pixel's membership of name n is
    exp(-|lab - lab_n|^2 / (2 sigma^2)) normalised over the names, lab the centre of its colour bin (32 levels
    a channel, as :func:`colour_bins`) in CIELab and lab_n the name's prototype, read from a table.

    Departure: the colour-name feature of the CN tracker (Danelljan et al. CVPR 2014) and CSRT maps a
    pixel to the 11 names by van de Weijer et al.'s table learnt from images (TIP 2009); here by soft
    nearness to a prototype of each name in CIELab."""
    h, w = patch.shape[:2]
    pn = _name_table()[colour_bins(patch, grey=False)]
    return pn.reshape(h // cell, cell, w // cell, cell, N_NAMES).mean(axis=(1, 3), dtype=np.float32)


def is_grey(image: np.ndarray) -> bool:
    """Whether ``image`` ((H, W) or (H, W, 3) uint8) holds grey levels only: one channel, or three whose
    values differ by at most ``GREY_TOLERANCE`` at every pixel (checked on every 4th row and column)."""
    if image.ndim == 2 or image.shape[2] == 1:
        return True
    sub = image[::4, ::4].astype(np.int16)
    return bool(np.abs(sub[..., 0] - sub[..., 1]).max() <= GREY_TOLERANCE
                and np.abs(sub[..., 1] - sub[..., 2]).max() <= GREY_TOLERANCE)


def colour_bins(image: np.ndarray, grey: bool) -> np.ndarray:
    """(H, W) int32 histogram bin of every pixel: ``(B >> 3) * 1024 + (G >> 3) * 32 + (R >> 3)`` of a BGR
    frame (``grey`` False), ``grey >> 3`` of a grey one."""
    if grey:
        g = image if image.ndim == 2 else image[..., 0]
        return (g >> 3).astype(np.int32)
    q = (image >> 3).astype(np.int32)
    return (q[..., 0] << 10) | (q[..., 1] << 5) | q[..., 2]


def cosine_window(h: int, w: int) -> np.ndarray:
    """(h, w) float32 Hann window, the outer product of two 1-D ones (zero at the borders)."""
    return np.outer(np.hanning(h), np.hanning(w)).astype(np.float32)


def sample(image: np.ndarray, centre: tuple[float, float], out_size: tuple[int, int],
           k: float | tuple[float, float], angle: float = 0.0) -> np.ndarray:
    """The window of ``image`` centred at ``centre`` (x, y), resampled so that ``k`` output pixels span
    one image pixel: output pixel (u, v) shows image point ``centre + ((u, v) - (out - 1) / 2) / k``.

    Parameters
    ----------
    image : (H, W) or (H, W, C) array (uint8 or float32); the border is replicated outside it.
    out_size : (w, h) of the output in pixels.
    k : output pixels per image pixel, one number or (kx, ky); below 1 the image is blurred first
        (sigma 0.4 / k) against aliasing.
    angle : radians the window is rolled by about ``centre``: output pixel (u, v) shows image point
        ``centre + R(angle) ((u, v) - (out - 1) / 2) / k`` (x right, y down: a positive angle turns the
        window clockwise on the screen), so a target rolled by ``angle`` comes out upright.

    Returns
    -------
    (h, w) or (h, w, C) array of ``image``'s dtype.
    """
    ow, oh = int(out_size[0]), int(out_size[1])
    kx, ky = (float(k), float(k)) if isinstance(k, (int, float)) else (float(k[0]), float(k[1]))
    cx, cy = float(centre[0]), float(centre[1])
    H, W = image.shape[:2]
    # the image pixels the window covers, plus a margin for the blur and the interpolation
    half_w, half_h = 0.5 * ow / kx, 0.5 * oh / ky
    if angle:
        # a rolled window covers at most the circle about its corners
        half_w = half_h = float(np.hypot(half_w, half_h))
    kmin = min(kx, ky)
    blur = 0.4 / kmin if kmin < 1 else 0.0
    m = 2.0 + 3.0 * blur
    x0 = int(np.clip(np.floor(cx - half_w - m), 0, W - 1))
    y0 = int(np.clip(np.floor(cy - half_h - m), 0, H - 1))
    x1 = int(np.clip(np.ceil(cx + half_w + m) + 1, x0 + 1, W))
    y1 = int(np.clip(np.ceil(cy + half_h + m) + 1, y0 + 1, H))
    crop = image[y0:y1, x0:x1]
    if blur > 0 and crop.shape[0] > 1 and crop.shape[1] > 1:
        crop = cv2.GaussianBlur(crop, (0, 0), blur)
    # output (u, v) -> crop (x, y) = centre - (x0, y0) + ((u, v) - (out - 1) / 2) / k
    if angle:
        # output (u, v) -> crop (x, y) = centre - (x0, y0) + R(angle) diag(1 / kx, 1 / ky) ((u, v) - (out - 1) / 2)
        c, s = math.cos(angle), math.sin(angle)
        a = np.array([[c / kx, -s / ky], [s / kx, c / ky]])
        o = np.array([(ow - 1) / 2.0, (oh - 1) / 2.0])
        M = np.column_stack([a, np.array([cx - x0, cy - y0]) - a @ o])
    else:
        M = np.array([[1.0 / kx, 0.0, cx - x0 - (ow - 1) / 2.0 / kx],
                      [0.0, 1.0 / ky, cy - y0 - (oh - 1) / 2.0 / ky]], dtype=np.float64)
    return cv2.warpAffine(crop, M, (ow, oh), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                          borderMode=cv2.BORDER_REPLICATE)
