"""The protocol every tracker implements: ``observe``, ``init``, ``propose``, ``update``, ``coast``.

Every tracker here is a recursive Bayesian filter run in the design's two stages
(``docs/architecture.md``):

1. **propose** -- hypotheses for frame ``t`` from the posterior at ``t - 1``: particles drawn
   from the dynamics, or poses found by optimisation and sampled about their peak (G-flow's
   Laplace proposals, Marks et al. 2004 eq. 14-16);
2. **update** -- the posterior at ``t``: the hypotheses weighed by frame ``t``'s likelihood,
   resampled, and the appearance model updated (G-flow eq. 17, 19, 7-10; M2 eq. 7).

plus **init** (the posterior at the first frame, from the user's box) and **coast** (the
posterior carried over a frame that could not be used). Each is a pure function of
``(params, state, inputs, rng)``: it returns new values and never changes its arguments, and
all its randomness comes from the :class:`FrameRng` it is given, so the same call gives the same
bits in a test, in the Python API (``gflow.Tracker``), ``--inline`` and the stage processes. The
stages of ``stages/`` are thin adapters of these calls: they turn messages into arguments and
results into messages, and hold what travels between processes.

The anchors: Stone Soup's one interface per role with the mathematics in its implementations
(``Predictor.predict``, ``Updater.update``), filterpy's one object per filter, OpenCV's
``init(frame, box)`` / ``update(frame)``.

Conventions: points are ``(x, y)`` pixels with the origin at the top-left pixel centre; a box
is ``(x, y, w, h)``, its top-left corner and its size.
"""

from __future__ import annotations

import zlib
import dataclasses
from dataclasses import dataclass, field
from typing import Any, Mapping, Protocol, TypeVar

import numpy as np

__all__ = ["Box", "Estimate", "unseen", "box_estimate", "box_step_estimate", "FrameRng", "stream_hash", "frame_rng",
           "tracker_rng", "FilterSide", "TrackingFilter", "UnusableFrame", "step", "TARGET_STATES", "PHASES",
           "time_step", "MAX_TIME_STEP"]

#: (x, y, w, h) in pixels
Box = tuple[float, float, float, float]

#: how the tracker judges the target: seen in the box, hidden where it is expected, being searched for
TARGET_STATES = ("tracked", "occluded", "lost")
#: the steps every tracker's estimates name: the first frame, an update with the frame's evidence, a frame
#: coasted over
PHASES = ("init", "track", "coast")


class UnusableFrame(ValueError):
    """A frame that carries no information for the tracker (uniform, say): the caller coasts over it."""


@dataclass(frozen=True)
class FrameRng:
    """The random draws of one frame ``t``: generator ``default_rng([seed, stream_hash, t, *path])``.

    ``path`` separates independent draws within the frame: G-flow's expert ``i`` draws from
    ``stream(i)`` and its resampling from ``stream()``; a particle filter's proposal and filter
    from ``stream(PURPOSE)`` with a constant of their own. ``stream_hash`` is the CRC-32 of the
    camera's stream name (:func:`stream_hash`; ``cam0`` in the shipped graphs).
    """

    seed: int
    stream_hash: int
    t: int

    def __post_init__(self) -> None:
        if self.seed < 0 or self.stream_hash < 0 or self.t < 0:
            raise ValueError(f"seed, stream hash and frame index must be >= 0, got {self.seed}, {self.stream_hash}, "
                             f"{self.t}")

    def stream(self, *path: int) -> np.random.Generator:
        """The generator of one independent draw of this frame."""
        return np.random.default_rng([int(self.seed), int(self.stream_hash), int(self.t), *(int(p) for p in path)])


# Explicit random streams: frame ``t`` of stage ``purpose`` draws from
# ``np.random.default_rng([seed, stream_hash, t, purpose])`` and nothing else, so a stage's
# outputs depend only on its configuration, its seed and the ordered inputs it consumed.


def stream_hash(stream: str) -> int:
    """A stable 32-bit hash of a stream id (CRC-32; Python's ``hash`` is salted per process)."""
    return zlib.crc32(stream.encode("utf-8"))


def frame_rng(seed: int, stream: str, seq: int, purpose: int) -> np.random.Generator:
    """The generator for one frame of one stage. ``purpose`` separates draws inside a stage."""
    if seed < 0 or seq < 0:
        raise ValueError(f"seed and seq must be non-negative, got seed={seed}, seq={seq}")
    return np.random.default_rng([seed, stream_hash(stream), seq, purpose])


