"""Filter stage of the appearance tracker: M2 with online exemplars.

An adapter of :class:`gflow_core.appearance_tracker.AppearanceTracker` (``observe``, ``init``,
``update``, ``coast``); the mathematics is :mod:`gflow_core.appearance` (its docstring lists the
departures from Toyama & Blake 2002). Its parameters are every field of
:class:`gflow_core.appearance_params.AppearanceParams` (derived from it, defaults included) plus
``seed`` and ``init``. This stage adapts the tracker to the pipeline's particle messages:

* Inputs: ``frames`` of frame t (colour or grey; the appearance channels are computed here
  from the grey levels, and the colour bins of the colour cue from the colours) and ``proposals`` for frame t from ``appearance.proposal`` (a random
  walk on alpha = (x, y, theta, s); theta is ignored and s = exp(log s)).
* Outputs: ``particles`` (the resampled posterior of t, alpha = (x, y, 0, s)) and
  ``estimate``: the box, the posterior mean and std of alpha, the ESS, the data path
  ``state`` -- ``init``, ``track``, ``occluded`` (the target was judged hidden: the box holds
  the prediction, the exemplars are not updated and a widening region is searched), ``lost``
  (hidden, and the search covers the whole frame), ``redetect`` (the search found it again
  this frame) or ``coast`` (no usable frame: the particles and the model are carried over
  unchanged) -- and what the tracker judges of the target: ``confidence``, P(visible) of
  :mod:`gflow_core.visibility`, and ``target_state`` (``tracked``, ``occluded``, ``lost``).

Bad input -- a missing, undecodable, uniform or wrongly sized frame, or missing proposals --
makes the filter coast and is reported; it never stops the stream.

The appearance channels of a frame depend on that frame alone, so they are the stage's
``prepare`` work (:mod:`stages.base`): as its own process, the host computes the channels of
frame t+1 on a second thread while ``step`` weighs frame t (5 of the filter's 16 ms a frame
on caviar1, measured before the channels were made faster); ``--inline`` computes them in
``step``. The bits are the same either way.

State for ``snapshot()`` / ``restore()``: the three exemplars, the particle cloud, the velocity,
the moments of the target's and the clutter's distance distributions, the colour histograms and
their distance moments, the hidden-frame count and counters, as msgpack of a small Struct
(version 4).
"""

from __future__ import annotations

from typing import Mapping

import msgspec
import numpy as np

from gflow_core import appearance as ap
from gflow_core.appearance_params import AppearanceParams
from gflow_core.features import to_grey
from gflow_core.appearance_dynamics import alpha_of, particles_of
from gflow_core.appearance_tracker import TRACKER, AppearanceObservation, AppearanceProposal, AppearanceTrack
from gflow_core.m2.tracking import ParticleCloud
from gflow_core.tracker import Estimate as TrackerEstimate
from gflow_core.tracker import UnusableFrame

from .base import Output, Stage, StageContext, StageInputError
from .messages import Estimate, Frame, Header, Message, MessageError, NDArray, Particles
from .particle_proposal import cloud_of, particles_msg
from .rng import tracker_rng
from .time_step import time_step
from .appearance_proposal import AppearanceStageFields
from .tracker_params import stage_params, tracker_params

__all__ = ["AppearanceFilterStage", "AppearanceFilterParams"]

SNAPSHOT_VERSION = 4


AppearanceFilterParams = stage_params(
    "AppearanceFilterParams", AppearanceParams, AppearanceStageFields, __name__,
    "Appearance filter settings: every field of :class:`gflow_core.appearance_params.AppearanceParams` "
    "(see it for meanings), ``seed`` and ``init``.")


