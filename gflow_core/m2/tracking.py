"""The M2 particle filter over X = (alpha, k) (Toyama & Blake 2002, sec. 3.3, 5.1.2).

One step of the filter is split the way the pipeline splits it:

* :func:`propose` (the proposal stage) samples the dynamics p(X_t | X_{t-1}) for every
  particle of the resampled posterior at t-1;
* :func:`weigh` (the filter stage) computes log p(y_t | X_t) by eq. 7 for every
  proposed particle;
* :func:`posterior` turns proposals and log-likelihoods into the MAP state, a posterior
  summary, the ESS and the resampled particle set for t.

The observation likelihood of a component (eq. 6-7, with lambda = 1 / 2 sigma_k^2 and
Z_k proportional to sigma_k^{d_k}, sec. 3.3.3) is

    log p(y | alpha, k) = -rho(T_alpha x~_k, z) / (2 sigma_k^2) - d_k log sigma_k + const.

The chamfer tracker of the runtime is this model with K = 1, d = 0 and lambda given
directly: log p = -lambda rho.

A frame that no hypothesis explains (blank or occluded, sec. 5.1.2 fig. 7): with K = 1
every rho is the same large value and the normalised weights stay flat, so the particles
coast on the dynamics. With learned sigma_k and d_k, eq. 7 on an empty image is *not*
neutral (it favours the widest kernels), so the filter stage detects a frame with no
evidence and passes zero log-likelihoods to :func:`posterior`: the posterior is the prior.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .. import similarity
from ..particles import LogWeights, systematic_resample, weight_histogram
from .chamfer import chamfer_distance
from .dynamics import ARDynamics, sample_markov

#: Default particles per block in :func:`weigh`.
WEIGH_CHUNK = 256

__all__ = ["ContourExemplars", "ParticleCloud", "Posterior", "propose", "weigh", "posterior", "weight_diagnostics",
           "init_particles", "template_from_edges"]


@dataclass(frozen=True)
class ContourExemplars:
    """K contour exemplars x~_k with their kernel parameters and dynamics.

    Attributes
    ----------
    curves : (K, P, 2) float64
        Exemplar points (x, y) in the exemplar's own frame (centred on its reference
        point), padded to P points.
    n_points : (K,) int64
        Number of valid points of each exemplar.
    sigma : (K,) float64
        Kernel width sigma_k (eq. 10); lambda_k = 1 / (2 sigma_k^2).
    d : (K,) float64
        Kernel dimension d_k (eq. 10 / 11); Z_k proportional to sigma_k^{d_k}.
    pi : (K,) float64
        Mixture weights pi_k, summing to 1.
    markov : (K, K) float64
        Exemplar transition matrix, rows summing to 1.
    dynamics : ARDynamics
        AR(1) process on alpha.
    """

    curves: np.ndarray
    n_points: np.ndarray
    sigma: np.ndarray
    d: np.ndarray
    pi: np.ndarray
    markov: np.ndarray
    dynamics: ARDynamics

    def __post_init__(self) -> None:
        curves = np.asarray(self.curves, dtype=np.float64)
        if curves.ndim != 3 or curves.shape[2] != 2 or curves.shape[0] < 1 or curves.shape[1] < 1:
            raise ValueError(f"exemplar curves must be (K, P, 2) with K, P >= 1, got shape {curves.shape}")
        k = curves.shape[0]
        object.__setattr__(self, "curves", curves)
        for name in ("n_points", "sigma", "d", "pi"):
            v = np.asarray(getattr(self, name), dtype=np.int64 if name == "n_points" else np.float64)
            if v.shape != (k,):
                raise ValueError(f"{name} must have shape ({k},) for K={k} exemplars, got {v.shape}")
            if not np.isfinite(v).all():
                raise ValueError(f"{name} contains NaN or inf")
            object.__setattr__(self, name, v)
        if (self.n_points < 1).any() or (self.n_points > curves.shape[1]).any():
            raise ValueError("every exemplar needs between 1 and P points")
        if (self.sigma <= 0).any():
            raise ValueError("kernel widths sigma_k must be positive")
        if (self.d < 0).any():
            raise ValueError("kernel dimensions d_k must be non-negative")
        markov = np.asarray(self.markov, dtype=np.float64)
        if markov.shape != (k, k):
            raise ValueError(f"Markov matrix must be ({k}, {k}), got {markov.shape}")
        if (markov < 0).any() or not np.allclose(markov.sum(axis=1), 1.0):
            raise ValueError("Markov matrix rows must be non-negative and sum to 1")
        object.__setattr__(self, "markov", markov)
        if not np.isclose(self.pi.sum(), 1.0) or (self.pi < 0).any():
            raise ValueError("mixture weights pi_k must be non-negative and sum to 1")

    @property
    def K(self) -> int:
        """Number of exemplars."""
        return int(self.curves.shape[0])

    @classmethod
    def single(cls, points: np.ndarray, lam: float, dynamics: ARDynamics) -> "ContourExemplars":
        """The K = 1 chamfer model: one template, likelihood exp(-lambda rho).

        Parameters
        ----------
        points : (P, 2) float64, template points centred on the reference point.
        lam : float, lambda > 0.
        dynamics : ARDynamics
        """
        if not lam > 0:
            raise ValueError(f"lambda must be positive, got {lam}")
        pts = np.asarray(points, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[1] != 2 or pts.shape[0] < 1:
            raise ValueError(f"template points must be (P, 2) with P >= 1, got shape {pts.shape}")
        # lambda = 1 / (2 sigma^2)  =>  sigma = sqrt(1 / (2 lambda))
        sigma = np.sqrt(1.0 / (2.0 * lam))
        return cls(curves=pts[None], n_points=np.array([pts.shape[0]]), sigma=np.array([sigma]),
                   d=np.array([0.0]), pi=np.array([1.0]), markov=np.ones((1, 1)), dynamics=dynamics)


@dataclass(frozen=True)
class ParticleCloud:
    """N weighted hypotheses X = (alpha, k).

    Attributes
    ----------
    alpha : (N, 4) float64, (ux, uy, theta, s).
    k : (N,) int64, exemplar index.
    log_w : (N,) float64, log-weights (equal after resampling).
    """

    alpha: np.ndarray
    k: np.ndarray
    log_w: np.ndarray

    def __post_init__(self) -> None:
        a = similarity.check_alpha(self.alpha)
        if a.ndim != 2:
            raise ValueError(f"particle alpha must be (N, 4), got shape {a.shape}")
        n = a.shape[0]
        k = np.asarray(self.k, dtype=np.int64)
        lw = np.asarray(self.log_w, dtype=np.float64)
        if k.shape != (n,) or lw.shape != (n,):
            raise ValueError(f"particle k and log_w must be ({n},), got {k.shape} and {lw.shape}")
        if np.isnan(lw).any():
            raise ValueError("particle log-weights contain NaN")
        object.__setattr__(self, "alpha", a)
        object.__setattr__(self, "k", k)
        object.__setattr__(self, "log_w", lw)

    @property
    def n(self) -> int:
        return int(self.alpha.shape[0])


@dataclass(frozen=True)
class Posterior:
    """Summary of p_t(X_t) after weighting (sec. 5.1.2).

    Attributes
    ----------
    map_alpha : (4,) float64, MAP transform argmax over particles of the posterior weight.
    map_k : int, MAP exemplar.
    mean_alpha : (4,) float64, weighted mean transform (angle averaged on the circle).
    std_alpha : (4,) float64, weighted standard deviation of each component.
    ess : float, effective sample size of the weights before resampling.
    log_evidence : float, log of the mean likelihood (log p(y_t | y_{1:t-1}) estimate).
    k_hist : (K,) float64, posterior probability of each exemplar.
    resampled : ParticleCloud, equally weighted particles for t (systematic resampling).
    """

    map_alpha: np.ndarray
    map_k: int
    mean_alpha: np.ndarray
    std_alpha: np.ndarray
    ess: float
    log_evidence: float
    k_hist: np.ndarray
    resampled: ParticleCloud = field(repr=False)


def template_from_edges(edges: np.ndarray, box: tuple[float, float, float, float], max_points: int,
                        rng: np.random.Generator | None = None) -> np.ndarray:
    """Template contour: the edge pixels inside a box, centred on the box centre.

    Parameters
    ----------
    edges : (H, W) uint8, non-zero on edges.
    box : (x, y, w, h), top-left corner and size in pixels.
    max_points : int
        At most this many points are kept, chosen evenly along the raster order
        (deterministic; ``rng`` is accepted for API symmetry and not used).

    Returns
    -------
    (P, 2) float64 points (x, y) relative to the box centre.

    Raises
    ------
    ValueError
        If the box does not overlap the image, or holds no edge pixel.
    """
    x, y, w, h = (float(v) for v in box)
    H, W = edges.shape
    if not (w > 0 and h > 0):
        raise ValueError(f"initial box must have positive size, got w={w}, h={h}")
    c0, r0 = max(int(np.floor(x)), 0), max(int(np.floor(y)), 0)
    c1, r1 = min(int(np.ceil(x + w)), W), min(int(np.ceil(y + h)), H)
    if c0 >= c1 or r0 >= r1:
        raise ValueError(f"initial box {box} lies outside the {W}x{H} image")
    rows, cols = np.nonzero(edges[r0:r1, c0:c1])
    if rows.size == 0:
        raise ValueError(f"no edge pixels inside the initial box {box}; lower the Canny thresholds")
    pts = np.stack([cols + c0, rows + r0], axis=1).astype(np.float64)
    if pts.shape[0] > max_points:
        pick = np.linspace(0, pts.shape[0] - 1, max_points).round().astype(np.intp)
        pts = pts[pick]
    centre = np.array([x + (w - 1) / 2.0, y + (h - 1) / 2.0])
    return pts - centre


def init_particles(alpha0: np.ndarray, k0: int, n: int, spread: np.ndarray, rng: np.random.Generator) -> ParticleCloud:
    """N particles around a known initial state, Gaussian in beta = (ux, uy, theta, log s).

    Parameters
    ----------
    alpha0 : (4,) float64
    k0 : int
    n : int
    spread : (4,) float64, std of (ux, uy, theta, log s).
    rng : numpy.random.Generator
    """
    if n < 1:
        raise ValueError(f"number of particles must be >= 1, got {n}")
    a0 = similarity.check_alpha(alpha0)
    beta = np.empty((n, 4))
    beta[:] = a0
    beta[:, 3] = np.log(a0[3])
    beta += rng.standard_normal((n, 4)) * np.asarray(spread, dtype=np.float64)
    beta[0] = [a0[0], a0[1], a0[2], np.log(a0[3])]  # keep the exact initial state
    alpha = beta.copy()
    alpha[:, 3] = np.exp(beta[:, 3])
    return ParticleCloud(alpha=alpha, k=np.full(n, k0, dtype=np.int64), log_w=np.zeros(n))


def propose(cloud: ParticleCloud, model: ContourExemplars, rng: np.random.Generator) -> ParticleCloud:
    """Sample X_t ~ p(X_t | X_{t-1}) for every particle (sec. 4.3): k by M, alpha by the AR process.

    The input should be the equally weighted, resampled posterior at t-1; the output
    carries zero log-weights (the proposal is the prior, so the weight is the likelihood).
    """
    # k_t ~ M[k_{t-1}, :]
    k = sample_markov(cloud.k, model.markov, rng)
    # alpha_t ~ AR(1)(alpha_{t-1})
    alpha = model.dynamics.predict(cloud.alpha, rng)
    return ParticleCloud(alpha=alpha, k=k, log_w=np.zeros(cloud.n))


def weigh(cloud: ParticleCloud, model: ContourExemplars, chamfer_img: np.ndarray,
          outside: float | None = None, chunk: int = WEIGH_CHUNK) -> tuple[np.ndarray, np.ndarray]:
    """Log-likelihood of every particle by eq. 7 on one chamfer image.

    Parameters
    ----------
    cloud : ParticleCloud with N particles.
    model : ContourExemplars
    chamfer_img : (H, W) float32, gamma(z_t, .).
    outside : float, optional, gamma for points off the image (default: image maximum).
    chunk : int, particles per block (<= 0: all at once). Results do not depend on it;
        blocks of a few hundred particles keep the (chunk, P, 2) temporaries in cache and
        were about 4x faster than one block at 2000 particles x 150 points
        (bench/bench_m2_likelihood.py).

    Returns
    -------
    log_lik : (N,) float64
    rho : (N,) float64, the chamfer distances rho(T_alpha x~_k, z_t).
    """
    if cloud.k.size and (cloud.k.min() < 0 or cloud.k.max() >= model.K):
        raise ValueError(f"particle exemplar index out of range [0, {model.K})")
    if outside is None:
        outside = float(np.max(chamfer_img))
    n = cloud.n
    step = n if chunk <= 0 else int(chunk)
    rho = np.empty(n)
    for s in range(0, n, max(step, 1)):
        k = cloud.k[s : s + step]
        # T_alpha x~_k for the particles of this block
        curves = similarity.apply_many(cloud.alpha[s : s + step], model.curves[k])
        rho[s : s + step] = chamfer_distance(chamfer_img, curves, model.n_points[k], outside=outside)
    sigma = model.sigma[cloud.k]
    # log p(y | alpha, k) = -rho / (2 sigma_k^2) - d_k log sigma_k        (eq. 7, Z_k ~ sigma_k^d_k)
    log_lik = -rho / (2.0 * sigma**2) - model.d[cloud.k] * np.log(sigma)
    return log_lik, rho


def _circular_mean(theta: np.ndarray, w: np.ndarray) -> float:
    return float(np.arctan2((w * np.sin(theta)).sum(), (w * np.cos(theta)).sum()))


def posterior(proposed: ParticleCloud, log_lik: np.ndarray, K: int, rng: np.random.Generator,
              n_out: int | None = None) -> Posterior:
    """Weight, summarise and resample: p_t(X_t) from proposals and likelihoods (sec. 5.1.2).

    Parameters
    ----------
    proposed : ParticleCloud, N particles drawn from the dynamics.
    log_lik : (N,) float64, from :func:`weigh`.
    K : int, number of exemplars (for the exemplar histogram).
    rng : numpy.random.Generator, used once, for systematic resampling.
    n_out : int, optional, number of resampled particles (default N).
    """
    log_lik = np.asarray(log_lik, dtype=np.float64)
    if log_lik.shape != (proposed.n,):
        raise ValueError(f"log_lik must be ({proposed.n},), got {log_lik.shape}")
    # w_t^i proportional to w_{t-1}^i p(y_t | X_t^i)   (proposal = prior)
    lw = proposed.log_w + np.nan_to_num(log_lik, nan=-np.inf)
    if not np.isfinite(lw).any():
        # No particle explains the frame at all: keep the prior (coast on the dynamics).
        lw = np.zeros_like(lw)
    weights = LogWeights(lw)
    W = weights.W
    i_map = int(np.argmax(lw))
    mean = (W[:, None] * proposed.alpha).sum(axis=0)
    mean[2] = _circular_mean(proposed.alpha[:, 2], W)
    dev = proposed.alpha - mean
    dev[:, 2] = np.angle(np.exp(1j * dev[:, 2]))
    std = np.sqrt((W[:, None] * dev**2).sum(axis=0))
    k_hist = np.bincount(proposed.k, weights=W, minlength=K).astype(np.float64)
    idx = systematic_resample(weights.log_W, rng, n_out)
    resampled = ParticleCloud(alpha=proposed.alpha[idx], k=proposed.k[idx], log_w=np.zeros(idx.size))
    return Posterior(map_alpha=proposed.alpha[i_map].copy(), map_k=int(proposed.k[i_map]), mean_alpha=mean,
                     std_alpha=std, ess=weights.ess, log_evidence=weights.log_mean, k_hist=k_hist,
                     resampled=resampled)


def weight_diagnostics(proposed: ParticleCloud, log_lik: np.ndarray) -> dict:
    """The weights of ``proposed`` before resampling, for stepping through a filter (no output depends on
    them): the histogram of the relative weights N W_i, the best particle (alpha, k, its log-likelihood)
    and the range of ``log_lik`` (N,); empty when no weight is finite."""
    lw = proposed.log_w + log_lik
    if not np.isfinite(lw).any():
        return {}
    best = int(np.argmax(lw))
    return {
        "weights_N*W": weight_histogram(lw),
        "best_particle": {"alpha": np.round(proposed.alpha[best], 3).tolist(), "k": int(proposed.k[best]),
                          "log_lik": round(float(log_lik[best]), 4)},
        "log_lik_range": [round(float(log_lik.min()), 4), round(float(log_lik.max()), 4)],
    }


def curve_box(points: np.ndarray) -> tuple[float, float, float, float]:
    """Bounding box (x, y, w, h) of a transformed curve, pixel-centre convention (w = xmax - xmin + 1)."""
    p = np.asarray(points, dtype=np.float64)
    x0, y0 = p.min(axis=0)
    x1, y1 = p.max(axis=0)
    return float(x0), float(y0), float(x1 - x0 + 1.0), float(y1 - y0 + 1.0)
