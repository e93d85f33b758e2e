"""Proposal stage of the contour particle filter: samples p(X_t | X_{t-1}) (M2 sec. 4.3).

An adapter of :func:`gflow_core.contour.dynamics.proposal_dynamics` and
:func:`~gflow_core.contour.dynamics.propose_cloud`, the proposal of the contour trackers' protocol
(:class:`~gflow_core.contour.protocol.ContourTracker`).

Input ``particles`` is the resampled posterior of frame t-1 (from the filter stage); the
output ``proposals`` are the particles for frame t, drawn from the dynamics with the
random stream ``FrameRng(seed, crc32(stream), t).stream(PURPOSE)`` (``PURPOSE_PROPOSAL``).

With no learned model (the chamfer tracker, K = 1) the dynamics are a random walk on
beta = (ux, uy, theta, log s) with the given standard deviations; with a learned M2
model (resource ``model``) they are its Markov matrix and AR(1) process. A model with
patch exemplars (the mouth tracker, sec. 5.2) is tracked "with no alpha transformations":
k follows the Markov matrix and alpha is passed through unchanged.

Departure from the paper (sec. 4.3): with ``init`` set (``gflow track --tracker m2`` sets it
to the start box), the AR(1) process on log s reverts to the initial box's scale, not to
the learned mean. The learned mean is the training person's distance from the training
camera: a model learned on caviar1 (people about 28x73 px) pulled a 17x50 px pedestrian of
crossing to 28x73 within three frames. Translation is a random walk, theta's mean is ~0.

With ``timed`` (set for live sources by ``pipeline/runtime/live_plan.py``) the stage also reads
the frames and joins frame t + 1 with the posterior of t, so the noise grows with the time
between the two frames' capture stamps (:mod:`stages.time_step`).

The stage keeps no state that its outputs depend on; its snapshot holds the step counter.
"""

from __future__ import annotations

from typing import Any, ClassVar, Mapping

import msgspec

from gflow_core.contour.dynamics import PURPOSE_PROPOSAL, proposal_dynamics, propose_cloud
from gflow_core.m2.model import M2Model
from gflow_core.m2.tracking import ParticleCloud

from gflow_core.contour.params import ChamferParams, M2Params
from gflow_core.params import defaults

from .base import Output, Params, Stage, StageContext, StageInputError
from .base import Params as _Params
from .messages import Frame, Message, MessageError, NDArray, Particles
from .rng import tracker_rng
from .time_step import time_step
from .tracker_params import StageFields, stage_params

__all__ = ["ProposalStage", "ProposalParams", "ProposalFields", "ChamferProposalStage", "ChamferProposalParams",
           "M2ProposalStage", "M2ProposalParams", "cloud_of", "particles_msg"]

PURPOSE = PURPOSE_PROPOSAL  # 0x9209
SNAPSHOT_VERSION = 1


