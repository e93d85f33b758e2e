"""Learning p(X_t | X_{t-1}) from training time series (Toyama & Blake 2002, sec. 4.3).

The estimated states X_t = (alpha_t, k_t) of the training sequence are treated as fixed
time-series data, and two independent parts are learned:

1. the Markov matrix M[i, j] = p(k_t = j | k_{t-1} = i) by histogramming transitions;
2. a first-order AR process on beta = (ux, uy, theta, log s) (:class:`.dynamics.ARDynamics`)
   by Yule-Walker:

       C0 = (1/n) sum_t (b_t - m)(b_t - m)^T,   C1 = (1/n) sum_t (b_{t+1} - m)(b_t - m)^T
       A  = C1 C0^-1,   Q = cov(b_{t+1} - m - A (b_t - m)),   B = chol(Q).

Several sequences (or one sequence with gaps) are passed as a list of runs; transitions
are counted only inside a run, and the autocovariances pool every run.

Departures from the paper
-------------------------
* The Markov histogram gets an additive (symmetric Dirichlet) prior ``prior`` per cell,
  M[i, j] = (n_ij + a) / (n_i + K a), so that transitions not seen in training keep a
  small positive probability and a row with no data is uniform.
* ``translation="random_walk"`` (the default of :func:`learn_ar`) fixes the rows of A for
  (ux, uy) to the identity and fits only (theta, log s) by Yule-Walker. An AR(1) with a
  mean fitted to image positions would pull every track back towards where the training
  subject walked; the random walk is translation invariant. ``"ar"`` fits all four.
* Q gets ``noise_floor**2`` added to its diagonal before the Cholesky factorisation, so
  that a component constant in training (e.g. theta = 0) keeps a usable noise level, and
  a ridge of max(1e-10 trace(C0) / D, 1e-12) regularises C0^-1.
"""

from __future__ import annotations

from typing import Literal, Sequence

import numpy as np

from .dynamics import ARDynamics, to_beta

__all__ = ["split_runs", "transition_counts", "learn_markov", "yule_walker", "learn_ar", "DEFAULT_NOISE_FLOOR"]

#: Minimum process-noise std on beta = (ux px, uy px, theta rad, log s).
DEFAULT_NOISE_FLOOR = np.array([0.5, 0.5, 0.005, 0.005])


def split_runs(frame_index: np.ndarray, sequence: np.ndarray | None = None) -> list[np.ndarray]:
    """Positions of consecutive-frame runs: a run breaks where the frame index does not step
    by exactly 1 or the sequence id changes.

    Parameters
    ----------
    frame_index : (T,) int64
    sequence : (T,) int64, optional

    Returns
    -------
    list of (T_r,) int64 index arrays into the inputs, in order, covering every item.
    """
    f = np.asarray(frame_index, dtype=np.int64)
    if f.ndim != 1:
        raise ValueError(f"frame_index must be 1-D, got shape {f.shape}")
    if f.size == 0:
        return []
    s = np.zeros_like(f) if sequence is None else np.asarray(sequence, dtype=np.int64)
    if s.shape != f.shape:
        raise ValueError("sequence ids must match frame_index")
    brk = np.nonzero((np.diff(f) != 1) | (np.diff(s) != 0))[0] + 1
    return np.split(np.arange(f.size), brk)


def transition_counts(label_runs: Sequence[np.ndarray], K: int) -> np.ndarray:
    """n_ij = number of t with k_{t-1} = i and k_t = j inside each run. Returns (K, K) float64."""
    n = np.zeros((K, K))
    for run in label_runs:
        r = np.asarray(run, dtype=np.int64)
        if r.size and (r.min() < 0 or r.max() >= K):
            raise ValueError(f"exemplar labels must lie in [0, {K})")
        if r.size >= 2:
            np.add.at(n, (r[:-1], r[1:]), 1.0)
    return n


def learn_markov(label_runs: Sequence[np.ndarray], K: int, prior: float = 1.0) -> np.ndarray:
    """Markov matrix over exemplars by histogramming transitions (sec. 4.3, item 1).

    Parameters
    ----------
    label_runs : list of (T_r,) int64 exemplar labels, one array per run of consecutive frames.
    K : int, number of exemplars.
    prior : float > 0, additive count per cell (symmetric Dirichlet).

    Returns
    -------
    M : (K, K) float64, M[i, j] = p(k_t = j | k_{t-1} = i), every entry > 0, rows sum to 1.
    """
    if int(K) != K or K < 1:
        raise ValueError(f"K must be a positive integer, got {K}")
    if not prior > 0:
        raise ValueError(f"the Markov prior count must be positive (unseen transitions must stay possible), "
                         f"got {prior}")
    n = transition_counts(label_runs, K)
    # M_ij = (n_ij + a) / (n_i + K a)
    return (n + prior) / (n.sum(axis=1, keepdims=True) + K * prior)


