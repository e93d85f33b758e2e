"""The appearance tracker on the tracker protocol of :mod:`gflow_core.tracker`.

:class:`AppearanceTracker` is the appearance tracker's :class:`~gflow_core.tracker.TrackingFilter`:

* ``observe`` -- the frame's grey levels and appearance channels (:func:`.filter.features`);
* ``init`` -- the anchor exemplar and the particles about the user's box
  (:func:`.filter.initialise`);
* ``propose`` -- the dynamics' random walk on (x, y, log s) about the posterior of frame t-1,
  std ``std_xy_rel sqrt(w0 h0)`` px for the centre and ``std_log_s`` for log s (M2 sec. 4.3 with
  A = I); the velocity term and the particles drawn at the response's peak are added by the
  update, which reads the frame;
* ``update`` -- :func:`.filter.step`: the mixture proposal weighed by the exemplar likelihood
  and the motion prior, the estimate, whether the target is present, hidden or lost, the search
  for a hidden one, the exemplars' update and resampling;
* ``coast`` -- the posterior carried over a frame with no evidence: particles and model unchanged,
  the target judged as before, confidence 0.

The proposal's random walk (:mod:`gflow_core.appearance.dynamics`) works on alpha = (x, y,
theta, s) with theta = 0 and s = exp(log s), the particles as the pipeline's particle messages
carry them, so a step here and a step through the stages (``stages/spec_box.py``) give the same
bits.

Random draws of frame ``t`` (:class:`~gflow_core.tracker.FrameRng`): the initial particles from
``stream(PURPOSE_INIT)``, the proposal from ``stream(PURPOSE_WALK)``, the update's detection
draws and resampling from ``stream(PURPOSE_STEP)``.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from . import filter as ap
from .. import colour
from .dynamics import PURPOSE_WALK, alpha_of, particles_of, walk
from .params import AppearanceParams
from ..features import to_grey
from ..tracker import Box, Estimate, FrameRng, UnusableFrame, box_estimate, box_step_estimate

__all__ = ["AppearanceTracker", "AppearanceObservation", "AppearanceProposal", "AppearanceTrack", "TRACKER",
           "alpha_of", "particles_of", "walk", "PURPOSE_INIT", "PURPOSE_STEP", "PURPOSE_WALK"]

#: the streams of a frame's draws: the initial particles, the update (the proposal's: PURPOSE_WALK)
PURPOSE_INIT, PURPOSE_STEP = 0x51A1, 0x51A2


@dataclass(frozen=True)
class AppearanceObservation:
    """What the appearance tracker reads of a frame.

    grey : (H, W) uint8 grey levels; feat : (H, W, 4) float32 appearance channels, or the
    ``ValueError`` computing them raised (a frame too small for them), raised by a step that uses it.
    bins : (H, W) uint8 colour bins (:func:`gflow_core.colour.bins`), or None without the colour cue.
    """

    grey: np.ndarray
    feat: np.ndarray | ValueError
    bins: np.ndarray | None = None

    def channels(self) -> np.ndarray:
        """The appearance channels (raises the ``ValueError`` they raised)."""
        if isinstance(self.feat, ValueError):
            raise self.feat
        return self.feat


@dataclass(frozen=True)
class AppearanceProposal:
    """The proposal for frame t: particles (N, 3) (x, y, log s) from the dynamics' random walk, and
    ``dt``, the frame periods since the posterior they came from."""

    particles: np.ndarray
    dt: float = 1.0


@dataclass(frozen=True)
class AppearanceTrack:
    """The posterior after a frame: the model's state (:class:`.filter.AppearanceState`) and how
    the target was judged on the last frame with evidence (what a coasted frame reports)."""

    core: ap.AppearanceState
    target_state: str = "tracked"


class AppearanceTracker:
    """The appearance tracker's :class:`gflow_core.tracker.TrackingFilter` (stateless: everything
    is in :class:`AppearanceTrack`)."""

    name = "appearance"
    Params = AppearanceParams

    def observe(self, params: AppearanceParams, image: np.ndarray) -> AppearanceObservation:
        """The grey levels, appearance channels and (``params.colour``) colour bins of a ``(H, W, 3)``
        BGR or ``(H, W)`` grey frame.

        Raises :class:`UnusableFrame` for a uniform frame (no evidence) and ``ValueError`` for one
        that is not an image."""
        grey = to_grey(image)
        self._check_evidence(grey)
        return self._observation(grey, colour.bins(image) if params.colour else None)

    def observe_grey(self, params: AppearanceParams, grey: np.ndarray) -> AppearanceObservation:
        """:meth:`observe` of a frame already in grey levels ``(H, W)`` uint8 (its colour bins are
        grey-level bins)."""
        self._check_evidence(grey)
        return self._observation(grey, colour.bins(grey) if params.colour else None)

    @staticmethod
    def _check_evidence(grey: np.ndarray) -> None:
        if grey.size == 0 or int(grey.max()) == int(grey.min()):
            raise UnusableFrame("uniform frame, no evidence")

    @staticmethod
    def _observation(grey: np.ndarray, bins: np.ndarray | None) -> AppearanceObservation:
        try:
            return AppearanceObservation(grey, ap.features(grey), bins)
        except ValueError as e:
            return AppearanceObservation(grey, e, bins)

    def init(self, params: AppearanceParams, obs: AppearanceObservation, box: Box, rng: FrameRng,
             resources: Mapping[str, Any]) -> tuple[AppearanceTrack, Estimate]:
        """The anchor exemplar of ``box`` and the particles about it (``ValueError`` for a box
        outside the frame or a frame too small for the channels)."""
        core = ap.initialise(obs.channels(), box, params, rng.stream(PURPOSE_INIT), obs.bins)
        a = np.array([core.centre[0], core.centre[1], 0.0, 1.0])
        est = self.estimate(params, rng.t, ap.box_of(core.centre, core.log_s, core.size0), "init", a, a,
                            np.zeros(4), float(params.particles), 0.0, 1.0, 1.0, "tracked")
        return AppearanceTrack(core), est

    def propose(self, params: AppearanceParams, state: AppearanceTrack, obs: AppearanceObservation | None,
                rng: FrameRng, dt: float = 1.0) -> AppearanceProposal:
        """The random walk about the posterior's particles (:func:`walk`), from ``rng.stream(PURPOSE_WALK)``
        (the frame is not read)."""
        core = state.core
        alpha = walk(params, alpha_of(core.particles), (float(core.size0[0]), float(core.size0[1])),
                     rng.stream(PURPOSE_WALK), dt)
        return AppearanceProposal(particles_of(alpha), dt)

    def update(self, params: AppearanceParams, state: AppearanceTrack, proposal: AppearanceProposal,
               obs: AppearanceObservation, rng: FrameRng) -> tuple[AppearanceTrack, Estimate]:
        """:func:`.filter.step` of the proposal on the frame. The estimate's phase is ``track``,
        ``redetect`` (the search found a hidden target again this frame), ``occluded`` or ``lost``."""
        res = ap.step(state.core, obs.channels(), proposal.particles, params, rng.stream(PURPOSE_STEP), proposal.dt,
                      obs.bins)
        return AppearanceTrack(res.state, res.target_state), box_step_estimate(rng.t, res, params.particles)

    def coast(self, params: AppearanceParams, state: AppearanceTrack, rng: FrameRng,
              obs: AppearanceObservation | None = None) -> tuple[AppearanceTrack, Estimate]:
        """No evidence from frame ``rng.t``: the posterior unchanged; the target is where it was judged
        to be, with no confidence."""
        core = state.core
        a = np.array([core.centre[0], core.centre[1], 0.0, float(np.exp(core.log_s))])
        judged = "tracked" if core.hidden_run == 0 else state.target_state
        est = self.estimate(params, rng.t, ap.box_of(core.centre, core.log_s, core.size0), "coast", a, a,
                            np.zeros(4), float(params.particles), 0.0, 0.0, 0.0, judged)
        return dataclasses.replace(state, target_state=judged), est

    def estimate(self, params: AppearanceParams, t: int, box: tuple[float, float, float, float], phase: str,
                 alpha: np.ndarray, mean: np.ndarray, std: np.ndarray, ess: float, log_evidence: float,
                 score: float, confidence: float, target_state: str) -> Estimate:
        """The appearance tracker's estimate of frame ``t``. ``extras``: ``alpha`` (4,) the estimate
        (x, y, 0, s); ``mean``, ``std`` (4,) the posterior's mean and std of alpha (std of log s);
        ``ess``; ``log_evidence``; ``score``, the posterior mean of the correlation r; ``n``, the
        number of particles."""
        return box_estimate(t, box, phase, alpha, mean, std, ess, log_evidence, score, params.particles, confidence,
                            target_state)


#: the one instance (it keeps no state)
TRACKER = AppearanceTracker()
