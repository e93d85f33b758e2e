"""Filter stage of the correlation-filter tracker.

An adapter of :class:`gflow_core.dcf.tracker.DCFTracker` (``observe``, ``init``, ``update``, ``coast``);
the mathematics is :mod:`gflow_core.dcf` (its docstring lists the papers and the departures). Its
parameters are every field of :class:`gflow_core.dcf.params.DCFParams` plus ``seed`` and ``init``.

* Inputs: ``frames`` of frame t (colour or grey) and ``proposals`` for frame t from ``dcf.proposal``
  (a random walk on alpha = (x, y, theta, s); theta is ignored and s = exp(log s)).
* Outputs: ``particles`` (the resampled posterior of t, alpha = (x, y, 0, s)) and ``estimate``: the
  box, the posterior's mean and std of alpha, the ESS, the data path ``state`` -- ``init``, ``track``,
  ``occluded``, ``lost``, ``redetect`` or ``coast`` -- and what the tracker judges of the target:
  ``confidence`` (P(visible)) and ``target_state`` (``tracked``, ``occluded``, ``lost``).

Bad input -- a missing, undecodable, uniform or wrongly sized frame, or missing proposals -- makes
the filter coast and is reported; it never stops the stream. The frame's observation (its grey
levels) is the stage's ``prepare`` work (:mod:`stages.base`).

State for ``snapshot()`` / ``restore()``: the tracker's state as arrays and values
(:func:`gflow_core.dcf.state.to_arrays`), the step count and the last estimate, as msgpack.
"""

from __future__ import annotations

from typing import Any, Mapping

import msgspec
import numpy as np

from gflow_core.dcf.dynamics import alpha_of, particles_of
from gflow_core.dcf.params import DCFParams
from gflow_core.dcf.state import DCFObservation, DCFProposal, DCFState, from_arrays, to_arrays
from gflow_core.dcf.tracker import TRACKER
from gflow_core.features import to_grey
from gflow_core.m2.tracking import ParticleCloud
from gflow_core.tracker import Estimate as TrackerEstimate
from gflow_core.tracker import UnusableFrame

from .base import Output, Stage, StageContext, StageInputError
from .dcf_proposal import DCFStageFields
from .messages import Estimate, Frame, Header, Message, MessageError, NDArray, Particles
from .particle_proposal import cloud_of, particles_msg
from .rng import tracker_rng
from .time_step import time_step
from .tracker_params import stage_params, tracker_params

__all__ = ["DCFFilterStage", "DCFFilterParams"]

SNAPSHOT_VERSION = 1

DCFFilterParams = stage_params(
    "DCFFilterParams", DCFParams, DCFStageFields, __name__,
    "Correlation-filter settings: every field of :class:`gflow_core.dcf.params.DCFParams` (see it for "
    "meanings), ``seed`` and ``init``.")