def yule_walker(runs: Sequence[np.ndarray], ridge: float = 1e-10) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """First-order vector AR by Yule-Walker, pooled over runs.

    Parameters
    ----------
    runs : list of (T_r, D) float64 series.
    ridge : float, C0 += ridge * trace(C0) / D * I before inversion.

    Returns
    -------
    A : (D, D) float64, x_{t+1} - m = A (x_t - m) + e_t.
    mean : (D,) float64, m.
    Q : (D, D) float64, covariance of the residuals e_t.
    """
    runs = [np.asarray(r, dtype=np.float64) for r in runs]
    runs = [r[:, None] if r.ndim == 1 else r for r in runs]
    if not runs or sum(r.shape[0] for r in runs) == 0:
        raise ValueError("no time series to fit")
    dim = runs[0].shape[1]
    if any(r.ndim != 2 or r.shape[1] != dim for r in runs):
        raise ValueError("every run must be (T_r, D) with the same D")
    if not all(np.isfinite(r).all() for r in runs):
        raise ValueError("time series contain NaN or inf")
    n_pairs = sum(max(r.shape[0] - 1, 0) for r in runs)
    if n_pairs < 2:
        raise ValueError(f"need at least 2 consecutive-frame transitions to fit the AR process, got {n_pairs}")
    allx = np.concatenate(runs)
    n = allx.shape[0]
    mean = allx.mean(axis=0)
    c = allx - mean
    # C0 = (1/n) sum_t (x_t - m)(x_t - m)^T
    C0 = c.T @ c / n
    C1 = np.zeros((dim, dim))
    for r in runs:
        rc = r - mean
        # C1 = (1/n) sum_t (x_{t+1} - m)(x_t - m)^T
        C1 += rc[1:].T @ rc[:-1]
    C1 /= n
    reg = C0 + max(ridge * np.trace(C0) / dim, 1e-12) * np.eye(dim)
    # A = C1 C0^-1   (solve A C0 = C1)
    A = np.linalg.solve(reg.T, C1.T).T
    res = np.concatenate([(r[1:] - mean) - (r[:-1] - mean) @ A.T for r in runs if r.shape[0] >= 2])
    # Q = (1/n_pairs) sum_t e_t e_t^T
    Q = res.T @ res / res.shape[0]
    return A, mean, Q


def learn_ar(alpha_runs: Sequence[np.ndarray], translation: Literal["random_walk", "ar"] = "random_walk",
             noise_floor: np.ndarray = DEFAULT_NOISE_FLOOR) -> ARDynamics:
    """AR(1) dynamics on beta = (ux, uy, theta, log s) from training transforms (sec. 4.3, item 2).

    Parameters
    ----------
    alpha_runs : list of (T_r, 4) float64 alpha = (ux, uy, theta, s), one per run of consecutive frames.
    translation : {"random_walk", "ar"}, see the module notes.
    noise_floor : (4,) float64, std added in quadrature to the residual noise.

    Returns
    -------
    ARDynamics with B = chol(Q + diag(noise_floor^2)).
    """
    if translation not in ("random_walk", "ar"):
        raise ValueError(f"translation model must be 'random_walk' or 'ar', got {translation!r}")
    beta_runs = [to_beta(np.asarray(a, dtype=np.float64).reshape(-1, 4)) for a in alpha_runs]
    floor = np.asarray(noise_floor, dtype=np.float64)
    if floor.shape != (4,) or (floor < 0).any():
        raise ValueError(f"noise_floor must be (4,) and non-negative, got {floor}")
    if translation == "ar":
        A, mean, _ = yule_walker(beta_runs)
    else:
        # theta, log s by Yule-Walker; ux, uy: A rows = identity (random walk)
        A_sub, m_sub, _ = yule_walker([b[:, 2:] for b in beta_runs])
        A = np.eye(4)
        A[2:, 2:] = A_sub
        mean = np.concatenate([np.concatenate(beta_runs)[:, :2].mean(axis=0), m_sub])
    res = np.concatenate([(b[1:] - mean) - (b[:-1] - mean) @ A.T for b in beta_runs if b.shape[0] >= 2])
    # Q = cov of the one-step residuals, floored;  B B^T = Q
    Q = res.T @ res / res.shape[0] + np.diag(floor**2)
    Q = 0.5 * (Q + Q.T)
    try:
        B = np.linalg.cholesky(Q)
    except np.linalg.LinAlgError:
        w, V = np.linalg.eigh(Q)
        B = V @ np.diag(np.sqrt(np.maximum(w, 0.0)))
    return ARDynamics(A=A, mean=mean, B=B)
