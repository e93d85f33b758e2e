"""Illumination-robust texture observation: a gain and a bias per frame (departure from the paper).

The paper observes the object texels directly, ``y_t(x_i(u)) = v_i + w`` (eq. 4), so a
change of light is a change of texture that the Kalman texels can follow only at the rate
``Psi_v`` allows; until then Gauss-Newton (eq. 14) explains the brighter or darker face by
moving the pose. Here the observation is affine in the texture::

    y_t(x_i(u)) = a v_i + b + w'          (one gain a and bias b per expert, pose and frame)

and ``a, b`` are nuisance parameters estimated in closed form (weighted least squares of
``y`` on the predicted texel means ``mu_v``, weights ``1 / (sigma_v + sigma_w)``, with a weak
Gaussian prior ``a ~ N(1, gain_std^2)``, ``b ~ N(0, bias_std^2)`` and ``a`` clamped to
``[1 / gain_max, gain_max]``). Gauss-Newton (eq. 14) and the likelihood (eq. 13) use the
residual ``y - (a mu_v + b)`` with the paper's variances ``sigma_v + sigma_w`` (the texel
variance is not scaled by ``a^2``: an approximation for ``a`` near 1); the texel Kalman update
(eq. 7, 8) observes the corrected ``y' = (y - b) / a``, so the texels stay in the photometric
frame of the first frame. ``a, b`` are the profile (maximum-likelihood) values at each pose:
recomputed, never sampled, so the proposal density ``g`` and the importance weights (eq. 16)
are unchanged in form.

A first version observed ``y'`` everywhere and added the Jacobian ``-n log a`` of the change of
variables to the likelihood; that term rewards ``a < 1`` by up to ``n log gain_max`` (300 for
the 225-vertex head), so flat, dark patches won the coarse search on ``jumping``. The form
above has no such reward.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["Photometric", "gain_bias", "correct", "predict"]


@dataclass(frozen=True)
class Photometric:
    """Settings of the per-frame gain/bias fit.

    Attributes
    ----------
    gain_std, bias_std : float
        Prior standard deviations of ``a`` about 1 and ``b`` about 0 (grey levels in [0, 1]).
    gain_max : float
        ``a`` is clamped to ``[1 / gain_max, gain_max]`` (> 1).
    """

    gain_std: float = 0.5
    bias_std: float = 0.3
    gain_max: float = 2.0

    def __post_init__(self) -> None:
        for nm in ("gain_std", "bias_std"):
            v = getattr(self, nm)
            if not (math.isfinite(v) and v > 0.0):
                raise ValueError(f"{nm} must be finite and > 0, got {v!r}")
        if not (math.isfinite(self.gain_max) and self.gain_max > 1.0):
            raise ValueError(f"gain_max must be finite and > 1, got {self.gain_max!r}")


def gain_bias(y: np.ndarray, mu: np.ndarray, w: np.ndarray, ph: Photometric) -> tuple[np.ndarray, np.ndarray]:
    """Gain ``a`` and bias ``b`` minimising ``sum_i w_i (y_i - a mu_i - b)^2`` plus the prior.

    Parameters
    ----------
    y : (..., n) float64
        Observed values at the vertices.
    mu : (..., n) float64
        Predicted texel means (broadcast against ``y``).
    w : (..., n) float64
        Weights ``1 / (sigma_v + sigma_w)`` (broadcast against ``y``).
    ph : Photometric

    Returns
    -------
    a, b : (...) float64
    """
    la = 1.0 / ph.gain_std ** 2
    lb = 1.0 / ph.bias_std ** 2
    w = np.broadcast_to(w, y.shape)
    mu = np.broadcast_to(mu, y.shape)
    sw = np.sum(w, axis=-1)
    sm = np.sum(w * mu, axis=-1)
    smm = np.sum(w * mu * mu, axis=-1)
    sy = np.sum(w * y, axis=-1)
    smy = np.sum(w * mu * y, axis=-1)
    # normal equations  [[smm + la, sm], [sm, sw + lb]] [a, b]^T = [smy + la, sy]^T
    a11, a12, a22 = smm + la, sm, sw + lb
    det = a11 * a22 - a12 * a12  # > 0: the prior makes the system positive definite
    a = ((smy + la) * a22 - a12 * sy) / det
    a = np.clip(a, 1.0 / ph.gain_max, ph.gain_max)
    # b given the (possibly clamped) a
    b = (sy - a * sm) / a22
    return a, b


def correct(y: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The corrected observation ``(y - b) / a`` (``a, b`` broadcast over the last axis)."""
    return (y - b[..., None]) / a[..., None]


def predict(mu: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The predicted observation ``a mu + b`` (``a, b`` broadcast over the last axis)."""
    return a[..., None] * mu + b[..., None]
