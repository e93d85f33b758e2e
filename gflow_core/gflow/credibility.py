"""Credibility of experts (sec. 3.3), resampling (sec. 3.4) and posterior summaries.

All weights are log-weights. The credibility of expert ``d`` (eq. 17) is its previous
credibility times its likelihood ``p(y_t | u_{1:t-1}, y_{1:t-1})``, estimated from its
importance weights by eq. 19 as ``sum_e w_t(d, e) / s``; credibilities are then
normalised over experts. New experts are drawn from parents in proportion to
credibility (systematic resampling, from :mod:`gflow_core.particles`), and each child
takes a pose drawn from its parent's weighted samples (eq. 15).

Departure from the paper: systematic rather than multinomial selection of parents
(same expectation, lower variance). The posterior mean rotation is the weighted
chordal mean (the weighted mean of rotation matrices projected onto SO(3)).
"""

from __future__ import annotations

import numpy as np
from scipy.special import logsumexp

from gflow_core.particles import ess, log_normalize, systematic_resample

from .geometry import ROT, box_minus, rotation_matrices, rotvec_from_matrices

__all__ = [
    "ess",
    "log_evidence",
    "log_credibility",
    "normalize_rows",
    "resample_experts",
    "pick_samples",
    "posterior_mean_pose",
    "pose_spread",
]


def log_evidence(log_w: np.ndarray) -> np.ndarray:
    """Log of the likelihood estimate of eq. 19 for each expert.

    Parameters
    ----------
    log_w : (E, s) float64
        Log importance weights (eq. 16).

    Returns
    -------
    (E,) float64
        ``log( sum_e w_t(d, e) / s )``.
    """
    s = log_w.shape[-1]
    # p(y_t | u_{1:t-1}^(d), y_{1:t-1}) ~ sum_e w_t(d, e) / s                   (eq. 19)
    return logsumexp(log_w, axis=-1) - np.log(s)


def log_credibility(log_prior_credibility: np.ndarray, log_lik: np.ndarray) -> np.ndarray:
    """Normalised log credibility of each expert (eq. 17).

    Parameters
    ----------
    log_prior_credibility : (E,) float64
        ``log p(u_{1:t-1} | y_{1:t-1})`` (uniform after resampling).
    log_lik : (E,) float64
        :func:`log_evidence`.

    Returns
    -------
    (E,) float64
        ``log p(u_{1:t-1} | y_{1:t})``, with ``sum(exp(.)) == 1``.
    """
    # p(u_{1:t-1} | y_{1:t}) = p(u_{1:t-1} | y_{1:t-1}) p(y_t | u_{1:t-1}, y_{1:t-1}) / p(y_t | y_{1:t-1})  (eq. 17)
    out, _ = log_normalize(log_prior_credibility + log_lik)
    return out


def normalize_rows(log_w: np.ndarray) -> np.ndarray:
    """Normalise log-weights along the last axis (each expert's samples, eq. 15)."""
    return log_w - logsumexp(log_w, axis=-1, keepdims=True)


def pick_samples(log_w_rows: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Draw one sample index per row in proportion to ``exp(log_w_rows)``.

    Parameters
    ----------
    log_w_rows : (N, s) float64
        Normalised log-weights per row.
    rng : numpy.random.Generator
        One ``random(N)`` draw.

    Returns
    -------
    (N,) int64
    """
    cdf = np.cumsum(np.exp(log_w_rows), axis=-1)
    u = rng.random(log_w_rows.shape[0]) * cdf[:, -1]
    idx = np.sum(cdf <= u[:, None], axis=-1)
    return np.minimum(idx, log_w_rows.shape[-1] - 1).astype(np.int64)


def resample_experts(
    log_cred: np.ndarray, log_w: np.ndarray, rng: np.random.Generator, n: int | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Create children from parents (sec. 3.4).

    Parameters
    ----------
    log_cred : (E,) float64
        Log credibilities (normalised or not).
    log_w : (E, s) float64
        Log importance weights of each expert's samples.
    rng : numpy.random.Generator
        One uniform draw (systematic resampling) then ``random(n)``.
    n : int, optional
        Number of children (default ``E``).

    Returns
    -------
    parents : (n,) int64
        Parent of each child, drawn in proportion to credibility.
    picks : (n,) int64
        Sample of the parent's pose opinion (eq. 15) the child takes as ``u_t``.
    """
    parents = systematic_resample(log_cred, rng, n)
    picks = pick_samples(normalize_rows(log_w)[parents], rng)
    return parents, picks


def posterior_mean_pose(poses: np.ndarray, log_w: np.ndarray) -> np.ndarray:
    """Weighted mean of pose vectors.

    Translation and coefficients are arithmetic means; the rotation is the chordal
    mean ``argmin_R sum_i W_i |R - R_i|_F^2`` (SVD projection of ``sum_i W_i R_i``).

    Parameters
    ----------
    poses : (N, P) float64
    log_w : (N,) float64

    Returns
    -------
    (P,) float64
    """
    lw, _ = log_normalize(log_w)
    W = np.exp(lw)
    mean = W @ poses
    M = np.einsum("i,ijk->jk", W, rotation_matrices(poses))
    U, _, Vt = np.linalg.svd(M)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt)) or 1.0])
    mean[ROT] = rotvec_from_matrices(U @ D @ Vt)
    return mean


def pose_spread(poses: np.ndarray, log_w: np.ndarray, mean: np.ndarray) -> np.ndarray:
    """Weighted standard deviation of poses about ``mean`` in the tangent space at ``mean``.

    Returns
    -------
    (P,) float64
        Rotation components in radians, translation in pixels, coefficients in their units.
    """
    lw, _ = log_normalize(log_w)
    W = np.exp(lw)
    d = box_minus(mean[None, :], poses)
    return np.sqrt(W @ (d * d))
