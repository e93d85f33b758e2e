"""Dynamics p(X_t | X_{t-1}) for X = (alpha, k) (Toyama & Blake 2002, sec. 4.3).

Two independent parts:

1. a Markov matrix M over exemplars, p(k_t = j | k_{t-1} = i) = M[i, j];
2. a first-order auto-regressive process on the transform,

       beta_t - mean = A (beta_{t-1} - mean) + B w_t,   w_t ~ N(0, I_4),

   where beta = (ux, uy, theta, log s). The scale runs in log space so that it stays
   positive; translation and rotation are unchanged.

Departures
----------
* :func:`scale_mean_at`: on video the model was not learned on, the AR(1) process on log s
  reverts to the initial box's scale, not to the learned mean (the training person's distance
  from the training camera: a model learned on caviar1, people about 28x73 px, pulled a 17x50 px
  pedestrian of crossing to 28x73 within three frames).
* :func:`at_resolution`: the noise of theta and log s is carried to the tracked target's
  resolution. The process is learned from the exemplar-composed training states (sec. 4.3),
  whose angle and scale move mostly with how precisely an exemplar can be aligned to each
  training item, and that is limited by the training target's size in pixels: a pixel of
  misalignment is 6 % of scale on crossing's 16x42 px pedestrian and 3 % on caviar1's 28x73 px
  one. A model learned on crossing (theta and log s noise 0.15-0.18 a frame) let a caviar1 pedestrian,
  1.9 times its size, shrink onto her upper body and jump 10-17 px up and down. The noise rows
  of theta and log s are divided by r, the initial box's size over the largest training
  target's, where r > 1: a target twice the size of every training target gets half the angle
  and scale noise. A target within the training sizes keeps the learned noise (the noise was
  learned at those resolutions; enlarging it for smaller targets made caviar1 frames 150-381,
  where the walker is 0.9 of the reference size, worse with its own model, and scaling it for
  caviar1's first box, 1.08 of the median training size, lowered the AUC of its own model).
  Translation noise stays in pixels (scaling it with s as well was worse in both directions
  between caviar1 and crossing).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["ARDynamics", "random_walk", "scale_mean_at", "at_resolution", "to_beta", "from_beta", "sample_markov",
           "sample_categorical"]


def to_beta(alpha: np.ndarray) -> np.ndarray:
    """(..., 4) alpha = (ux, uy, theta, s) -> beta = (ux, uy, theta, log s)."""
    b = np.array(alpha, dtype=np.float64, copy=True)
    b[..., 3] = np.log(b[..., 3])
    return b


def from_beta(beta: np.ndarray) -> np.ndarray:
    """(..., 4) beta = (ux, uy, theta, log s) -> alpha = (ux, uy, theta, s)."""
    a = np.array(beta, dtype=np.float64, copy=True)
    a[..., 3] = np.exp(a[..., 3])
    return a


@dataclass(frozen=True)
class ARDynamics:
    """First-order AR process on beta = (ux, uy, theta, log s).

    Attributes
    ----------
    A : (4, 4) float64
        Transition matrix.
    mean : (4,) float64
        Process mean (irrelevant where the corresponding row of A is the identity).
    B : (4, 4) float64
        Noise gain; the process noise covariance is B B^T.
    """

    A: np.ndarray
    mean: np.ndarray
    B: np.ndarray

    def __post_init__(self) -> None:
        for name, shape in (("A", (4, 4)), ("mean", (4,)), ("B", (4, 4))):
            v = np.asarray(getattr(self, name), dtype=np.float64)
            if v.shape != shape:
                raise ValueError(f"ARDynamics.{name} must have shape {shape}, got {v.shape}")
            if not np.isfinite(v).all():
                raise ValueError(f"ARDynamics.{name} contains NaN or inf")
            object.__setattr__(self, name, v)

    def predict(self, alpha: np.ndarray, rng: np.random.Generator, dt: float = 1.0) -> np.ndarray:
        """Sample alpha_t ~ p(alpha_t | alpha_{t-1}) for N particles. (N, 4) -> (N, 4).

        ``dt``: the time since the previous frame in frame periods (1: the next frame); the
        noise grows as sqrt(dt), as a random walk's does over dt steps (A itself is not raised
        to dt). With dt = 1 the bits are those of the one-step model."""
        beta = to_beta(alpha)
        w = rng.standard_normal(beta.shape) * np.sqrt(dt)
        # beta_t = mean + A (beta_{t-1} - mean) + sqrt(dt) B w
        beta_t = self.mean + (beta - self.mean) @ self.A.T + w @ self.B.T
        return from_beta(beta_t)

    def log_density(self, alpha_t: np.ndarray, alpha_prev: np.ndarray) -> np.ndarray:
        """log p(alpha_t | alpha_{t-1}) up to a constant, in beta coordinates. (N, 4) x (N, 4) -> (N,)."""
        r = to_beta(alpha_t) - (self.mean + (to_beta(alpha_prev) - self.mean) @ self.A.T)
        cov = self.B @ self.B.T + 1e-12 * np.eye(4)
        sol = np.linalg.solve(cov, r.T).T
        return -0.5 * np.einsum("ij,ij->i", r, sol)


def scale_mean_at(dynamics: ARDynamics, log_s: float) -> ARDynamics:
    """The AR(1) process with the mean of log s moved to ``log_s`` (A and B unchanged).

    The learned mean of log s is the training target's distance from the training camera;
    on another video the target's own size (the initial box) is the level to revert to.
    """
    mean = dynamics.mean.copy()
    mean[3] = log_s
    return ARDynamics(A=dynamics.A, mean=mean, B=dynamics.B)


def at_resolution(dynamics: ARDynamics, r: float) -> ARDynamics:
    """The AR(1) process with the noise of theta and log s (rows 2 and 3 of B) divided by ``r``
    where ``r`` > 1: a learned contour model tracking a target ``r`` times the size of the largest
    it was learned on (module docstring). Unchanged for ``r`` <= 1.

    Parameters
    ----------
    dynamics : the learned process.
    r : the initial box's scale over the largest training item's, s_0 / s_train (s = sqrt(w h)
        over the reference box's, ``M2Model.alpha_from_box``, ``M2Model.train_scale``); 0 < r.
    """
    if not r > 0:  # NaN refused too
        raise ValueError(f"the scale ratio must be positive, got {r}")
    if r <= 1.0 + 1e-9:  # a first box as large as the largest training target (caviar1's own) is within
        return dynamics
    B = dynamics.B.copy()
    # (theta, log s) noise at the target's resolution: rows 2, 3 of B over r
    B[2:] /= r
    return ARDynamics(A=dynamics.A, mean=dynamics.mean, B=B)


def random_walk(std_xy: float, std_theta: float, std_log_s: float) -> ARDynamics:
    """A random walk (A = I) with independent noise on each component."""
    return ARDynamics(A=np.eye(4), mean=np.zeros(4), B=np.diag([std_xy, std_xy, std_theta, std_log_s]))


def sample_categorical(p: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """n draws of k ~ p by the inverse CDF (one ``rng.uniform(size=n)`` call).

    Parameters
    ----------
    p : (K,) float64, probabilities summing to 1 (the mixture weights pi_k, say).
    n : int >= 1

    Returns
    -------
    (n,) int64
    """
    if n < 1:
        raise ValueError(f"number of draws must be >= 1, got {n}")
    cdf = np.cumsum(np.asarray(p, dtype=np.float64))
    cdf[-1] = 1.0  # guard against round-off so every draw finds a category
    return np.searchsorted(cdf, rng.uniform(size=n), side="right").astype(np.int64)


def sample_markov(k: np.ndarray, markov: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Sample k_t ~ M[k_{t-1}, :] for each particle.

    Parameters
    ----------
    k : (N,) int64, previous exemplar indices.
    markov : (K, K) float64, rows sum to 1.
    rng : numpy.random.Generator

    Returns
    -------
    (N,) int64
    """
    k = np.asarray(k, dtype=np.int64)
    if markov.shape[0] == 1:
        return np.zeros_like(k)
    cdf = np.cumsum(markov[k], axis=1)
    cdf[:, -1] = 1.0
    u = rng.uniform(size=(k.size, 1))
    return (u > cdf).sum(axis=1).astype(np.int64)
