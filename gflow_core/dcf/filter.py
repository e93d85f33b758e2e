"""The discriminative correlation filter: closed-form ridge regression in the Fourier domain.

A multichannel linear correlation filter h = (h_1 ... h_C) is the ridge regression of a
desired response g (a Gaussian peaked at zero displacement) on every cyclic shift of a training
sample f (the target and the background around it, tapered by a cosine window). Over cyclic
shifts the data matrix is circulant, diagonalised by the DFT, so the normal equations decouple
per frequency (Henriques et al., PAMI 2015, sec. 4.4, eq. 12 for one channel; with C channels
and a shared denominator this is the filter of Danelljan et al., BMVC 2014, eq. 3, of
Bolme et al.'s MOSSE, CVPR 2010, eq. 10, for C = 1):

    H_l = conj(G) F_l / (sum_k conj(F_k) F_k + lambda)                      (DSST eq. 3)

Online, numerator and denominator are running averages at the learning rate eta
(DSST eq. 5, MOSSE eq. 11-13):

    A_l <- (1 - eta) A_l + eta conj(G) F_l,     B <- (1 - eta) B + eta sum_k conj(F_k) F_k,

and the response to a test sample z over every displacement is

    y = F^-1 { sum_l conj(A_l) Z_l / (B + lambda) }                          (DSST eq. 6)

so that y(d) is large where z holds the training sample displaced by d.

Arrays: samples are (h, w, C) float32 cell features with h and w odd (so no Nyquist bin needs
splitting when a response is upsampled); spectra are ``numpy.fft.rfft2`` over the first two axes,
(h, w // 2 + 1, C) complex128. Index (i, j) of a response is the displacement (i, j) cells,
cyclic: rows past h // 2 are negative displacements.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Spectrum", "gaussian_label", "spectrum", "train", "blend", "respond", "upsample", "centred",
           "spatial", "correlate_full", "peak", "sidelobe"]


@dataclass(frozen=True)
class Spectrum:
    """A filter as its numerator and denominator (DSST eq. 5): ``num`` (h, w // 2 + 1, C) complex128,
    ``den`` (h, w // 2 + 1) float64; the filter is num / (den + lambda)."""

    num: np.ndarray
    den: np.ndarray


def gaussian_label(h: int, w: int, sigma: float) -> np.ndarray:
    """(h, w) float64 desired response: g(d) = exp(-|d|^2 / (2 sigma^2)) over cyclic displacements d
    (cells), peaked at index (0, 0) (Henriques et al. 2015, sec. 6.1: sigma ~ 0.1 of the target size)."""
    dy = np.fft.fftfreq(h) * h
    dx = np.fft.fftfreq(w) * w
    # g(dy, dx) = exp(-(dx^2 + dy^2) / (2 sigma^2))
    return np.exp(-(dy[:, None] ** 2 + dx[None, :] ** 2) / (2.0 * sigma * sigma))


def spectrum(x: np.ndarray, window: np.ndarray) -> np.ndarray:
    """F = DFT of the windowed sample: x (h, w, C) float32 times window (h, w), rfft2 over the cells."""
    return np.fft.rfft2(x * window[..., None], axes=(0, 1))


def train(f_hat: np.ndarray, g_hat: np.ndarray) -> Spectrum:
    """The numerator and denominator of one sample (DSST eq. 3): A_l = conj(G) F_l, B = sum_k |F_k|^2.

    f_hat : (h, w', C) complex spectrum of the windowed sample; g_hat : (h, w') rfft2 of the label."""
    # A_l = conj(G) F_l
    num = np.conj(g_hat)[..., None] * f_hat
    # B = sum_k conj(F_k) F_k
    den = np.einsum("ijc,ijc->ij", f_hat.real, f_hat.real) + np.einsum("ijc,ijc->ij", f_hat.imag, f_hat.imag)
    return Spectrum(num, den)


def blend(old: Spectrum, new: Spectrum, eta: float) -> Spectrum:
    """The running average at rate ``eta`` (DSST eq. 5): A <- (1 - eta) A + eta A_new, B likewise."""
    return Spectrum((1.0 - eta) * old.num + eta * new.num, (1.0 - eta) * old.den + eta * new.den)


def respond(filt: Spectrum, z_hat: np.ndarray, lam: float) -> np.ndarray:
    """Y = sum_l conj(A_l) Z_l / (B + lambda) (DSST eq. 6): (h, w') complex spectrum of the response."""
    # sum_l conj(A_l) Z_l (einsum: its sums are in a fixed order, the same bits in any process)
    s = (np.einsum("ijc,ijc->ij", filt.num.real, z_hat.real) + np.einsum("ijc,ijc->ij", filt.num.imag, z_hat.imag)
         + 1j * (np.einsum("ijc,ijc->ij", filt.num.real, z_hat.imag)
                 - np.einsum("ijc,ijc->ij", filt.num.imag, z_hat.real)))
    return s / (filt.den + lam)


def upsample(y_hat: np.ndarray, shape: tuple[int, int], factor: int) -> np.ndarray:
    """The response of spectrum ``y_hat`` (rfft2 of an (h, w) map, h and w odd) on a grid ``factor``
    times finer, by zero-padding the spectrum (band-limited interpolation): (h factor, w factor)
    float64, index (i, j) the displacement (i / factor, j / factor) cells, cyclic."""
    h, w = shape
    H, W = h * factor, w * factor
    big = np.zeros((H, W // 2 + 1), dtype=np.complex128)
    top = (h + 1) // 2
    big[:top, : y_hat.shape[1]] = y_hat[:top]
    big[H - (h - top):, : y_hat.shape[1]] = y_hat[top:]
    # the inverse DFT of the padded spectrum, scaled so values keep their amplitude
    return np.fft.irfft2(big, s=(H, W)) * (H * W / float(h * w))


def centred(y: np.ndarray) -> np.ndarray:
    """A cyclic response with displacement 0 moved to index (h // 2, w // 2) (``fftshift``)."""
    return np.fft.fftshift(y)


def spatial(filt: Spectrum, lam: float, shape: tuple[int, int]) -> np.ndarray:
    """The filter in the spatial domain: h_l = F^-1 { A_l / (B + lambda) }, (h, w, C) float64 in the
    window's own cells (the response to z at displacement d is sum_x h(x) z(x + d), cyclic)."""
    H = filt.num / (filt.den + lam)[..., None]
    return np.fft.irfft2(H, s=shape, axes=(0, 1))


def correlate_full(h: np.ndarray, feats: np.ndarray) -> np.ndarray:
    """The filter ``h`` (fh, fw, C) (:func:`spatial`) correlated with a larger map of cells ``feats``
    (H, W, C): (H, W) float64, y(i, j) = sum_l sum_(u, v) h_l(u, v) x_l(i + u - fh // 2, j + v - fw // 2),
    zero outside the map: y(i, j) scores the window centred on cell (i, j), i.e. the target there."""
    fh, fw = h.shape[:2]
    Hh, Ww = feats.shape[:2]
    sh, sw = Hh + fh, Ww + fw
    # correlation = convolution with the flipped filter; by DFTs of the zero-padded maps
    fx = np.fft.rfft2(feats, s=(sh, sw), axes=(0, 1))
    fk = np.fft.rfft2(h[::-1, ::-1], s=(sh, sw), axes=(0, 1))
    prod = np.einsum("ijc,ijc->ij", fx.real, fk.real) - np.einsum("ijc,ijc->ij", fx.imag, fk.imag) + 1j * (
        np.einsum("ijc,ijc->ij", fx.real, fk.imag) + np.einsum("ijc,ijc->ij", fx.imag, fk.real))
    full = np.fft.irfft2(prod, s=(sh, sw))
    # full(i, j) = sum h(fh - 1 - a, fw - 1 - b) x(i - a, j - b): the centre of h on cell (i, j) at
    # i + (fh - 1) - fh // 2, j + (fw - 1) - fw // 2
    oy, ox = fh - 1 - fh // 2, fw - 1 - fw // 2
    return full[oy:oy + Hh, ox:ox + Ww]


def peak(y: np.ndarray) -> tuple[int, int, float]:
    """(row, col, value) of the maximum of a map (the first, in row-major order, of equal maxima)."""
    i = int(np.argmax(y))
    r, c = divmod(i, y.shape[1])
    return r, c, float(y[r, c])


def sidelobe(y: np.ndarray, r: int, c: int, half: tuple[int, int]) -> float:
    """The best value of a centred map ``y`` outside the rectangle of half-sides ``half`` (rows, cols)
    around (r, c) -- the best look-alike away from the peak; -inf when nothing is left."""
    mask = np.ones(y.shape, dtype=bool)
    mask[max(0, r - half[0]): r + half[0] + 1, max(0, c - half[1]): c + half[1] + 1] = False
    return float(y[mask].max()) if mask.any() else -np.inf
