"""The 1-D scale filter of DSST (Danelljan, Hager, Khan & Felsberg, BMVC 2014, sec. 3.2).

At the estimated position, S patches of the target's size times a^n (n = -(S-1)/2 ... (S-1)/2,
a the scale step) are resampled to one model size; their fHOG cells, flattened, make a
(S, D) sample whose rows are ordered by scale. A correlation filter along the scale axis (one
dimension, D channels; the same closed form as the translation filter, DSST eq. 3, 5, 6)
learns to answer with a Gaussian peaked at the middle row, so its response to a new sample
peaks at the row of the target's present scale.

Departures: 17 scales, as fDSST (Danelljan et al., PAMI 2017) samples, without its PCA. fDSST
interpolates the response to 33 scales and takes their best, a half step; DSST takes the best of its
own. Here the best of the 17 is taken, whole steps of ``scale_step`` (2 %), unless ``scale_refine``
(off by default) refines the peak by the parabola through it and its neighbours, to any size between
them: a size that changes slowly (a walker going away, 0.1 % a frame) is then followed rather than
held until it has changed by a step, but so is a drift of the running filter's idea of the size,
which the whole steps hold back; it stays off because on the shared sequences it loses more than it
gains (docs/dcf-development.md, "The scale filter's peak between its scales"). DSST resamples a
target larger than its model area down to it and samples a smaller one at its own size; with
``scale_upsample`` (on by default; off, DSST's rule) a smaller one is resampled up to the model area
too. A target of 16 x 18 px at its own size gives a sample of 4 x 4 cells of
4 px, in which a step of 2 % in scale moves an edge by a third of a pixel: the response over the
scales is all but flat and its peak wanders from frame to frame, walking the size (on the shared
sequences at half size, ``gflow benchmark --variant small``, the surfer's box grew from 16 x 18 to 24 x 26 with
its centre within 5 px, and jumping's face shrank from 19 to 14 px as it grew). Resampled to the
model area, every target is seen at the same number of cells (docs/dcf-development.md, "A small
target's size" and "Colour names, a small target's size and the roll at detection on by default").
With a prior (``scale_prior``, :mod:`.sizeprior`) the pick is the mode of
the response read as a likelihood times a Gaussian prior on the log size (:func:`size_posterior`);
DSST has no prior on the size.

The first frame's filter (``scale_anchor``, off by default): DSST's scale filter is a running average only
(eq. 5), so nothing ties its idea of the target's size to the size the user gave. Where its response
over the scales is flat (a small target, blur), a slight lean toward one side takes a step, the
filter learns the box at the new size as its middle, and the size walks with nothing pulling it back
(the half-size surfer's head grew from 16 x 18 to 24 x 26 px). The tracker's translation filter has
the same weakness and the same remedy already: detection uses (1 - w) the running filter plus w the
first frame's, never updated (``anchor_weight``, :mod:`.model`). With ``scale_anchor`` the scale
filter keeps its first frame's numerator and denominator beside the running ones and detects with the
same mixture, w = ``anchor_weight``:

    y = F^-1 { sum_d conj((1 - w) A_d + w A0_d) Z_d / ((1 - w) B + w B0 + lambda) }.

The first frame's filter answers the target's size relative to the first box, at whatever size the
box now has (its rows are the first box times a^n), so a size that really changes is still followed.
Departure: DSST and fDSST have no anchor in either filter; the anchor of the translation filter is
ours too (:mod:`.model`). It is off by default: on the shared sequences it adds AUC on the whole and on
blurred and half-size footage, but loses it on every 3rd frame and on grey david_indoor, and gets
fewer stress cases back (docs/dcf-development.md, "The scale filter's first frame").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .features import hog, sample

__all__ = ["ScaleFilter", "model_size", "scale_sample", "init_scale", "learn_scale", "detect_scale", "size_posterior"]


@dataclass(frozen=True)
class ScaleFilter:
    """The scale filter: ``num`` (S, D) complex128 and ``den`` (S,) float64 (DSST eq. 5), ``label_hat``
    (S,) the DFT of the desired response, ``model`` (w, h) the samples' size in pixels; ``anchor_num``
    (S, D) and ``anchor_den`` (S,) the first frame's ``num`` and ``den``, never updated (None unless
    ``scale_anchor`` kept them: detection then uses the running filter alone)."""

    num: np.ndarray
    den: np.ndarray
    label_hat: np.ndarray
    model: tuple[int, int]
    anchor_num: np.ndarray | None = None
    anchor_den: np.ndarray | None = None


def model_size(size0: tuple[float, float], area: int, cell: int, upsample: bool = False) -> tuple[int, int]:
    """(w, h) pixels of the scale samples: the target's aspect, at most ``area`` pixels (DSST's 512),
    whole cells, at least 2 cells a side; with ``upsample``, about ``area`` pixels whatever the target's
    size (a smaller target is resampled up to it)."""
    w, h = float(size0[0]), float(size0[1])
    # f = sqrt(area / (w h)), capped at 1 unless upsampled
    f = float(np.sqrt(area / (w * h)))
    if not upsample:
        f = min(1.0, f)
    return (max(2, int(round(w * f / cell))) * cell, max(2, int(round(h * f / cell))) * cell)


def scale_sample(grey: np.ndarray, centre: tuple[float, float], size: tuple[float, float], factors: np.ndarray,
                 model: tuple[int, int], cell: int) -> np.ndarray:
    """(S, D) float64: row n is the fHOG cells of the box of ``size`` (w, h) times ``factors[n]`` at
    ``centre``, resampled to ``model`` (w, h) pixels, flattened, times the 1-D Hann window over scales."""
    mw, mh = model
    patches = np.empty((len(factors), mh, mw), dtype=np.float32)
    for n, f in enumerate(factors):
        # k = model pixels per image pixel of the box at this scale (the larger of the two, so it covers the box)
        k = max(mw / (size[0] * f), mh / (size[1] * f))
        patches[n] = sample(grey, centre, (mw, mh), k)
    x = hog(patches, cell).reshape(len(factors), -1).astype(np.float64)
    # the window over scales tapers the extreme ones (DSST sec. 3.2)
    return x * np.hanning(len(factors) + 2)[1:-1, None]


def _factors(n: int, step: float) -> np.ndarray:
    """a^i for i = -(n - 1) / 2 ... (n - 1) / 2."""
    return step ** (np.arange(n) - (n - 1) // 2).astype(np.float64)


def init_scale(grey: np.ndarray, centre: tuple[float, float], size: tuple[float, float], n: int, step: float,
               area: int, cell: int, upsample: bool = False, anchor: bool = False) -> ScaleFilter:
    """The scale filter of the first frame: one sample (DSST eq. 3); the label is a Gaussian over the
    scale index of std sqrt(S) / 4 peaked at the middle row (DSST sec. 4). ``upsample``: see
    :func:`model_size`; ``anchor``: keep this frame's filter beside the running one (``scale_anchor``)."""
    model = model_size(size, area, cell, upsample)
    idx = np.arange(n) - (n - 1) // 2
    sigma = np.sqrt(n) / 4.0
    # g(n) = exp(-n^2 / (2 sigma^2)), n the scale index about the middle
    label_hat = np.fft.fft(np.exp(-0.5 * idx ** 2 / sigma ** 2))
    f = np.fft.fft(scale_sample(grey, centre, size, _factors(n, step), model, cell), axis=0)
    # A = conj(G) F, B = sum_d |F_d|^2                                          (DSST eq. 3)
    num = np.conj(label_hat)[:, None] * f
    den = (f.real ** 2 + f.imag ** 2).sum(axis=1)
    # with anchor, the first frame's numerator and denominator kept beside the running ones (scale_anchor)
    return ScaleFilter(num, den, label_hat, model, num if anchor else None, den if anchor else None)