class _ProposalSnapshot(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    version: int
    done: int


#: the random walk's defaults: the chamfer tracker's (ChamferParams, where they live), not a copy
_WALK = defaults(ChamferParams)


class ProposalParams(Params, frozen=True):
    """Dynamics of the proposal. ``model``: path of a learned M2 model (empty: random walk, its
    ``std_xy``, ``std_theta`` and ``std_log_s`` by default those of
    :class:`gflow_core.contour.params.ChamferParams`).

    ``init`` (x, y, w, h), with a learned contour model: the AR(1) process on log s reverts
    to the scale of this box instead of the learned mean (see the module docstring).
    """

    seed: int = 0
    std_xy: float = _WALK["std_xy"]
    std_theta: float = _WALK["std_theta"]
    std_log_s: float = _WALK["std_log_s"]
    model: str = ""
    init: tuple[float, float, float, float] | None = None
    timed: bool = False  # also read the frames: the noise grows with the time to the next frame

    def __post_init__(self) -> None:
        if self.init is not None and not (self.init[2] > 0 and self.init[3] > 0):
            raise ValueError(f"init box must have positive width and height, got {self.init}")


class ProposalFields(StageFields, frozen=True):
    """What the chamfer and m2 proposal stages take besides their tracker's parameters: ``seed``,
    ``model`` (a learned M2 model's path), ``init`` (the initial box: the AR(1) process on log s
    reverts to its scale) and ``timed`` (also read the frames: the noise grows with the time to the
    next frame)."""

    seed: int = 0
    model: str = ""
    init: tuple[float, float, float, float] | None = None
    timed: bool = False

    def check(self, tracker: Any) -> None:
        if self.init is not None and not (self.init[2] > 0 and self.init[3] > 0):
            raise ValueError(f"init box must have positive width and height, got {self.init}")


ChamferProposalParams = stage_params("ChamferProposalParams", ChamferParams, ProposalFields, __name__,
                                     "The chamfer tracker's proposal: every field of "
                                     ":class:`gflow_core.contour.params.ChamferParams` (its random walk: "
                                     "``std_xy``, ``std_theta``, ``std_log_s``), ``seed``, ``init`` and ``timed``.")
M2ProposalParams = stage_params("M2ProposalParams", M2Params, ProposalFields, __name__,
                                "The M2 tracker's proposal: every field of :class:`gflow_core.contour.params.M2Params`, "
                                "``seed``, ``model`` (required: its dynamics), ``init`` and ``timed``.")


def counter_snapshot(done: int) -> bytes:
    """The snapshot of a proposal stage: its step counter (its outputs depend on no other state)."""
    return msgspec.msgpack.encode(_ProposalSnapshot(version=SNAPSHOT_VERSION, done=done))


def restored_counter(stage: str, data: bytes) -> int:
    """The step counter of a :func:`counter_snapshot` (``ValueError`` naming ``stage`` otherwise)."""
    try:
        snap = msgspec.msgpack.decode(data, type=_ProposalSnapshot)
    except msgspec.DecodeError as e:
        raise ValueError(f"stage {stage!r}: not a proposal snapshot: {e}") from None
    if snap.version != SNAPSHOT_VERSION:
        raise ValueError(f"stage {stage!r}: proposal snapshot version {snap.version}, expected {SNAPSHOT_VERSION}")
    return snap.done


def cloud_of(msg: Particles) -> ParticleCloud:
    """Unpack a Particles message into a validated ParticleCloud."""
    try:
        return ParticleCloud(alpha=msg.alpha.array(), k=msg.k.array(), log_w=msg.log_w.array())
    except (MessageError, ValueError) as e:
        raise StageInputError(f"particles {msg.header.seq}: {e}") from None


def posterior_input(ctx: StageContext, inputs: Mapping[str, Message | None]) -> tuple[Particles, ParticleCloud, float]:
    """A proposal stage's inputs: the posterior message of frame t-1, its cloud, and the periods from
    it to frame t (:mod:`stages.time_step`; 1 unless ``timed`` joined frame t as ``frames``)."""
    msg = inputs["particles"]
    assert isinstance(msg, Particles)
    cloud = cloud_of(msg)
    frame = inputs.get("frames")
    dt = time_step(ctx, frame.header.stamp_ns, msg.header.stamp_ns) if isinstance(frame, Frame) else 1.0
    return msg, cloud, dt


def particles_msg(header, kind: str, cloud: ParticleCloud) -> Particles:
    return Particles(header=header, kind=kind, alpha=NDArray.of(cloud.alpha), k=NDArray.of(cloud.k),
                     log_w=NDArray.of(cloud.log_w))


class ProposalStage(Stage[ProposalParams]):
    kind = "particle.proposal"
    Params: ClassVar[type[_Params]] = ProposalParams  # the chamfer and m2 stages below derive theirs
    inputs = {"particles": Particles}
    outputs = {"proposals": Particles}
    input_offsets = {"frames": -1}  # timed: frame t + 1 joins the posterior of t
    #: whether the stage needs a learned model (the ``model`` resource)
    needs_model: ClassVar[bool] = False

    @classmethod
    def ports(cls, params: ProposalParams) -> tuple[Mapping[str, type], Mapping[str, type]]:
        return ({"particles": Particles, "frames": Frame} if params.timed else cls.inputs), cls.outputs

    def __init__(self, params: ProposalParams, ctx) -> None:
        super().__init__(params, ctx)
        model = ctx.resources.get("model")
        if self.needs_model and model is None:
            raise ValueError(f"stage {ctx.name!r}: {self.kind} needs a learned model: set model: MODEL.npz "
                             f"(`gflow learn m2`)")
        if model is not None and not isinstance(model, M2Model):
            raise ValueError(f"stage {ctx.name!r}: model {params.model!r} is a {type(model).__name__}, "
                             "not an M2 model")
        # patch exemplars are tracked with no alpha transformations (sec. 5.2)
        walk = None if model is not None else (params.std_xy, params.std_theta, params.std_log_s)
        self.markov, self.dynamics, self.fixed_alpha = proposal_dynamics(model, params.init, walk)
        self.done = 0

    def step(self, seq: int, inputs: Mapping[str, Message | None]) -> list[Output]:
        msg, cloud, dt = posterior_input(self.ctx, inputs)
        t = seq + 1
        rng = tracker_rng(self.params.seed, self.ctx.stream, t).stream(PURPOSE)
        # k_t ~ M[k_{t-1}], alpha_t ~ AR(1)(alpha_{t-1}) over dt frame periods
        try:
            out = propose_cloud(cloud, self.markov, self.dynamics, rng, dt, self.fixed_alpha)
        except ValueError as e:
            raise StageInputError(f"particles {seq}: {e}") from None
        self.done += 1
        return [("proposals", particles_msg(self.header(t, msg.header.stamp_ns), "proposal", out))]

    def summary(self) -> dict:
        return {"proposed": self.done}

    def snapshot(self) -> bytes:
        return counter_snapshot(self.done)

    def restore(self, data: bytes) -> None:
        self.done = restored_counter(self.ctx.name, data)


class ChamferProposalStage(ProposalStage):
    """The chamfer tracker's proposal (graph ``chamfer``): the random walk of ``ChamferParams``."""

    kind = "chamfer.proposal"
    Params = ChamferProposalParams


class M2ProposalStage(ProposalStage):
    """The M2 tracker's proposal (graph ``m2``): the learned model's dynamics (a model is required)."""

    kind = "m2.proposal"
    Params = M2ProposalParams
    needs_model = True
