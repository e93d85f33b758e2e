"""CSR-DCF's channel reliability: a weight per feature channel on the filter's response at detection.

The filter's response is the sum of its channels' responses (:func:`.filter.respond`), every one of
the 32 channels (31 fHOG and the intensity, :func:`.model.cells_of`) counting alike. Lukezic, Vojir,
Cehovin, Matas & Kristan ("Discriminative correlation filter with channel and spatial reliability",
CVPR 2017, sec. 3.2-3.3) weight channel d's response by its reliability w_d, the weights summing to 1:

    y = sum_d w_d (h_d * z_d),

w_d the product of two parts, normalised to sum 1 and averaged over time at a rate eta_w:

* learning reliability: the largest value of channel d's response of the frame's filter on the sample
  it was learnt from -- a channel that explains the label by itself peaks high;
* detection reliability: 1 - min(rho_2 / rho_1, 1/2), rho_1 and rho_2 the first and second highest local
  maxima ("major modes") of channel d's response on the new frame -- a channel whose response has a
  rival peak is ambiguous there;

    w~_d = lrn_d det_d / sum_k lrn_k det_k,     w <- (1 - eta_w) w + eta_w w~,  w <- w / sum_k w_k.

What was checked, and where: the paper itself was not at hand. The form above is that of the authors'
MATLAB code (github.com/alanlukezic/csr-dcf: ``create_csr_tracker.m`` -- the first weights are the
learning reliability alone, the largest value of each channel's response of the first filter on the
first sample, normalised to sum 1 -- and ``track_csr_tracker.m`` -- the detection reliability from
each channel's response on the search window scaled to [0, 1] by its minimum and maximum, its
regional maxima sorted, floored at 1/2), and of the update step read in a copy of that code (the
product, normalised, averaged at ``channels_weight_lr``, normalised again); OpenCV's CSRT
(``tracker_csrt.cpp``) keeps the learning reliability alone, averaged at ``weights_lr`` 0.02.

Departures:

* the weights are scaled to a mean of 1 (C w, C the channels) before they multiply the filter, so equal
  weights give back the unweighted filter and its response keeps the scale the tracker's score
  distributions and ``kappa`` were set on (CSR-DCF's weights sum to 1 and only its peak's place is read);
* the learning reliability is of the running filter (the one detection uses, after this frame's update)
  on this frame's sample: the running filter here is solved again from the running average of the samples
  (BACF sec. 3.3), and no filter of the frame alone is solved; CSR-DCF solves one and averages filters;
* the detection reliability is read in :func:`gflow_core.dcf.model.learn` on the window at the estimate,
  of the running filter before this frame's update -- not on the window at the prediction the particles
  were weighed in (the same frame, the window shifted by the motion found) -- and its local maxima are
  those of the cyclic response on cells, over 3 x 3 neighbourhoods (the MATLAB code: ``imregionalmax``);
* the first frame's filter (the anchor) keeps the first frame's weights: it stands for the first frame's
  tracker, never updated, and weighting it by the running weights would let it drift with them (``verify``,
  which scores with the anchor alone, so reads the first frame's weighted filter);
* the intensity channel is left out of the weighting unless ``channel_intensity``: it keeps a weight of
  1 and the 31 fHOG channels share theirs (:func:`scaled`). Its largest response is on another scale
  than theirs -- cell means of grey levels in [-0.5, 0.5] against clipped gradient histograms -- and
  the learning reliability compares the channels' largest responses as they are: on skating1 it gave the
  intensity 2.8 times the mean weight on the first frame and 5.2 by frame 300, and cost skating1 (0.288
  against 0.604 on the nine, seed 1: docs/dcf-development.md);
* the detection reliability was at its floor of 1/2 on nearly every channel and frame measured (the
  fHOG channels' responses over the wide window each have rival modes: on the first 40 frames of
  skating1 the second mode's median was 0.72-0.95 of the first's), so in practice the weights are
  the learning reliability's -- OpenCV's CSRT's form;
* the long-term filter (:mod:`.longterm`) and the scale filter are not weighted;
* the rate is the filter's own on that frame (``rate``, or what ``young`` / ``rate_adapt`` make of it),
  as the MATLAB code's default and OpenCV's set both rates to 0.02.
"""

from __future__ import annotations

import numpy as np

__all__ = ["responses", "learning", "detection", "combine", "blend", "scaled", "DETECTION_FLOOR"]

#: the detection reliability's floor, 1 - 1/2: a rival mode higher than half the first counts as half
DETECTION_FLOOR = 0.5