class _Snapshot(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    version: int
    initialised: bool
    arrays: dict[str, NDArray] = {}
    values: dict[str, Any] = {}
    steps: int = 0
    last: dict = {}


class DCFFilterStage(Stage[DCFStageFields]):
    kind = "dcf.filter"
    Params = DCFFilterParams
    inputs = {"frames": Frame, "proposals": Particles}
    outputs = {"particles": Particles, "estimate": Estimate}
    drivers = frozenset({"frames"})
    prepare_ports = frozenset({"frames"})

    def __init__(self, params: DCFStageFields, ctx: StageContext) -> None:
        super().__init__(params, ctx)
        if params.init is None:
            raise ValueError("the dcf filter needs an initial box: set init: [x, y, w, h]")
        self.core = tracker_params(params, DCFParams)
        self.state: DCFState | None = None
        self.shape: tuple[int, int] | None = None
        self.steps = 0
        self.last: dict = {}

    def required(self, seq: int) -> frozenset[str]:
        return frozenset({"frames"}) if self.state is None else frozenset(self.inputs)

    def prepare(self, port: str, msg: Message) -> tuple[tuple[int, ...], DCFObservation | UnusableFrame]:
        """(the frame's (H, W), the tracker's observation or the UnusableFrame a uniform frame raised).
        Raises MessageError or ValueError for an image that cannot be read."""
        assert isinstance(msg, Frame)
        image = msg.image.array()
        try:
            obs = TRACKER.observe(self.core, image)
            return obs.grey.shape, obs
        except UnusableFrame as e:
            return to_grey(image).shape, e

    def _observe(self, frame: Frame | None, seq: int) -> DCFObservation | None:
        """The tracker's observation of the frame, or None (reported) when the frame cannot be used."""
        if frame is None:
            self.report("missing_frame", f"frame {seq}: no frame arrived; coasting", seq)
            return None
        try:
            shape, obs = self.prepared("frames", frame)
        except (MessageError, ValueError) as e:
            self.report("bad_frame", f"frame {seq}: {e}; coasting", seq)
            return None
        if self.shape is not None and shape != self.shape:
            self.report("bad_frame", f"frame {seq}: {shape[1]}x{shape[0]} but the stream is "
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
        n = len(self.state.particles)
        post = ParticleCloud(alpha=alpha_of(self.state.particles), k=np.zeros(n, np.int64), log_w=np.zeros(n))
        return [("particles", particles_msg(header, "posterior", post)), ("estimate", msg)]

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
        except ValueError as e:  # a box outside the frame, a frame too small for the cells
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
                proposed = st.particles
            else:
                proposed = particles_of(alpha)
        else:
            self.report("missing_proposals", f"frame {seq}: no proposals arrived; reusing the last posterior", seq)
            proposed = st.particles
        obs = self._observe(frame, seq)
        if obs is None:
            self.state, est = TRACKER.coast(self.core, st, rng)
            return self._outputs(frame.header if frame is not None else self.header(seq, 0), est)
        assert frame is not None
        # periods since the posterior the proposals came from (its stamp: the proposal stage keeps it)
        dt = time_step(self.ctx, frame.header.stamp_ns, prop.header.stamp_ns) if isinstance(prop, Particles) else 1.0
        self.state, est = TRACKER.update(self.core, st, DCFProposal(proposed, dt), obs, rng)
        return self._outputs(frame.header, est)

    def summary(self) -> dict:
        """The last estimate (seq, box, ESS, state, response at the estimate) and the step count."""
        return dict(self.last, steps=self.steps)

    # -- snapshot / restore ---------------------------------------------------------------
    def snapshot(self) -> bytes:
        if self.state is None:
            return msgspec.msgpack.encode(_Snapshot(version=SNAPSHOT_VERSION, initialised=False, steps=self.steps))
        arrays, values = to_arrays(self.state)
        return msgspec.msgpack.encode(_Snapshot(version=SNAPSHOT_VERSION, initialised=True,
                                                arrays={k: NDArray.of(v) for k, v in arrays.items()}, values=values,
                                                steps=self.steps, last=self.last))

    def restore(self, data: bytes) -> None:
        name = self.ctx.name
        try:
            snap = msgspec.msgpack.decode(data, type=_Snapshot)
        except msgspec.DecodeError as e:
            raise ValueError(f"stage {name!r}: not a dcf.filter snapshot: {e}") from None
        if snap.version != SNAPSHOT_VERSION:
            raise ValueError(f"stage {name!r}: dcf snapshot version {snap.version}, expected {SNAPSHOT_VERSION}")
        self.steps, self.last = snap.steps, dict(snap.last)
        if not snap.initialised:
            self.state, self.shape = None, None
            return
        try:
            self.state = from_arrays({k: v.array() for k, v in snap.arrays.items()}, snap.values, self.core)
        except (KeyError, IndexError, TypeError, MessageError, ValueError) as e:
            raise ValueError(f"stage {name!r}: bad dcf snapshot: {e}") from None
        self.shape = None
