"""An appearance metric beside chamfer for learned M2 models, and a bounded online exemplar bank.

Toyama & Blake (2002) use one metric per model: chamfer on contours (sec. 5.1) or the
shuffle distance on grey patches (sec. 5.2). A chamfer model learned on one pedestrian
does not transfer to another: the learned silhouettes fit the clutter of another scene
(the crosswalk stripes of ``crossing``) as well as the new person. This module adds a
second, appearance, metric to a contour model, so the observation likelihood of a state
X = (alpha, k) is the product of two kernels (eq. 6-7, each with its own d, sigma):

    log p(y | alpha, k) = log K_chamfer(rho_c(T_alpha x~_k, z); sigma_k, d_k)
                        + log K_app(min_j rho_a(a_j, z_alpha); sigma', d').

**The appearance distance** (departure: the paper's shuffle distance is on grey levels).
z_alpha is the region of the frame's locally normalised edge-orientation channels
(:func:`gflow_core.orientation.orientation_channels`, 4 channels) under the transformed
reference box T_alpha(box_ref), sampled on a grid of ``res`` = (tw, th) points; a_k is the
same region of exemplar k's own training frame at its training state. rho_a = 1 - r, with r
the Pearson correlation over all grid points and channels. The channels are invariant to
gain and bias of the grey levels and far less sensitive to the colour of clothes than grey
levels (measured: see docs/accuracy.md, m2), which is what a different person needs.
rho_a lies in [0, 2]; sigma'_k, d'_k are fitted to the validation distances by eq. 10 or 11
(:func:`.kernel.fit_kernels`), exactly like the chamfer kernels.

**Online exemplars** (departure: the paper's exemplars are fixed after learning). A bank of
at most ``bound`` appearance exemplars cut from the tracked video: slot 0 is the initial box
(the user's box, never replaced); later, on frames where the estimate is *confident*
(its appearance correlation with the nearest exemplar is at least ``confident_r``), at
most one every ``every`` frames, the estimate's region is added; beyond the bound it
replaces the least used online slot (usage: an exponentially decaying count of the frames
on which the slot was the estimate's nearest online exemplar). The learned exemplars are
never changed.

**One appearance kernel on the nearest exemplar** (departure). The appearance factor uses the
distance to the nearest appearance exemplar, learned or online, under one pooled kernel
(sigma', d') = the medians of the learned d'_k, sigma'_k. With each exemplar's own kernel the
normalisers -d'_k log sigma'_k chose k (narrow exemplars won on caviar1: 3.5 px instead of
1.6 px); pooled, the appearance factor informs alpha and chamfer alone chooses k. The online
exemplars are not states of the Markov chain over k: k keeps indexing the learned exemplars,
so the learned dynamics are untouched. (``per_exemplar=True`` in :func:`appearance_log_lik`
gives the per-exemplar form.) The tracker also widens the learned kernels on frame 0
(:func:`.kernel.calibrate_sigma`).

Correlations are dot products computed by ``np.einsum`` rather than BLAS, whose sums depend on
the thread count: a stage process runs with one thread, ``--inline`` with more, and both
must give the same bits.

Coordinates: image (x, y) pixels, origin at the top-left pixel centre; item coordinates are
centred on the reference point, the reference box spans ref_size = (w, h) around it.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Sequence

import cv2
import numpy as np

from .. import similarity
from ..orientation import N_BINS, orientation_channels
from .kernel import fit_kernels, log_kernel

__all__ = ["DEFAULT_MAX_AREA", "patch_resolution", "frame_features", "grid_points", "sample_patches", "sample_patches_near",
           "correlation_distances", "learn_appearance", "AppearanceKernels", "OnlineBank", "new_bank",
           "bank_update", "appearance_log_lik"]

#: default number of grid points of an appearance exemplar (tw * th)
DEFAULT_MAX_AREA = 200


def patch_resolution(ref_size: np.ndarray, max_area: int = DEFAULT_MAX_AREA) -> tuple[int, int]:
    """Grid (tw, th) with the reference box's aspect ratio and about ``max_area`` points (>= 4 x 4)."""
    w, h = (float(v) for v in ref_size)
    if not (w > 0 and h > 0):
        raise ValueError(f"reference size must be positive, got {ref_size}")
    f = np.sqrt(max_area / (w * h))
    return max(4, int(round(w * f))), max(4, int(round(h * f)))