def tracker_rng(seed: int, stream: str, seq: int) -> FrameRng:
    """The draws of one frame for a tracker: ``FrameRng(seed, stream_hash(stream), seq)``, whose
    ``stream(purpose)`` is :func:`frame_rng`'s generator."""
    return FrameRng(int(seed), stream_hash(stream), int(seq))


#: the longest step a tracker is told (25 periods: one second at 25 frames/s). After a longer gap
#: (a reconnect) the motion models' spread already covers any motion a tracker could follow,
#: and the search windows that grow with it stay affordable.
MAX_TIME_STEP = 25.0


def time_step(period_ns: float, stamp_ns: int, prev_stamp_ns: int) -> float:
    """The ``dt`` of :meth:`TrackingFilter.propose`: the time from the frame stamped ``prev_stamp_ns`` to
    the one stamped ``stamp_ns``, in nominal frame periods of ``period_ns``, within [1, :data:`MAX_TIME_STEP`].

    A tracker's motion model is tuned per frame. A live source skips frames when the tracker is
    slower than the camera (the newest frame wins) and loses some while it reconnects, so the
    frames a tracker sees are not one period apart: its motion noise and proposal widths must grow
    with the time that passed.

    1.0 when the stamps are media time (``period_ns`` is 0: files keep their bits, since multiplying
    by 1.0 and taking sqrt(1.0) are exact) or either stamp is missing (0: a message made without a
    frame). Never below 1: a live source delivers at most one frame a period, and the host stamps of
    frames decoded in a burst are closer together than the camera took them.
    """
    if period_ns <= 0 or stamp_ns <= 0 or prev_stamp_ns <= 0:
        return 1.0
    return min(MAX_TIME_STEP, max(1.0, (stamp_ns - prev_stamp_ns) / period_ns))


@dataclass(frozen=True)
class Estimate:
    """What a tracker reports for one frame.

    Attributes
    ----------
    frame : int
        The frame index ``t``.
    box : (x, y, w, h) float
        Where the target is, in pixels.
    confidence : float in [0, 1]
        How sure the tracker is that ``box`` holds the target.
    target_state : {"tracked", "occluded", "lost"}
        The target as the tracker judges it.
    phase : str
        Which step made it: ``init`` for the first frame, ``track`` after an update with the
        frame's evidence, ``coast`` when the frame could not be used and the posterior was only
        carried over; a tracker may name steps of its own (the contour filter's ``lost`` and
        ``redetect``, the appearance filter's ``occluded``).
    extras : mapping
        The tracker's own outputs (G-flow: ``pose``, ``rotation``, ``expert_points``, ...; see
        each tracker's ``estimate`` docstring). Arrays are read-only.
    """

    frame: int
    box: Box
    confidence: float
    target_state: str
    phase: str
    extras: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.target_state not in TARGET_STATES:
            raise ValueError(f"target_state must be one of {', '.join(TARGET_STATES)}, got {self.target_state!r}")


def box_estimate(t: int, box: Box, phase: str, alpha: np.ndarray, mean: np.ndarray, std: np.ndarray, ess: float,
                 log_evidence: float, score: float, particles: int, confidence: float, target_state: str) -> Estimate:
    """The estimate of frame ``t`` of a box tracker over alpha = (x, y, 0, s) (appearance, dcf).
    ``extras``: ``alpha`` (4,) the estimate; ``mean``, ``std`` (4,) the posterior's mean and std of
    alpha (std of log s); ``ess``; ``log_evidence``; ``score`` (the tracker's own: see its
    ``estimate``); ``n``, the number of particles."""
    b = tuple(float(v) for v in box)
    extras = {"alpha": tuple(float(v) for v in alpha), "mean": tuple(float(v) for v in mean),
              "std": tuple(float(v) for v in std), "ess": float(ess), "log_evidence": float(log_evidence),
              "score": float(score), "n": int(particles)}
    return Estimate(frame=int(t), box=(b[0], b[1], b[2], b[3]), confidence=float(confidence),
                    target_state=target_state, phase=phase, extras=extras)


