"""M2 kernel parameters d_k, sigma_k (Toyama & Blake 2002, sec. 3.3.3 and 4.2).

The validation distances rho_v of a cluster are modelled as sigma^2 chi^2_d, i.e. a Gamma
distribution with shape d/2 and scale 2 sigma^2. Two estimators:

* moments (eq. 10, the default), with rho_bar = mean(rho) and rho2_bar = mean(rho^2):

      d = 2 rho_bar^2 / (rho2_bar - rho_bar^2),     sigma = sqrt(rho_bar / d)

* maximum likelihood with integer d >= 1 (eq. 11): sigma as above and d maximising

      L(d) = -log Gamma(d/2) + (d/2) (log(d/2) - 1 - log(rho_a / rho_g))

  where rho_a, rho_g are the arithmetic and geometric means of the samples. L is the
  Gamma log-likelihood per sample (up to a constant) with the scale profiled out; it is
  concave in d, so the integer maximiser is found by a scan.

The likelihood of eq. 6-7 with lambda = 1 / (2 sigma^2) and Z proportional to sigma^d is

    log p(y | alpha, k) = -rho / (2 sigma_k^2) - d_k log sigma_k + const.

Departures from the paper
-------------------------
* Note 4.2.1(1) says eq. 11 gives the trivial d = 1 when rho_a / rho_g > 4/e. For
  eq. 11 as printed the exact condition is L(1) >= L(2), i.e.
  rho_a / rho_g >= 2 pi / e ~ 2.31 (:data:`MLE_D1_RATIO`); 4/e ~ 1.47 would give d = 1
  for samples of chi^2_2 (ratio e^gamma ~ 1.78) and even chi^2_3. :func:`mle` follows
  eq. 11 exactly; pass ``trivial_ratio=4/e`` to apply the paper's note as a rule.
* The MLE needs rho > 0 (the geometric mean); zero distances (a validation item
  identical to its exemplar) are left out of the MLE, not of the moments.
* A cluster with fewer than ``min_samples`` (default 10) validation distances gets the
  pooled estimate of all clusters; d is clipped to ``d_range``. The moments estimate
  from a handful of samples is too noisy to use: for sigma^2 chi^2_d samples its standard
  deviation is about 0.6 d at N = 10 and 0.3 d at N = 30, with an upward bias
  (bench/bench_m2_polygons.py), and with K = 100 exemplars on caviar1 four-sample
  clusters gave d from 100 to 1000 against a pooled d of about 13.
* With ``min_rho`` > 0 (``gflow learn m2 --kernel-floor``; :data:`CURVE_KERNEL_FLOOR` for contour
  models by default), a cluster whose mean validation
  distance rho_bar is at most ``min_rho`` gets the pooled estimate too: its distances are the pixel
  grid's, not the target's variation. On a small training target (crossing's walker, 16x42 px)
  consecutive frames can be the same outline up to rasterisation; two renderings of one outline at
  sub-pixel offsets are about 0.24 px^2 apart (quadratic profile, 16x42 px), and such a cluster's
  moments fit is the quantisation noise's: rho_bar 0.32-0.33 px^2, d about the number of its
  exemplar's points (23-33 for 30-41 points), sigma 0.1. Calibrated on another target (caviar1's
  first box), its kernel is 13-23 nats above the pooled one at the same distance (the normaliser
  -d_k log sigma_k), and its exemplar is chosen on nearly every frame wherever its few points fit.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

#: the pixel floor of a contour model's kernels, px^2 (the module docstring's departure): twice the
#: distance between two renderings of one 16x42 px outline at sub-pixel offsets
CURVE_KERNEL_FLOOR = 0.5

__all__ = ["moments", "mle", "mle_objective", "MLE_D1_RATIO", "PAPER_NOTE_RATIO", "KernelFit",
           "fit_kernels", "log_kernel", "KERNEL_METHODS", "CURVE_KERNEL_FLOOR"]

#: rho_a / rho_g above which eq. 11 is maximised by d = 1 (L(1) > L(2)): 2 pi / e.
MLE_D1_RATIO = 2.0 * np.pi / np.e
#: The threshold printed in the paper's note 4.2.1(1): 4 / e.
PAPER_NOTE_RATIO = 4.0 / np.e
KERNEL_METHODS = ("moments", "mle")
D_MAX_SCAN = 100_000


def _samples(rho: np.ndarray) -> np.ndarray:
    r = np.asarray(rho, dtype=np.float64).ravel()
    if r.size < 2:
        raise ValueError(f"need at least 2 distance samples to fit d and sigma, got {r.size}")
    if not np.isfinite(r).all() or (r < 0).any():
        raise ValueError("distance samples must be finite and non-negative")
    return r


def moments(rho: np.ndarray) -> tuple[float, float]:
    """Moments estimate of (d, sigma) from samples of sigma^2 chi^2_d (eq. 10).

    Parameters
    ----------
    rho : (n,) float64, n >= 2, non-negative.

    Returns
    -------
    d : float (inf if the samples have zero variance), sigma : float.
    """
    r = _samples(rho)
    m1 = r.mean()
    m2 = (r * r).mean()
    var = m2 - m1 * m1
    if not m1 > 0:
        raise ValueError("all distance samples are zero: cannot fit sigma")
    if var <= 0:
        return float("inf"), 0.0
    # d_k = 2 rho_bar^2 / (rho2_bar - rho_bar^2)                                      (10)
    d = 2.0 * m1 * m1 / var
    # sigma_k = sqrt(rho_bar / d_k)                                                  (10)
    sigma = np.sqrt(m1 / d)
    return float(d), float(sigma)


def mle_objective(d: np.ndarray, rho_a: float, rho_g: float) -> np.ndarray:
    """L(d) of eq. 11, vectorised over d.

    Parameters
    ----------
    d : (m,) float64, dimensions > 0.
    rho_a, rho_g : float, arithmetic and geometric means of the samples (rho_g > 0).
    """
    d = np.asarray(d, dtype=np.float64)
    h = d / 2.0
    from scipy.special import gammaln  # imported here: 0.2 s at start-up for the processes that never need it

    # L(d) = -log Gamma(d/2) + (d/2)(log(d/2) - 1 - log(rho_a / rho_g))               (11)
    return -gammaln(h) + h * (np.log(h) - 1.0 - np.log(rho_a / rho_g))


def mle(rho: np.ndarray, trivial_ratio: float | None = None, d_max: int = D_MAX_SCAN) -> tuple[int, float]:
    """Maximum-likelihood (d, sigma) with integer d >= 1 (eq. 11).

    Parameters
    ----------
    rho : (n,) float64, samples; zeros are ignored (see module notes).
    trivial_ratio : float, optional
        If given, return d = 1 whenever rho_a / rho_g > trivial_ratio (the paper's note
        4.2.1(1) with ``PAPER_NOTE_RATIO``). By default eq. 11 alone decides, which gives
        d = 1 exactly when the ratio exceeds :data:`MLE_D1_RATIO`.
    d_max : int, largest d considered.

    Returns
    -------
    d : int, sigma : float = sqrt(rho_a / d).
    """
    r = _samples(rho)
    r = r[r > 0]
    if r.size < 2:
        raise ValueError("need at least 2 positive distance samples for the MLE (geometric mean)")
    rho_a = float(r.mean())
    rho_g = float(np.exp(np.log(r).mean()))
    ratio = rho_a / rho_g
    if trivial_ratio is not None and ratio > trivial_ratio:
        d = 1
    else:
        # L is concave in d and its continuous maximiser is about 1 / log(rho_a / rho_g)
        lr = np.log(max(ratio, 1.0))
        hi = int(min(d_max, max(64, np.ceil(4.0 / lr) if lr > 0 else d_max)))
        cand = np.arange(1, hi + 1, dtype=np.float64)
        d = int(cand[np.argmax(mle_objective(cand, rho_a, rho_g))])
    # sigma = sqrt(rho_bar / d)                                                      (10)
    return d, float(np.sqrt(rho_a / d))


@dataclass(frozen=True)
class KernelFit:
    """Per-cluster kernel parameters.

    Attributes
    ----------
    d : (K,) float64, d_k.
    sigma : (K,) float64, sigma_k.
    n : (K,) int64, validation samples per cluster.
    pooled : (K,) bool, True where the cluster had too few samples (or distances at the pixel floor,
        ``min_rho``) and got the pooled fit.
    method : str, "moments" or "mle".
    """

    d: np.ndarray
    sigma: np.ndarray
    n: np.ndarray
    pooled: np.ndarray
    method: str


def _fit(rho: np.ndarray, method: str, trivial_ratio: float | None) -> tuple[float, float]:
    if method == "moments":
        return moments(rho)
    d, s = mle(rho, trivial_ratio=trivial_ratio)
    return float(d), s


def fit_kernels(rho: np.ndarray, labels: np.ndarray, K: int, method: str = "moments", min_samples: int = 10,
                d_range: tuple[float, float] = (0.5, 1000.0), trivial_ratio: float | None = None,
                min_rho: float = 0.0) -> KernelFit:
    """d_k, sigma_k for every cluster from validation distances (sec. 4.2).

    Parameters
    ----------
    rho : (V,) float64, rho_v = rho(T_alpha_v x~_v, z_v) for each validation item.
    labels : (V,) int64, the exemplar k of each validation item.
    K : int, number of clusters.
    method : {"moments", "mle"}, eq. 10 or eq. 11.
    min_samples : int, clusters with fewer samples get the pooled estimate.
    d_range : (float, float), d is clipped to this range (sigma recomputed from the clipped d).
    trivial_ratio : float, optional, passed to :func:`mle`.
    min_rho : float >= 0, clusters whose mean validation distance is at most this get the pooled
        estimate too (0: none; the module docstring's pixel floor).

    Returns
    -------
    KernelFit
    """
    if method not in KERNEL_METHODS:
        raise ValueError(f"unknown kernel estimator {method!r}; choose one of {KERNEL_METHODS}")
    rho = np.asarray(rho, dtype=np.float64)
    labels = np.asarray(labels, dtype=np.int64)
    if rho.shape != labels.shape or rho.ndim != 1:
        raise ValueError(f"rho and labels must be matching 1-D arrays, got {rho.shape} and {labels.shape}")
    if labels.size and (labels.min() < 0 or labels.max() >= K):
        raise ValueError(f"labels must lie in [0, {K})")
    if rho.size < 2 or not (rho > 0).sum() >= 2:
        raise ValueError(f"need at least 2 non-zero validation distances to learn the kernels, got {rho.size}; "
                         "use more training items than exemplars")
    if not (np.isfinite(min_rho) and min_rho >= 0):
        raise ValueError(f"min_rho must be finite and >= 0, got {min_rho}")
    lo, hi = d_range

    def clipped(r: np.ndarray) -> tuple[float, float] | None:
        try:
            d, _ = _fit(r, method, trivial_ratio)
        except ValueError:
            return None
        if not np.isfinite(d):
            d = hi
        d = float(np.clip(d, lo, hi))
        # sigma = sqrt(rho_bar / d)                                                  (10)
        return d, float(np.sqrt(r.mean() / d))

    pooled_fit = clipped(rho)
    if pooled_fit is None:
        raise ValueError("cannot fit a kernel to the pooled validation distances")
    d = np.empty(K)
    sigma = np.empty(K)
    n = np.bincount(labels, minlength=K).astype(np.int64)
    pooled = np.zeros(K, dtype=bool)
    for k in range(K):
        r_k = rho[labels == k]
        # too few samples, or distances at the pixel floor (rho_bar <= min_rho): the pooled fit
        fit = clipped(r_k) if n[k] >= min_samples and not (min_rho > 0 and r_k.mean() <= min_rho) else None
        if fit is None or not fit[1] > 0:
            fit, pooled[k] = pooled_fit, True
        d[k], sigma[k] = fit
    return KernelFit(d=d, sigma=sigma, n=n, pooled=pooled, method=method)


def log_kernel(rho: npt.ArrayLike, sigma: npt.ArrayLike, d: npt.ArrayLike) -> np.ndarray:
    """Log of the M2 kernel, eq. 6-7 with lambda = 1/(2 sigma^2) and Z ~ sigma^d (sec. 3.3.3).

    Parameters
    ----------
    rho, sigma, d : broadcastable float64 arrays.

    Returns
    -------
    log p(y | X) up to a constant common to all states.
    """
    sigma = np.asarray(sigma, dtype=np.float64)
    # log p(y | alpha, k) = -rho / (2 sigma_k^2) - d_k log sigma_k                       (7)
    return -np.asarray(rho, dtype=np.float64) / (2.0 * sigma**2) - np.asarray(d, dtype=np.float64) * np.log(sigma)


def calibrate_sigma(sigma: np.ndarray, d: np.ndarray, rho0: float) -> np.ndarray:
    """Kernel widths widened so that a known true match at distance ``rho0`` is typical.

    Under kernel k a true match has rho / sigma_k^2 distributed as chi^2 with d_k degrees of
    freedom (sec. 3.3.3), mean d_k sigma_k^2. On video the model was not learned on, the
    target in the user's box is a true match; if its distance rho0 exceeds d_k sigma_k^2,
    sigma_k^2 becomes rho0 / d_k (departure from the paper, which keeps the learned widths).
    Never narrows a kernel.

    Returns
    -------
    (K,) float64, max(sigma_k, sqrt(rho0 / d_k)).
    """
    sigma = np.asarray(sigma, dtype=np.float64)
    d = np.asarray(d, dtype=np.float64)
    if not np.isfinite(rho0) or rho0 <= 0:
        return sigma.copy()
    return np.maximum(sigma, np.sqrt(rho0 / d))