def frame_features(grey: np.ndarray) -> np.ndarray:
    """(H, W, 4) float32 orientation channels of a grey frame (0-255)."""
    return orientation_channels(grey)


def grid_points(ref_size: np.ndarray, res: tuple[int, int]) -> np.ndarray:
    """(th * tw, 2) item points (x, y): the centres of a tw x th grid over the reference box."""
    tw, th = res
    w, h = (float(v) for v in ref_size)
    xs = ((np.arange(tw) + 0.5) / tw - 0.5) * w
    ys = ((np.arange(th) + 0.5) / th - 0.5) * h
    gx, gy = np.meshgrid(xs, ys)
    return np.stack([gx.ravel(), gy.ravel()], axis=1)


def sample_patches(feat: np.ndarray, alpha: np.ndarray, ref_size: np.ndarray, res: tuple[int, int]) -> np.ndarray:
    """z_alpha for N transforms: the channels at T_alpha(grid), bilinear, edge-replicated.

    Parameters
    ----------
    feat : (H, W, C) float32 channels of the frame (C <= 4).
    alpha : (N, 4) or (4,) float64 transforms (ux, uy, theta, s).

    Returns
    -------
    (N, th, tw, C) float32
    """
    a = np.atleast_2d(np.asarray(alpha, dtype=np.float64))
    tw, th = res
    pts = grid_points(ref_size, res)
    img = similarity.apply_many(a, np.broadcast_to(pts, (a.shape[0],) + pts.shape))  # (N, P, 2)
    mx = img[..., 0].reshape(-1, tw).astype(np.float32)
    my = img[..., 1].reshape(-1, tw).astype(np.float32)
    out = cv2.remap(feat, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return out.reshape(a.shape[0], th, tw, -1)


def sample_patches_near(grey: np.ndarray, alpha: np.ndarray, ref_size: np.ndarray, res: tuple[int, int],
                        margin: int = 16) -> np.ndarray:
    """:func:`sample_patches` of the frame's channels, computed only on the region the patches cover.

    The channels are computed on the grey crop around every patch's grid plus ``margin``
    pixels (the pooling and normalising Gaussians reach about 3 x 4 px), which is several
    times faster than the whole frame for one target. (N, th, tw, C) float32.
    """
    a = np.atleast_2d(np.asarray(alpha, dtype=np.float64))
    H, W = grey.shape
    tw, th = res
    pts = grid_points(ref_size, res)
    img = similarity.apply_many(a, np.broadcast_to(pts, (a.shape[0],) + pts.shape))
    # the grid is a rectangle: its image lies within the images of its 4 corners
    c = similarity.apply_many(a, pts[[0, tw - 1, -tw, -1]]).reshape(-1, 2)
    lo = np.floor(c.min(axis=0)) - margin
    hi = np.ceil(c.max(axis=0)) + margin
    x0, y0 = int(np.clip(lo[0], 0, W - 3)), int(np.clip(lo[1], 0, H - 3))
    x1, y1 = int(np.clip(hi[0] + 1, x0 + 3, W)), int(np.clip(hi[1] + 1, y0 + 3, H))
    feat = frame_features(grey[y0:y1, x0:x1])
    mx = (img[..., 0] - x0).reshape(-1, tw).astype(np.float32)
    my = (img[..., 1] - y0).reshape(-1, tw).astype(np.float32)
    out = cv2.remap(feat, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return out.reshape(a.shape[0], th, tw, -1)


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a @ b.T without BLAS: (N, D) x (M, D) -> (N, M) float64.

    BLAS results can depend on the thread count (``--inline`` runs with more threads than a
    stage process), and the multi-process and inline runs must agree bit for bit; numpy's
    own einsum loops sum in a fixed order.
    """
    return np.einsum("nd,md->nm", a, b, optimize=False).astype(np.float64)


def _unit(patches: np.ndarray) -> np.ndarray:
    """Rows centred and scaled to unit norm (float32: r is a dot product of two rows)."""
    v = np.asarray(patches, dtype=np.float32).reshape(len(patches), -1)
    v = v - v.mean(axis=1, keepdims=True)
    n = np.sqrt(np.einsum("ij,ij->i", v, v))[:, None]
    return v / np.maximum(n, np.float32(1e-9))


def correlation_distances(patches: np.ndarray, exemplars: np.ndarray) -> np.ndarray:
    """rho_a = 1 - Pearson r between every patch and every exemplar: (N, E) float64 in [0, 2].

    A flat patch (no variation) has r = 0 with everything (rho_a = 1).
    """
    return 1.0 - _dot(_unit(patches), _unit(exemplars))


@dataclass(frozen=True)
class AppearanceKernels:
    """Learned appearance exemplars a_k and their kernels.

    patches : (K, th, tw, C) float32; sigma, d : (K,) float64.
    """

    patches: np.ndarray
    sigma: np.ndarray
    d: np.ndarray

    @property
    def res(self) -> tuple[int, int]:
        return int(self.patches.shape[2]), int(self.patches.shape[1])

    @property
    def online_kernel(self) -> tuple[float, float]:
        """(sigma, d) of the online slots: the medians of the learned ones."""
        return float(np.median(self.sigma)), float(np.median(self.d))


def learn_appearance(greys: Sequence[np.ndarray], states_alpha: np.ndarray, medoids: np.ndarray,
                     is_validation: np.ndarray, labels: np.ndarray, ref_size: np.ndarray, *,
                     method: str = "moments", max_area: int = DEFAULT_MAX_AREA, min_samples: int = 10,
                     d_range: tuple[float, float] = (0.5, 1000.0)) -> AppearanceKernels:
    """Appearance exemplars and kernels from the training items (sec. 4.2, with rho_a).

    Parameters
    ----------
    greys : T grey frames, the frame of each training item.
    states_alpha : (T, 4) image states alpha_t (item -> image) from learning.
    medoids : (K,) item index of each exemplar.
    is_validation, labels : (T,) the validation mask and best exemplar of every item.
    ref_size : (2,) reference box size (w, h), item units.

    Returns
    -------
    AppearanceKernels; a_k is exemplar k's region at its state; sigma'_k, d'_k fitted to
    rho_a(a_{k_v}, z_v) over the validation items v.
    """
    T = len(greys)
    if states_alpha.shape != (T, 4) or labels.shape != (T,) or is_validation.shape != (T,):
        raise ValueError(f"need one frame, state and label per training item (T = {T})")
    res = patch_resolution(ref_size, max_area)
    z = np.empty((T, res[1], res[0], N_BINS), dtype=np.float32)
    for t in range(T):
        z[t] = sample_patches(frame_features(greys[t]), states_alpha[t], ref_size, res)[0]
    ex = z[np.asarray(medoids, dtype=np.intp)]
    val = np.nonzero(is_validation)[0]
    K = ex.shape[0]
    rho = np.array([correlation_distances(z[v : v + 1], ex[labels[v] : labels[v] + 1])[0, 0] for v in val])
    # rho_a of an exemplar with itself is 0; a validation distance of exactly 0 would make eq. 10 degenerate
    rho = np.maximum(rho, 1e-6)
    kf = fit_kernels(rho, labels[val], K, method=method, min_samples=min_samples, d_range=d_range)
    return AppearanceKernels(patches=ex, sigma=kf.sigma, d=kf.d)


@dataclass(frozen=True)
class OnlineBank:
    """At most ``bound`` online appearance exemplars (slot 0: the initial box, kept).

    patches : (n, th, tw, C) float32; usage : (n,) float64 decaying use counts;
    frame : (n,) int64 frame each slot was cut from; last_add : frame of the last addition.
    """

    patches: np.ndarray
    usage: np.ndarray
    frame: np.ndarray
    last_add: int

    @property
    def n(self) -> int:
        return int(self.patches.shape[0])


def new_bank(first: np.ndarray, frame: int) -> OnlineBank:
    """A bank holding the initial region ``first`` (th, tw, C)."""
    return OnlineBank(patches=np.asarray(first, dtype=np.float32)[None].copy(), usage=np.ones(1),
                      frame=np.array([frame], dtype=np.int64), last_add=int(frame))


def bank_update(bank: OnlineBank, patch: np.ndarray, nearest: int, confident: bool, frame: int, *, bound: int,
                every: int, decay: float = 0.95) -> OnlineBank:
    """One frame of the bank: count the use of slot ``nearest``, and add ``patch`` when confident.

    usage <- decay * usage, +1 for ``nearest`` (the estimate's nearest online slot). When
    ``confident`` and at least ``every`` frames after the last addition: append ``patch``
    if fewer than ``bound`` slots are filled, else replace the least used slot among
    1..bound-1 (slot 0, the initial box, is kept). A new slot starts with usage 1.
    """
    if bound < 1:
        raise ValueError(f"bound must be >= 1, got {bound}")
    usage = bank.usage * decay
    if 0 <= nearest < bank.n:
        usage[nearest] += 1.0
    patches, frames, last = bank.patches, bank.frame, bank.last_add
    if confident and frame - bank.last_add >= every and bound > 1:
        p = np.asarray(patch, dtype=np.float32)[None]
        if bank.n < bound:
            patches = np.concatenate([patches, p])
            usage = np.append(usage, 1.0)
            frames = np.append(frames, np.int64(frame))
        else:
            j = 1 + int(np.argmin(usage[1:bound]))
            patches = patches.copy()
            patches[j] = p[0]
            usage[j] = 1.0
            frames = frames.copy()
            frames[j] = frame
        last = int(frame)
    return replace(bank, patches=patches, usage=usage, frame=frames, last_add=last)


def appearance_log_lik(patches: np.ndarray, k: np.ndarray, kernels: AppearanceKernels,
                       bank: OnlineBank | None, per_exemplar: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """log K_app for N particles (see the module docstring).

    Default: the pooled kernel on the nearest exemplar, learned or online. ``per_exemplar``:
    the larger of exemplar k's own kernel and the pooled kernel on the best online slot.

    Parameters
    ----------
    patches : (N, th, tw, C) regions z_alpha of the particles.
    k : (N,) learned exemplar of each particle.

    Returns
    -------
    log_lik : (N,) float64
    r_best : (N,) float64, the largest correlation over the learned exemplars (only exemplar k
        with ``per_exemplar``) and the bank.
    nearest : (N,) int64, index of the nearest online slot (-1 with no bank).
    """
    k = np.asarray(k, dtype=np.intp)
    u = _unit(patches)
    r_all = _dot(u, _unit(kernels.patches))  # (N, K)
    if per_exemplar:
        r_k = r_all[np.arange(len(k)), k]
        # log K(rho_a; sigma'_k, d'_k), rho_a = 1 - r                     (eq. 7 with the appearance metric)
        ll = log_kernel(1.0 - r_k, kernels.sigma[k], kernels.d[k])
    else:
        r_k = r_all.max(axis=1)
    s, d = kernels.online_kernel
    r_best = r_k
    nearest = np.full(k.shape, -1, dtype=np.int64)
    if bank is not None and bank.n:
        r_on = _dot(u, _unit(bank.patches))  # (N, B)
        nearest = np.argmax(r_on, axis=1).astype(np.int64)
        r_best = np.maximum(r_k, r_on[np.arange(len(k)), nearest])
    if per_exemplar:
        ll = np.maximum(ll, log_kernel(1.0 - r_best, s, d))
    else:
        # one pooled kernel on the nearest exemplar, learned or online: the appearance term
        # informs alpha and leaves the choice of k to chamfer
        ll = log_kernel(1.0 - r_best, s, d)
    return ll, r_best, nearest