def box_step_estimate(t: int, res: Any, particles: int) -> Estimate:
    """:func:`box_estimate` of a box tracker's step result ``res`` (appearance, dcf): its ``state``
    (``centre``, ``log_s``), posterior ``mean`` and ``std`` (3,) of (x, y, log s), ``box``, ``ess``,
    ``log_evidence``, ``score``, ``confidence``, ``target_state`` and ``redetected``. The phase is
    ``track``, ``redetect`` (the search found a hidden target again this frame), ``occluded`` or ``lost``."""
    nst = res.state
    a = np.array([nst.centre[0], nst.centre[1], 0.0, float(np.exp(nst.log_s))])
    mean = np.array([res.mean[0], res.mean[1], 0.0, float(np.exp(res.mean[2]))])
    std = np.array([res.std[0], res.std[1], 0.0, float(res.std[2])])
    phase = ("redetect" if res.redetected else "track") if res.target_state == "tracked" else res.target_state
    return box_estimate(t, res.box, phase, a, mean, std, res.ess, res.log_evidence, res.score, particles,
                        res.confidence, res.target_state)


P = TypeVar("P")
S = TypeVar("S")
O = TypeVar("O")  # noqa: E741 (the observation)
Q = TypeVar("Q")
P_in = TypeVar("P_in", contravariant=True)  # the parameters, which a filter only reads
Q_in = TypeVar("Q_in", contravariant=True)  # the proposals, which the filter's side only reads


class FilterSide(Protocol[P_in, S, O, Q_in]):
    """The filter's side of a tracker (:class:`TrackingFilter` without ``propose``): what a filter
    stage calls, whose proposals come from another stage (a tracker over the preprocess stage's
    features, :data:`gflow_core.contour.features_filter.FEATURE_FILTER`, is one alone). The
    implementations keep no state of their own: everything is in ``S``."""

    #: the tracker's name (``gflow track --tracker NAME``)
    name: str

    def observe(self, params: P_in, image: np.ndarray) -> O:
        """What the tracker reads of a frame (``(H, W, 3)`` BGR or ``(H, W)`` grey uint8).

        Raises :class:`UnusableFrame` for a frame with no information (the caller coasts) and
        ``ValueError`` for one that is not an image."""
        ...

    def init(self, params: P_in, obs: O, box: Box, rng: FrameRng, resources: Mapping[str, Any]) -> tuple[S, Estimate]:
        """The posterior at the first frame, from the user's ``box``. ``resources`` holds what the
        caller loaded for the tracker (a learned model, under ``"model"``): the core opens no file."""
        ...

    def update(self, params: P_in, state: S, proposal: Q_in, obs: O, rng: FrameRng) -> tuple[S, Estimate]:
        """The posterior at frame ``rng.t``: ``proposal`` weighed by the evidence of ``obs``."""
        ...

    def coast(self, params: P_in, state: S, rng: FrameRng, obs: O | None = None) -> tuple[S, Estimate]:
        """The posterior carried over frame ``rng.t``, which could not be used (``obs`` is the frame
        when it was readable but its proposals or update failed)."""
        ...


class TrackingFilter(FilterSide[P_in, S, O, Q], Protocol[P_in, S, O, Q]):
    """A tracker as a two-stage filter over parameters ``P``, states ``S``, observations ``O`` and
    proposals ``Q``: its :class:`FilterSide` and ``propose``."""

    def propose(self, params: P_in, state: S, obs: O, rng: FrameRng, dt: float = 1.0) -> Q:
        """Hypotheses for frame ``rng.t`` from the posterior ``state`` at the previous frame; ``dt``
        is the time since that frame in nominal frame periods (1 for files)."""
        ...


def step(f: TrackingFilter[P, S, O, Q], params: P, state: S, obs: O, rng: FrameRng,
         dt: float = 1.0) -> tuple[S, Estimate]:
    """One frame: ``f.update(params, state, f.propose(params, state, obs, rng, dt), obs, rng)``."""
    return f.update(params, state, f.propose(params, state, obs, rng, dt), obs, rng)


#: what a tracker reports of a target on a frame it coasted over without an image it could use (the
#: frame did not arrive, could not be read, or was uniform): hidden from it, the box where the dynamics
#: expect it (docs/stress.md, "Confidence and state")
UNSEEN_STATE = "occluded"


def unseen(est: Estimate) -> Estimate:
    """The estimate of a frame coasted without a usable image: never ``tracked``, since nothing was
    seen (the tracker's own ``occluded`` or ``lost`` is kept; the tracker's state is not changed, so
    the frames after it are tracked as before)."""
    return est if est.target_state != "tracked" else dataclasses.replace(est, target_state=UNSEEN_STATE)
