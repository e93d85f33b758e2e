"""Particle-filter primitives shared by every tracker: log-space weights, ESS, resampling.

Weights are kept as log-weights everywhere so that a likelihood of exp(-1000) does not
underflow to zero and collapse the filter. Names follow Doucet & Johansen's tutorial and
the ``particles`` library (nchopin/particles).

References
----------
Kitagawa, G. (1996). Monte Carlo filter and smoother for non-Gaussian nonlinear state
space models. J. Comput. Graph. Stat. 5(1) -- systematic resampling.
Kong, Liu & Wong (1994) -- effective sample size ESS = 1 / sum(W_i^2).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["LogWeights", "log_normalize", "ess", "systematic_resample", "weight_histogram"]


def log_normalize(log_w: np.ndarray) -> tuple[np.ndarray, float]:
    """Normalise log-weights so that ``sum(exp(out)) == 1``.

    Parameters
    ----------
    log_w : (N,) float64
        Unnormalised log-weights. ``-inf`` entries are allowed (zero weight).

    Returns
    -------
    log_W : (N,) float64
        Normalised log-weights.
    log_sum : float
        ``log(sum(exp(log_w)))``, the log of the normalising constant.

    Raises
    ------
    ValueError
        If ``log_w`` is empty, contains NaN or ``+inf``, or every weight is zero.
    """
    log_w = np.asarray(log_w, dtype=np.float64)
    if log_w.ndim != 1 or log_w.size == 0:
        raise ValueError(f"log-weights must be a non-empty 1-D array, got shape {log_w.shape}")
    if np.isnan(log_w).any() or np.isposinf(log_w).any():
        raise ValueError("log-weights contain NaN or +inf")
    m = log_w.max()
    if not np.isfinite(m):
        raise ValueError("every particle has zero weight (all log-weights are -inf)")
    # log sum_i exp(lw_i) = m + log sum_i exp(lw_i - m)
    log_sum = float(m + np.log(np.exp(log_w - m).sum()))
    return log_w - log_sum, log_sum


def ess(log_w: np.ndarray) -> float:
    """Effective sample size ``1 / sum(W_i^2)`` of (possibly unnormalised) log-weights.

    Parameters
    ----------
    log_w : (N,) float64

    Returns
    -------
    float in ``[1, N]``.
    """
    log_W, _ = log_normalize(log_w)
    # ESS = 1 / sum_i W_i^2 = exp(-log sum_i exp(2 log W_i))
    two = 2.0 * log_W
    m = two.max()
    return float(np.exp(-(m + np.log(np.exp(two - m).sum()))))


def systematic_resample(log_w: np.ndarray, rng: np.random.Generator, n: int | None = None) -> np.ndarray:
    """Systematic resampling (Kitagawa 1996): one uniform draw, ``n`` evenly spaced pointers.

    Parameters
    ----------
    log_w : (N,) float64
        Log-weights (normalised or not).
    rng : numpy.random.Generator
        The only source of randomness (one ``uniform`` draw).
    n : int, optional
        Number of indices to draw; defaults to ``N``.

    Returns
    -------
    idx : (n,) int64
        Ancestor indices, sorted ascending.
    """
    log_W, _ = log_normalize(log_w)
    n = log_W.size if n is None else int(n)
    if n <= 0:
        raise ValueError(f"number of resampled particles must be positive, got {n}")
    cdf = np.cumsum(np.exp(log_W))
    cdf[-1] = 1.0  # guard against round-off so every pointer finds an ancestor
    # u_i = (U + i) / n,  U ~ Uniform[0, 1)
    u = (rng.uniform() + np.arange(n)) / n
    return np.searchsorted(cdf, u, side="right").astype(np.int64)


def weight_histogram(log_w: np.ndarray, edges: tuple[float, ...] = (0.0, 0.1, 0.5, 1.0, 2.0, 5.0, 10.0)) -> dict[str, int]:
    """How many particles have a relative weight N W_i in each bin (1 = an average particle).

    Parameters
    ----------
    log_w : (N,) float64 log-weights.
    edges : bin edges of N W_i; the last bin is open-ended.

    Returns
    -------
    {"[a, b)": count, ..., ">= last": count}
    """
    log_W, _ = log_normalize(log_w)
    rel = np.exp(log_W) * log_W.size
    bounds = list(edges) + [np.inf]
    out = {}
    for a, b in zip(bounds[:-1], bounds[1:]):
        key = f">= {a:g}" if np.isinf(b) else f"[{a:g}, {b:g})"
        out[key] = int(np.count_nonzero((rel >= a) & (rel < b)))
    return out


@dataclass(frozen=True)
class LogWeights:
    """Immutable log-weights with their normalised form and ESS (as in ``particles``).

    Attributes
    ----------
    lw : (N,) float64
        Unnormalised log-weights.
    """

    lw: np.ndarray
    # set in __post_init__
    _log_W: np.ndarray = field(init=False, repr=False, compare=False)
    _log_sum: float = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        lw = np.asarray(self.lw, dtype=np.float64)
        lw.setflags(write=False)
        object.__setattr__(self, "lw", lw)
        log_W, log_sum = log_normalize(lw)
        log_W.setflags(write=False)
        object.__setattr__(self, "_log_W", log_W)
        object.__setattr__(self, "_log_sum", log_sum)

    @property
    def log_W(self) -> np.ndarray:
        """(N,) normalised log-weights."""
        return self._log_W

    @property
    def W(self) -> np.ndarray:
        """(N,) normalised weights, summing to 1."""
        return np.exp(self._log_W)

    @property
    def log_mean(self) -> float:
        """log of the mean weight, ``log(1/N sum exp(lw))`` (the log marginal likelihood increment)."""
        return self._log_sum - float(np.log(self.lw.size))

    @property
    def ess(self) -> float:
        """Effective sample size, in ``[1, N]``."""
        return float(1.0 / np.sum(self.W**2))
