"""A motion model that switches between two modes (``motion_switch``; off at 0).

The constant-velocity model (:mod:`.dynamics`) predicts c_{t-1} + v dt. When the target turns or stops
-- a face swinging back, a skater changing direction, any motion played at two or three times its speed
-- the prediction overshoots by |v| dt, the filter's window is centred where the target is not (its
cosine taper halves the target's features a quarter of the window from its centre) and the motion
prior pulls the particles towards the overshoot. A mixed-state particle filter (Isard & Blake, "A
mixed-state Condensation tracker with automatic model-switching", ICCV 1998; McGinnity & Irwin's
multiple-model particle filter, 2000) gives every particle a discrete motion mode beside its place, the
modes switching by a Markov chain, and lets the likelihood pick the mode. Here two modes:

* m = 0, constant velocity: c_t ~ N(c_{t-1} + v dt, (sigma_p sqrt(dt) + beta |v| dt)^2 I), as without modes;
* m = 1, manoeuvre: the target kept its speed but not its heading, or stopped:
  c_t ~ N(c_{t-1}, (sigma_p sqrt(dt) + |v| dt)^2 I) -- the velocity's mean moved into the noise,

sigma_p = ``motion_prior`` box, beta = ``speed_noise``; the two coincide while the target is still. The
mode switches with probability p = ``motion_switch`` a frame,

    pi_t(1) = (1 - p) mu_{t-1}(1) + p (1 - mu_{t-1}(1)),        (the Markov transition, IMM's eq. of mixing)

mu_{t-1}(1) the posterior probability of the manoeuvre after frame t-1. Each particle of the proposal
draws its mode from pi_t and moves by it (the CV ones by v dt plus beta |v| dt w, the others by |v| dt
w); every particle, those drawn at the response too, is weighed by the motion prior of the mixture,

    p(c_t) = sum_m pi_t(m) N(c_t; pred_m, S_m),

and the manoeuvre's posterior probability is the weighted mean of the particles' responsibilities,

    mu_t(1) = sum_i W_i pi_t(1) N(c_i; pred_1, S_1) / p(c_i).

The filter's window is centred at the mixture's mean prediction c_{t-1} + pi_t(0) v dt.

Departures: Isard & Blake carry each particle's mode through resampling; here the modes are collapsed
to the probability mu after each frame (the mixing step of Blom & Bar-Shalom's IMM, IEEE TAC 1988) and
drawn again from pi, and mu is read from the mixture's responsibilities (Rao-Blackwellised over the
mode), not counted from the particles' labels. The two modes share one velocity estimate (IMM keeps
one per mode). A frame the target is not judged present leaves mu at pi (no evidence of the mode).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .params import DCFParams

__all__ = ["Motion", "predict", "draw", "move", "log_prior", "posterior", "log_place"]


@dataclass(frozen=True)
class Motion:
    """The two modes' predictions of a frame: ``pi`` (2,) the modes' prior probabilities pi_t, ``pred``
    (2, 2) each mode's predicted centre (rows: mode), ``std`` (2, 2) each mode's prior std (sx, sy) px,
    ``noise`` (2,) the std of each mode's own share of the particles' noise (px), ``mean`` (2,) the
    mixture's mean prediction (the window's centre), ``origin`` (2,) the last estimate c_{t-1}, about which
    the proposal walked (a mode's particles move by pred_m - origin)."""

    pi: np.ndarray
    pred: np.ndarray
    std: np.ndarray
    noise: np.ndarray
    mean: np.ndarray
    origin: np.ndarray


def predict(p: DCFParams, mu: float, centre: np.ndarray, velocity: np.ndarray, box: tuple[float, float],
            extra: float, spread: float, dt: float) -> Motion:
    """The modes' prior of frame t from ``mu`` = mu_{t-1}(1), the last estimate ``centre`` (2,), the
    ``velocity`` (2,) px / frame, the box (w, h), ``extra`` = beta |v| dt, the place's ``spread`` since the
    target was last seen (added in quadrature, as the tracker's prior) and ``dt`` frame periods."""
    q = p.motion_switch
    # pi_t(1) = (1 - p) mu_{t-1}(1) + p (1 - mu_{t-1}(1))
    pi1 = (1.0 - q) * mu + q * (1.0 - mu)
    pi = np.array([1.0 - pi1, pi1])
    speed = float(np.hypot(velocity[0], velocity[1])) * dt
    pred = np.stack([centre + velocity * dt, centre.astype(np.float64)])
    noise = np.array([extra, speed])
    base = p.motion_prior * math.sqrt(dt) * np.asarray(box, dtype=np.float64)
    # S_m = (sigma_p sqrt(dt) + noise_m)^2, widened by the spread in quadrature
    std = np.hypot(base[None, :] + noise[:, None], spread)
    # the mixture's mean: c_{t-1} + pi_t(0) v dt
    mean = centre + pi[0] * velocity * dt
    return Motion(pi, pred, std, noise, mean, pred[1])


def draw(m: Motion, n: int, rng: np.random.Generator) -> np.ndarray:
    """(n,) int the mode of each of ``n`` particles of the proposal, drawn from pi_t."""
    return (rng.random(n) < m.pi[1]).astype(np.int64)


def move(m: Motion, walked: np.ndarray, modes: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """(N, 2) the walked centres ``walked`` (N, 2) moved by their modes ``modes`` (N,): the CV ones by
    v dt + beta |v| dt w, the manoeuvring ones by |v| dt w (w ~ N(0, I_2))."""
    w = rng.standard_normal((len(walked), 2))
    # c_t = c~_t + (pred_m - c_{t-1}) + noise_m w
    return walked + (m.pred[modes] - m.origin) + m.noise[modes][:, None] * w


def _log_modes(m: Motion, xy: np.ndarray) -> np.ndarray:
    """(N, 2) log pi_t(m) + log N(c_i; pred_m, S_m) of the centres ``xy`` (N, 2)."""
    out = np.empty((len(xy), 2))
    for k in range(2):
        sx, sy = m.std[k]
        # log N = -((x - px)^2 / 2 sx^2 + (y - py)^2 / 2 sy^2) - log(2 pi sx sy)
        d2 = (xy[:, 0] - m.pred[k, 0]) ** 2 / (2.0 * sx * sx) + (xy[:, 1] - m.pred[k, 1]) ** 2 / (2.0 * sy * sy)
        out[:, k] = (math.log(m.pi[k]) if m.pi[k] > 0 else -np.inf) - d2 - math.log(2.0 * math.pi * sx * sy)
    return out


def log_prior(m: Motion, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """log p(c_i) = log sum_m pi_t(m) N(c_i; pred_m, S_m) of the centres ``xy`` (N, 2), and (N,) the
    manoeuvre's responsibility pi_t(1) N(c_i; pred_1, S_1) / p(c_i)."""
    lm = _log_modes(m, xy)
    top = lm.max(axis=1)
    # log sum_m exp(l_m), by the largest term
    lp = top + np.log(np.exp(lm[:, 0] - top) + np.exp(lm[:, 1] - top))
    return lp, np.exp(lm[:, 1] - lp)


def posterior(W: np.ndarray, resp1: np.ndarray) -> float:
    """mu_t(1) = sum_i W_i r_i: the manoeuvre's posterior probability from the normalised weights ``W``
    (N,) and the responsibilities ``resp1`` (N,) (einsum: the same bits in one thread and in many)."""
    return float(min(max(np.einsum("i,i->", W, resp1), 0.0), 1.0))


def log_place(m: Motion, c: np.ndarray, area: float) -> float:
    """log p(c) + log A: how much likelier the mixture's prior puts the target at ``c`` (2,) than clutter,
    uniform over the ``area`` (px^2) of the window."""
    return float(log_prior(m, np.asarray(c, dtype=np.float64)[None, :])[0][0]) + math.log(area)