def learn_scale(sf: ScaleFilter, grey: np.ndarray, centre: tuple[float, float], size: tuple[float, float],
                step: float, cell: int, rate: float) -> ScaleFilter:
    """The running average with a new sample at the estimate (DSST eq. 5)."""
    n = len(sf.den)
    f = np.fft.fft(scale_sample(grey, centre, size, _factors(n, step), sf.model, cell), axis=0)
    # A <- (1 - eta) A + eta conj(G) F,  B <- (1 - eta) B + eta sum_d |F_d|^2
    num = (1.0 - rate) * sf.num + rate * np.conj(sf.label_hat)[:, None] * f
    den = (1.0 - rate) * sf.den + rate * (f.real ** 2 + f.imag ** 2).sum(axis=1)
    return ScaleFilter(num, den, sf.label_hat, sf.model, sf.anchor_num, sf.anchor_den)


def detect_scale(sf: ScaleFilter, grey: np.ndarray, centre: tuple[float, float], size: tuple[float, float],
                 step: float, cell: int, lam: float, refine: bool = False,
                 prior: tuple[float, float, float] | None = None, anchor: float = 0.0) -> tuple[float, np.ndarray]:
    """The log-scale change at ``centre`` and the response over the scales (S,).

    y = F^-1 { sum_d conj(A_d) Z_d / (B + lambda) } (DSST eq. 6) over the scale index; its peak n*
    gives the change n* log a, a whole number of steps, or with ``refine`` the vertex of the parabola
    through the peak and its neighbours (``scale_refine``). With ``prior`` =
    (log s, sigma, kappa) the peak (and the parabola) is that of :func:`size_posterior` instead (the held box's log size
    log s relative to the first box, a Gaussian prior of std sigma on it, the response's sharpness kappa).
    With ``anchor`` w > 0 (and the first frame's filter kept), A and B are (1 - w) the running ones plus
    w the first frame's (module docstring)."""
    n = len(sf.den)
    z = np.fft.fft(scale_sample(grey, centre, size, _factors(n, step), sf.model, cell), axis=0)
    num, den = sf.num, sf.den
    if anchor > 0 and sf.anchor_num is not None and sf.anchor_den is not None:
        # A = (1 - w) A_t + w A_0,  B = (1 - w) B_t + w B_0: the first frame's filter mixed in
        num = (1.0 - anchor) * sf.num + anchor * sf.anchor_num
        den = (1.0 - anchor) * sf.den + anchor * sf.anchor_den
    # sum_d conj(A_d) Z_d (einsum: a fixed order of summation)
    s = np.einsum("sd,sd->s", np.conj(num), z)
    y = np.fft.ifft(s / (den + lam)).real
    score = y if prior is None else size_posterior(y, step, *prior)
    i = int(np.argmax(score))
    d = float(i - (n - 1) // 2)
    if refine and 0 < i < n - 1:
        a, b, c = score[i - 1], score[i], score[i + 1]
        den = a - 2.0 * b + c
        if den < 0:
            # the vertex of the parabola through (i - 1, a), (i, b), (i + 1, c)
            d += float(np.clip(0.5 * (a - c) / den, -0.5, 0.5))
    return d * float(np.log(step)), y


def size_posterior(y: np.ndarray, step: float, log_s: float, sigma: float, kappa: float) -> np.ndarray:
    """(S,) the log-posterior over the scale filter's S scales of a box whose log size relative to the first
    box is ``log_s``: the response read as a likelihood, p(z | s) ~ exp(kappa y) (as the particles read the
    translation response), times a Gaussian prior log s ~ N(0, sigma^2) on the size (the first box's).

    log p(n | z) = kappa y_n - (log s + n log a)^2 / (2 sigma^2) + const, n the scale index about the middle.
    A response that barely prefers a neighbouring size (a flat top) no longer moves the box away from the
    first size frame after frame; a clear preference still does."""
    n = len(y)
    # log s_n = log s + n log a, n = -(S - 1) / 2 ... (S - 1) / 2
    ls = log_s + (np.arange(n) - (n - 1) // 2) * float(np.log(step))
    # log p(n | z) = kappa y_n - log s_n^2 / (2 sigma^2)
    return kappa * np.asarray(y, dtype=np.float64) - 0.5 * ls ** 2 / sigma ** 2