class _Snapshot(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    version: int
    initialised: bool
    size0: tuple[float, float] = (0.0, 0.0)
    res: tuple[int, int] = (0, 0)
    anchor: NDArray | None = None
    recent: NDArray | None = None
    slow: NDArray | None = None
    particles: NDArray | None = None
    centre: tuple[float, float] = (0.0, 0.0)
    log_s: float = 0.0
    velocity: tuple[float, float] = (0.0, 0.0)
    target: tuple[float, float, int] = (0.0, 0.0, 0)  # moments m1, m2 and count of the target's distance
    clutter: tuple[float, float, int] = (0.0, 0.0, 0)  # the same of the clutter's best distance
    hidden_run: int = 0
    back: float = 0.0  # filtered P(present) of the last frame while the target is hidden
    colour0: NDArray | None = None  # colour histograms: the first box's and the running one (None: no colour cue)
    colour: NDArray | None = None
    ctarget: tuple[float, float, int] = (0.0, 0.0, 0)  # moments of the target's and the clutter's colour distance
    cclutter: tuple[float, float, int] = (0.0, 0.0, 0)
    steps: int = 0
    last: dict = {}


def _posterior(header: Header, parts: np.ndarray) -> Particles:
    """The resampled posterior (N, 3) as a Particles message (k = 0, equal weights)."""
    n = len(parts)
    return particles_msg(header, "posterior", ParticleCloud(alpha=alpha_of(parts), k=np.zeros(n, np.int64),
                                                            log_w=np.zeros(n)))


class AppearanceFilterStage(Stage[AppearanceStageFields]):
    kind = "appearance.filter"
    Params = AppearanceFilterParams
    inputs = {"frames": Frame, "proposals": Particles}
    outputs = {"particles": Particles, "estimate": Estimate}
    drivers = frozenset({"frames"})
    prepare_ports = frozenset({"frames"})

    def __init__(self, params: AppearanceStageFields, ctx: StageContext) -> None:
        super().__init__(params, ctx)
        if params.init is None:
            raise ValueError("the appearance filter needs an initial box: set init: [x, y, w, h]")
        self.core = tracker_params(params, AppearanceParams)
        self.state: AppearanceTrack | None = None
        self.shape: tuple[int, int] | None = None
        self.steps = 0
        self.last: dict = {}

    def required(self, seq: int) -> frozenset[str]:
        return frozenset({"frames"}) if self.state is None else frozenset(self.inputs)

    def prepare(self, port: str, msg: Message) -> tuple[np.ndarray, AppearanceObservation | UnusableFrame]:
        """(grey (H, W) uint8, the tracker's observation of it, or the UnusableFrame a uniform frame
        raised). Raises MessageError or ValueError for an image that cannot be read."""
        assert isinstance(msg, Frame)
        image = msg.image.array()
        try:
            obs = TRACKER.observe(self.core, image)
            return obs.grey, obs
        except UnusableFrame as e:
            return to_grey(image), e

    def _observe(self, frame: Frame | None, seq: int) -> AppearanceObservation | None:
        """The tracker's observation of the frame, or None (reported) when the frame cannot be used."""
        if frame is None:
            self.report("missing_frame", f"frame {seq}: no frame arrived; coasting", seq)
            return None
        try:
            grey, obs = self.prepared("frames", frame)
        except (MessageError, ValueError) as e:
            self.report("bad_frame", f"frame {seq}: {e}; coasting", seq)
            return None
        if self.shape is not None and grey.shape != self.shape:
            self.report("bad_frame", f"frame {seq}: {grey.shape[1]}x{grey.shape[0]} but the stream is "
                        f"{self.shape[1]}x{self.shape[0]}; coasting", seq)
            return None
        if isinstance(obs, UnusableFrame):
            self.report("blank_frame", f"frame {seq}: uniform frame, no evidence; coasting", seq)
            return None
        return obs

    def _outputs(self, header: Header, est: TrackerEstimate) -> list[Output]:
        """The posterior and the estimate messages of the tracker's estimate."""
        assert self.state is not None
        self.steps += 1
        x, y, w, h = est.box
        outline = np.array([[x, y], [x + w, y], [x + w, y + h], [x, y + h]], dtype=np.float32)
        e = est.extras
        self.last = {"seq": header.seq, "box": [round(v, 2) for v in est.box], "ess": round(float(e["ess"]), 1),
                     "state": est.phase, "score": round(float(e["score"]), 4),
                     "confidence": round(float(est.confidence), 4), "target_state": est.target_state}
        msg = Estimate(header=header, box=est.box, alpha=e["alpha"], k=0, mean=e["mean"], std=e["std"], ess=e["ess"],
                       n=e["n"], log_evidence=e["log_evidence"], contour=NDArray.of(outline), state=est.phase,
                       confidence=est.confidence, target_state=est.target_state)
        return [("particles", _posterior(header, self.state.core.particles)), ("estimate", msg)]

    def _initialise(self, seq: int, frame: Frame | None) -> list[Output]:
        p = self.params
        try:
            obs = self._observe(frame, seq)
            if obs is None or frame is None:
                raise StageInputError(f"frame {seq}: cannot initialise on this frame")
            assert p.init is not None
            self.state, est = TRACKER.init(self.core, obs, p.init, tracker_rng(p.seed, self.ctx.stream, seq), {})
        except StageInputError:
            raise
        except ValueError as e:  # a box outside the frame, a frame too small for the channels
            raise StageInputError(f"frame {seq}: {e}") from None
        self.shape = obs.grey.shape
        return self._outputs(frame.header, est)

    def step(self, seq: int, inputs: Mapping[str, Message | None]) -> list[Output]:
        frame = inputs.get("frames")
        frame = frame if isinstance(frame, Frame) else None
        if self.state is None:
            return self._initialise(seq, frame)
        p, n = self.params, self.core.particles
        st = self.state
        rng = tracker_rng(p.seed, self.ctx.stream, seq)
        prop = inputs.get("proposals")
        if isinstance(prop, Particles):
            alpha = cloud_of(prop).alpha
            if alpha.shape[0] != n or not np.isfinite(alpha).all() or not (alpha[:, 3] > 0).all():
                self.report("bad_proposals", f"proposals {seq}: {alpha.shape[0]} particles (expected "
                            f"{n}), non-finite or non-positive scale; reusing the last posterior", seq)
                proposed = st.core.particles
            else:
                proposed = particles_of(alpha)
        else:
            self.report("missing_proposals", f"frame {seq}: no proposals arrived; reusing the last posterior", seq)
            proposed = st.core.particles
        obs = self._observe(frame, seq)
        if obs is None:
            self.state, est = TRACKER.coast(self.core, st, rng)
            return self._outputs(frame.header if frame is not None else self.header(seq, 0), est)
        assert frame is not None
        # periods since the posterior the proposals came from (its stamp: the proposal stage keeps it)
        dt = time_step(self.ctx, frame.header.stamp_ns, prop.header.stamp_ns) if isinstance(prop, Particles) else 1.0
        self.state, est = TRACKER.update(self.core, st, AppearanceProposal(proposed, dt), obs, rng)
        return self._outputs(frame.header, est)

    def summary(self) -> dict:
        """The last estimate (seq, box, ESS, state, appearance score r) and the step count."""
        return dict(self.last, steps=self.steps)

    # -- snapshot / restore ---------------------------------------------------------------
    def snapshot(self) -> bytes:
        if self.state is None:
            return msgspec.msgpack.encode(_Snapshot(version=SNAPSHOT_VERSION, initialised=False, steps=self.steps))
        st = self.state.core
        return msgspec.msgpack.encode(_Snapshot(
            version=SNAPSHOT_VERSION, initialised=True, size0=(float(st.size0[0]), float(st.size0[1])),
            res=(int(st.res[0]), int(st.res[1])), anchor=NDArray.of(st.anchor), recent=NDArray.of(st.recent),
            slow=NDArray.of(st.slow), particles=NDArray.of(st.particles), centre=(float(st.centre[0]), float(st.centre[1])),
            log_s=float(st.log_s), velocity=(float(st.velocity[0]), float(st.velocity[1])),
            target=(st.target.m1, st.target.m2, st.target.n), clutter=(st.clutter.m1, st.clutter.m2, st.clutter.n),
            hidden_run=int(st.hidden_run), back=float(st.back),
            colour0=None if st.colour0 is None else NDArray.of(st.colour0),
            colour=None if st.colour is None else NDArray.of(st.colour),
            ctarget=(st.ctarget.m1, st.ctarget.m2, st.ctarget.n), cclutter=(st.cclutter.m1, st.cclutter.m2, st.cclutter.n),
            steps=self.steps, last=self.last))

    def restore(self, data: bytes) -> None:
        name = self.ctx.name
        try:
            snap = msgspec.msgpack.decode(data, type=_Snapshot)
        except msgspec.DecodeError as e:
            raise ValueError(f"stage {name!r}: not an appearance.filter snapshot: {e}") from None
        if snap.version != SNAPSHOT_VERSION:
            raise ValueError(f"stage {name!r}: appearance snapshot version {snap.version}, expected {SNAPSHOT_VERSION}")
        self.steps, self.last = snap.steps, dict(snap.last)
        if not snap.initialised:
            self.state, self.shape = None, None
            return
        try:
            assert (snap.anchor is not None and snap.recent is not None and snap.slow is not None
                    and snap.particles is not None)
            anchor, recent, slow = snap.anchor.array().copy(), snap.recent.array().copy(), snap.slow.array().copy()
            parts = snap.particles.array().copy()
            colour0 = None if snap.colour0 is None else snap.colour0.array().copy()
            colour = None if snap.colour is None else snap.colour.array().copy()
        except (AssertionError, MessageError, ValueError) as e:
            raise ValueError(f"stage {name!r}: bad appearance snapshot: {e}") from None
        core = ap.AppearanceState(size0=np.array(snap.size0), res=(snap.res[0], snap.res[1]), anchor=anchor,
                                  recent=recent, particles=parts, centre=np.array(snap.centre), log_s=snap.log_s,
                                  velocity=np.array(snap.velocity), slow=slow, target=ap.ChiSquare(*snap.target),
                                  clutter=ap.ChiSquare(*snap.clutter), hidden_run=snap.hidden_run,
                                  back=snap.back, colour0=colour0, colour=colour,
                                  ctarget=ap.ChiSquare(*snap.ctarget), cclutter=ap.ChiSquare(*snap.cclutter))
        # the target as the last estimate judged it (what a coasted frame reports)
        self.state = AppearanceTrack(core, str(self.last.get("target_state", "occluded")))
        self.shape = None