def responses(det: np.ndarray, x_hat: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """(h, w, C) float64 every channel's own response of the filter ``det`` (h, w // 2 + 1, C) complex
    (:func:`.filter.detector`) on the sample of spectrum ``x_hat`` (same shape), cyclic, index (0, 0)
    displacement 0; ``shape`` (h, w) the cells. Their sum over C is :func:`.filter.respond`'s."""
    # y_d = F^-1 { D_d X_d }
    return np.fft.irfft2(det * x_hat, s=shape, axes=(0, 1))


def learning(y: np.ndarray) -> np.ndarray:
    """(C,) the learning reliability of each channel: the largest value of its response ``y`` (h, w, C) on
    its training sample, clipped at 0 (a channel that only lowers the response is given none)."""
    # lrn_d = max_x y_d(x)
    return np.maximum(y.reshape(-1, y.shape[-1]).max(axis=0), 0.0)


def detection(y: np.ndarray) -> np.ndarray:
    """(C,) the detection reliability of each channel, 1 - min(rho_2 / rho_1, 1/2) in [1/2, 1]: ``y``
    (h, w, C) the channels' responses on the new frame, cyclic; each scaled to [0, 1] by its minimum and
    maximum (rho_1 = 1), rho_2 its second highest local maximum over 3 x 3 cells (0 without one). A flat
    response gives 1, as the MATLAB code leaves it."""
    lo = y.min(axis=(0, 1))
    span = y.max(axis=(0, 1)) - lo
    flat = span <= 0
    n = (y - lo) / np.where(flat, 1.0, span)
    # the local maxima: cells at least as high as every neighbour (the response is cyclic)
    peaks = n >= _cyclic_max3(n)
    c = n.shape[-1]
    first = np.argmax(n.reshape(-1, c), axis=0)
    peaks.reshape(-1, c)[first, np.arange(c)] = False
    rho2 = np.where(peaks, n, 0.0).reshape(-1, c).max(axis=0)
    # det_d = 1 - min(rho_2 / rho_1, 1/2),  rho_1 = 1                   (CSR-DCF sec. 3.2, the authors' code)
    out = 1.0 - np.minimum(rho2, 1.0 - DETECTION_FLOOR)
    return np.where(flat, 1.0, out)


def _cyclic_max3(n: np.ndarray) -> np.ndarray:
    """(h, w, C) each cell's maximum over its 3 x 3 neighbourhood, cyclic, channel by channel (scipy's
    ``maximum_filter(n, size=(3, 3, 1), mode="wrap")``, without importing scipy)."""
    rows = np.maximum(np.maximum(n, np.roll(n, 1, axis=0)), np.roll(n, -1, axis=0))
    return np.maximum(np.maximum(rows, np.roll(rows, 1, axis=1)), np.roll(rows, -1, axis=1))


def combine(lrn: np.ndarray, det: np.ndarray | None = None) -> np.ndarray:
    """(C,) the frame's weights: lrn_d det_d normalised to sum 1 (``det`` None: the learning reliability
    alone, as on the first frame); equal weights when every product is 0."""
    # w~_d = lrn_d det_d / sum_k lrn_k det_k
    w = lrn if det is None else lrn * det
    total = float(w.sum())
    return np.full(w.shape, 1.0 / w.size) if not total > 0 else w / total


def blend(w: np.ndarray, new: np.ndarray, rate: float) -> np.ndarray:
    """(C,) the running weights after a frame's ``new`` at ``rate``, normalised to sum 1."""
    # w <- (1 - eta) w + eta w~,  w <- w / sum_k w_k
    out = (1.0 - rate) * w + rate * new
    return out / float(out.sum())


def scaled(det: np.ndarray, w: np.ndarray, intensity: bool) -> np.ndarray:
    """The filter ``det`` (h, w', C) with channel d multiplied by C w_d (the weights at a mean of 1, so equal
    weights leave the filter as it is); without ``intensity`` the last channel (the intensity,
    :func:`.model.cells_of`) keeps 1 and the others are multiplied by (C - 1) w_d / sum_(k < C) w_k."""
    # D_d <- C w_d D_d
    f = w.size * w
    rest = float(w[:-1].sum())
    if not intensity:
        # D_d <- (C - 1) w_d / sum_(k < C) w_k D_d  (d < C),  D_C <- D_C
        f = np.append((w.size - 1) * w[:-1] / rest if rest > 0 else np.ones(w.size - 1), 1.0)
    return det * f[None, None, :]
