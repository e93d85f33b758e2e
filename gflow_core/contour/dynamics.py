"""The contour trackers' proposal (chamfer, m2): p(X_t | X_{t-1}) of M2 sec. 4.3.

Kept apart from :mod:`gflow_core.contour.protocol` so that the proposal stage imports only the
dynamics (numpy), not the filter's image processing (SciPy, OpenCV): a stage process pays at
start-up only for what it runs.

Draws: ``FrameRng(seed, stream_hash, t).stream(PURPOSE_PROPOSAL)``, the same generator as
:func:`gflow_core.tracker.frame_rng` ``(seed, stream, t, PURPOSE)`` that the proposal stage draws from.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..m2 import dynamics as dyn
from ..m2.dynamics import ARDynamics, at_resolution, sample_markov, scale_mean_at
from ..m2.model import M2Model
from ..m2.tracking import ParticleCloud
from ..tracker import Box

__all__ = ["PURPOSE_PROPOSAL", "proposal_dynamics", "propose_cloud", "ContourProposal"]

#: the stream of a frame's proposal draws
PURPOSE_PROPOSAL = 0x9209


def proposal_dynamics(model: M2Model | None, init: Box | None, walk: tuple[float, float, float] | None
                      ) -> tuple[np.ndarray, ARDynamics, bool]:
    """The proposal's (Markov matrix (K, K), AR(1) dynamics, alpha fixed): with no learned model the
    random walk of deviations ``walk`` (std_xy, std_theta, std_log_s) and K = 1; with one its
    Markov matrix and AR(1) process, for a contour model with the log s mean moved to the scale of
    ``init`` (:func:`.m2.dynamics.scale_mean_at`) and the noise of theta and log s at the tracked
    target's resolution (:func:`.m2.dynamics.at_resolution`); a patch model is tracked with no
    alpha transformations (sec. 5.2: alpha fixed)."""
    if model is None:
        if walk is None:
            raise ValueError("a proposal with no learned model needs the random walk's deviations")
        return np.ones((1, 1)), dyn.random_walk(*walk), False
    dynamics = model.dynamics
    if init is not None and model.kind == "curve":
        s0 = float(model.alpha_from_box(init)[3])
        dynamics = scale_mean_at(model.dynamics, float(np.log(s0)))
        if np.isfinite(model.train_scale):  # files before format 3 do not say: their dynamics as learned
            # the target's size over the largest training target's: the resolution the noise is carried to
            dynamics = at_resolution(dynamics, s0 / model.train_scale)
    return model.markov, dynamics, model.kind == "patch"


def propose_cloud(cloud: ParticleCloud, markov: np.ndarray, dynamics: ARDynamics, rng: np.random.Generator,
                  dt: float = 1.0, fixed_alpha: bool = False) -> ParticleCloud:
    """The proposal for the next frame: k_t ~ M[k_{t-1}], alpha_t ~ AR(1)(alpha_{t-1}) over ``dt``
    frame periods (unchanged with ``fixed_alpha``), equal weights. Raises ``ValueError`` for an
    exemplar index beyond the Markov matrix."""
    if cloud.k.max(initial=0) >= markov.shape[0]:
        raise ValueError(f"exemplar index beyond the model's K={markov.shape[0]}")
    k = sample_markov(cloud.k, markov, rng)
    alpha = cloud.alpha.copy() if fixed_alpha else dynamics.predict(cloud.alpha, rng, dt)
    return ParticleCloud(alpha=alpha, k=k, log_w=np.zeros(cloud.n))


@dataclass(frozen=True)
class ContourProposal:
    """The contour proposal of clouds: k_t ~ M[k_{t-1}], alpha_t ~ AR(1)(alpha_{t-1}) over dt frame
    periods (alpha unchanged with ``fixed_alpha``), :func:`propose_cloud`; made with
    ``ContourProposal(*proposal_dynamics(model, init, walk))``."""

    markov: np.ndarray
    dynamics: ARDynamics
    fixed_alpha: bool

    def __call__(self, cloud: ParticleCloud, rng: np.random.Generator, dt: float) -> ParticleCloud:
        return propose_cloud(cloud, self.markov, self.dynamics, rng, dt, self.fixed_alpha)
