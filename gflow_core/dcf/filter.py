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

    y = F^-1 { sum_l conj(A_l) Z_l / (B + lambda) } = F^-1 { sum_l D_l Z_l }   (DSST eq. 6)

so that y(d) is large where z holds the training sample displaced by d.

Arrays: samples are (h, w, C) float32 cell features with h and w odd (so no Nyquist bin needs
splitting when a response is upsampled); spectra are ``numpy.fft.rfft2`` over the first two axes,
(h, w // 2 + 1, C) complex128. Index (i, j) of a response is the displacement (i, j) cells,
cyclic: rows past h // 2 are negative displacements.

The transforms are numpy's (pocketfft). :func:`correlate_valid` pads to a 5-smooth length
(:func:`fast_length`) and inverts in the order scipy.fft does (the complex transform over rows
unscaled, the real one over columns, then one scaling by 1 / (sh sw)), so that its bits are those
scipy.fft gave while importing scipy cost each process 0.4 s of CPU.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Spectrum", "gaussian_label", "spectrum", "train", "blend", "detector", "respond", "upsample", "centred",
           "spatial", "correlate_valid", "fast_length", "peak", "sidelobe"]


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
    """F = DFT of the windowed sample: x (h, w, C) times window (h, w), rfft2 over the cells, complex128."""
    return np.fft.rfft2(x.astype(np.float64) * window[..., None], axes=(0, 1))


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


def detector(filt: Spectrum, lam: float) -> np.ndarray:
    """The filter as detection applies it: D_l = conj(A_l) / (B + lambda), (h, w', C) complex, so that the
    response's spectrum is Y = sum_l D_l Z_l (DSST eq. 6)."""
    return np.conj(filt.num) / (filt.den + lam)[..., None]


def respond(det: np.ndarray, z_hat: np.ndarray) -> np.ndarray:
    """Y = sum_l D_l Z_l (DSST eq. 6 with D = :func:`detector`): (h, w') complex spectrum of the response."""
    # sum over channels by einsum: a fixed order of summation, the same bits in any process
    return (np.einsum("ijc,ijc->ij", det.real, z_hat.real) - np.einsum("ijc,ijc->ij", det.imag, z_hat.imag)
            + 1j * (np.einsum("ijc,ijc->ij", det.real, z_hat.imag) + np.einsum("ijc,ijc->ij", det.imag, z_hat.real)))


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


def spatial(det: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """The filter in the spatial domain, h_l = F^-1 { conj(D_l) }: (h, w, C) float64 in the window's own
    cells, so that the response to z at displacement d is sum_x h(x) z(x + d), cyclic."""
    return np.fft.irfft2(np.conj(det), s=shape, axes=(0, 1))


def correlate_valid(h: np.ndarray, feats: np.ndarray) -> np.ndarray:
    """The filter ``h`` (fh, fw, C) (:func:`spatial`) slid over a larger map of cells ``feats`` (H, W, C):
    (H - fh + 1, W - fw + 1) float64,

        y(i, j) = sum_l sum_(u, v) h_l(u, v) x_l(i + u, j + v),

    the score of the window whose top-left cell is (i, j) (its centre at (i + fh // 2, j + fw // 2)),
    for every window that lies inside the map. By DFTs of a fast length (the wrapped parts fall outside
    the windows kept)."""
    fh, fw = h.shape[:2]
    Hh, Ww = feats.shape[:2]
    if Hh < fh or Ww < fw:
        raise ValueError(f"the map ({Hh}x{Ww} cells) is smaller than the filter ({fh}x{fw})")
    sh, sw = fast_length(Hh), fast_length(Ww)
    # y = x correlated with h = F^-1 { X conj(H) } over the (zero-padded) map
    fx = np.fft.rfft2(feats.astype(np.float64), s=(sh, sw), axes=(0, 1))
    fk = np.fft.rfft2(h, s=(sh, sw), axes=(0, 1))
    prod = (np.einsum("ijc,ijc->ij", fx.real, fk.real) + np.einsum("ijc,ijc->ij", fx.imag, fk.imag)
            + 1j * (np.einsum("ijc,ijc->ij", fx.imag, fk.real) - np.einsum("ijc,ijc->ij", fx.real, fk.imag)))
    # F^-1 over rows (complex, unscaled), then over columns (complex to real), scaled once by 1 / (sh sw)
    rows = np.fft.ifft(prod, axis=0, norm="forward")
    return (np.fft.irfft(rows, n=sw, axis=1, norm="forward") * (1.0 / (sh * sw)))[: Hh - fh + 1, : Ww - fw + 1]


def fast_length(n: int) -> int:
    """The smallest 5-smooth integer (2^a 3^b 5^c) at least ``n`` >= 1: a length pocketfft transforms
    without Bluestein's algorithm (scipy.fft.next_fast_len(n, real=True))."""
    best = 1 << max(n - 1, 0).bit_length()  # a power of 2 is 5-smooth
    p5 = 1
    while p5 < best:
        p35 = p5
        while p35 < best:
            # the least power of 2 that lifts p35 to n or beyond
            q = p35 << max(0, (-(-n // p35) - 1).bit_length())
            best = min(best, q)
            p35 *= 3
        p5 *= 5
    return best


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
