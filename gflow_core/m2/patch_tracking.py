"""M2 tracking of patch exemplars without transforms (Toyama & Blake 2002, sec. 5.2).

For the mouth sequences the images are "largely registered", so tracking runs "with no
alpha transformations": the state is the exemplar index k alone, the dynamics are the
Markov matrix M, and the observation likelihood is eq. 7 with the shuffle (or L2)
distance of the observed patch z_t to the exemplar,

    log p(y_t | k) = -rho(x~_k, z_t) / (2 sigma_k^2) - d_k log sigma_k + const.

rho depends on the particle only through k, so a step computes the K distances once
and indexes them by each particle's k: the cost is K distance evaluations per frame,
independent of the number of particles.

Since k is discrete, the exact forward algorithm (Rabiner 1989, as in sec. 5.1.2)

    p_t(k) proportional to p(y_t | k) sum_j M[j, k] p_{t-1}(j)

is also given (:func:`forward_step`); the particle filter converges to it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..particles import LogWeights, systematic_resample
from .distances import Metric, check_patches
from .dynamics import sample_categorical, sample_markov
from .kernel import log_kernel

__all__ = ["PatchExemplars", "PatchPosterior", "exemplar_log_likelihood", "init_k", "propose_k", "weigh_patches",
           "patch_posterior", "forward_step"]


@dataclass(frozen=True)
class PatchExemplars:
    """K patch exemplars x~_k with kernel parameters, Markov dynamics and their metric.

    Attributes
    ----------
    patches : (K, h, w) float64
    sigma, d, pi : (K,) float64
    markov : (K, K) float64, rows sum to 1.
    metric : Metric with ``kind == "patch"`` (shuffle or L2).
    """

    patches: np.ndarray
    sigma: np.ndarray
    d: np.ndarray
    pi: np.ndarray
    markov: np.ndarray
    metric: Metric

    def __post_init__(self) -> None:
        p = check_patches(self.patches, "exemplar patches")
        K = p.shape[0]
        object.__setattr__(self, "patches", p)
        for name in ("sigma", "d", "pi"):
            v = np.asarray(getattr(self, name), dtype=np.float64)
            if v.shape != (K,) or not np.isfinite(v).all():
                raise ValueError(f"{name} must be ({K},) and finite, got shape {v.shape}")
            object.__setattr__(self, name, v)
        if (self.sigma <= 0).any():
            raise ValueError("kernel widths sigma_k must be positive")
        m = np.asarray(self.markov, dtype=np.float64)
        if m.shape != (K, K) or (m < 0).any() or not np.allclose(m.sum(axis=1), 1.0):
            raise ValueError(f"Markov matrix must be ({K}, {K}), non-negative, rows summing to 1")
        object.__setattr__(self, "markov", m)
        if self.metric.kind != "patch":
            raise ValueError(f"patch tracking needs a patch metric, got {self.metric.name!r}")

    @property
    def K(self) -> int:
        return int(self.patches.shape[0])


@dataclass(frozen=True)
class PatchPosterior:
    """p_t(k) from weighted particles.

    Attributes
    ----------
    map_k : int, the particle state with the highest posterior weight.
    k_hist : (K,) float64, posterior probability of each exemplar.
    ess : float, effective sample size before resampling.
    log_evidence : float, log mean likelihood.
    resampled : (N,) int64, equally weighted particles for t (systematic resampling).
    """

    map_k: int
    k_hist: np.ndarray
    ess: float
    log_evidence: float
    resampled: np.ndarray


def exemplar_log_likelihood(model: PatchExemplars, observation: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """log p(y | k) for every exemplar (eq. 7) and the distances rho(x~_k, z).

    Parameters
    ----------
    model : PatchExemplars
    observation : (h, w) patch z_t, registered like the exemplars.

    Returns
    -------
    log_lik : (K,) float64, rho : (K,) float64
    """
    z = model.metric.features(observation)
    rho = model.metric.to_image(model.patches, z)
    return log_kernel(rho, model.sigma, model.d), rho


def init_k(n: int, model: PatchExemplars, rng: np.random.Generator) -> np.ndarray:
    """n particles with k ~ pi. Returns (n,) int64."""
    return sample_categorical(model.pi, n, rng)


def propose_k(k: np.ndarray, model: PatchExemplars, rng: np.random.Generator) -> np.ndarray:
    """k_t ~ M[k_{t-1}, :] for each particle. (N,) -> (N,) int64."""
    return sample_markov(np.asarray(k, dtype=np.int64), model.markov, rng)


def weigh_patches(k: np.ndarray, model: PatchExemplars, observation: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Log-likelihood of N particles (eq. 7), computing the K distances once.

    Parameters
    ----------
    k : (N,) int64, particle exemplar indices.
    model : PatchExemplars
    observation : (h, w) patch z_t.

    Returns
    -------
    log_lik : (N,) float64, rho : (N,) float64
    """
    k = np.asarray(k, dtype=np.int64)
    if k.size and (k.min() < 0 or k.max() >= model.K):
        raise ValueError(f"particle exemplar index out of range [0, {model.K})")
    ll, rho = exemplar_log_likelihood(model, observation)
    return ll[k], rho[k]


def patch_posterior(k: np.ndarray, log_lik: np.ndarray, K: int, rng: np.random.Generator,
                    n_out: int | None = None) -> PatchPosterior:
    """Weight (proposal = prior, so w = likelihood), summarise and resample."""
    k = np.asarray(k, dtype=np.int64)
    lw = np.asarray(log_lik, dtype=np.float64)
    if lw.shape != k.shape:
        raise ValueError(f"log_lik must be {k.shape}, got {lw.shape}")
    weights = LogWeights(np.nan_to_num(lw, nan=-np.inf))
    W = weights.W
    k_hist = np.bincount(k, weights=W, minlength=K).astype(np.float64)
    idx = systematic_resample(weights.log_W, rng, n_out)
    return PatchPosterior(map_k=int(k[np.argmax(lw)]), k_hist=k_hist, ess=weights.ess,
                          log_evidence=weights.log_mean, resampled=k[idx])


def forward_step(p_prev: np.ndarray, model: PatchExemplars, observation: np.ndarray) -> np.ndarray:
    """Exact filter over k: p_t(k) proportional to p(y_t | k) sum_j M[j, k] p_{t-1}(j).

    Parameters
    ----------
    p_prev : (K,) float64, p_{t-1}(k); for the first frame pass ``model.pi`` (the prior is
        then pi M, as for particles drawn from pi and propagated by :func:`propose_k`).

    Returns
    -------
    (K,) float64, summing to 1.
    """
    p_prev = np.asarray(p_prev, dtype=np.float64)
    if p_prev.shape != (model.K,):
        raise ValueError(f"p_prev must be ({model.K},), got {p_prev.shape}")
    ll, _ = exemplar_log_likelihood(model, observation)
    # p(k_t | y_{1:t-1}) = sum_j M[j, k] p_{t-1}(j)
    pred = p_prev @ model.markov
    lp = np.log(np.maximum(pred, 1e-300)) + ll
    lp -= lp.max()
    p = np.exp(lp)
    return p / p.sum()
