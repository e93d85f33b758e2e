"""Proposal stage of the contour particle filter: samples p(X_t | X_{t-1}) (M2 sec. 4.3).

Input ``particles`` is the resampled posterior of frame t-1 (from the filter stage); the
output ``proposals`` are the particles for frame t, drawn from the dynamics with the
random stream ``frame_rng(seed, stream, t, PURPOSE)``.

With no learned model (the chamfer tracker, K = 1) the dynamics are a random walk on
beta = (ux, uy, theta, log s) with the given standard deviations; with a learned M2
model (resource ``model``) they are its Markov matrix and AR(1) process. A model with
patch exemplars (the mouth tracker, sec. 5.2) is tracked "with no alpha transformations":
k follows the Markov matrix and alpha is passed through unchanged.

The stage keeps no state that its outputs depend on; its snapshot holds the step counter.
"""

from __future__ import annotations

from typing import Mapping

import msgspec
import numpy as np

from gflow_core.m2 import dynamics as dyn
from gflow_core.m2.dynamics import sample_markov
from gflow_core.m2.model import M2Model
from gflow_core.m2.tracking import ParticleCloud

from .base import Output, Params, Stage, StageInputError
from .messages import Message, MessageError, NDArray, Particles
from .rng import frame_rng

__all__ = ["ProposalStage", "ProposalParams", "cloud_of", "particles_msg"]

PURPOSE = 0x9209
SNAPSHOT_VERSION = 1


class _ProposalSnapshot(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    version: int
    done: int


class ProposalParams(Params):
    """Dynamics of the proposal. ``model``: path of a learned M2 model (empty: random walk)."""

    seed: int = 0
    std_xy: float = 4.0
    std_theta: float = 0.02
    std_log_s: float = 0.02
    model: str = ""


def cloud_of(msg: Particles) -> ParticleCloud:
    """Unpack a Particles message into a validated ParticleCloud."""
    try:
        return ParticleCloud(alpha=msg.alpha.array(), k=msg.k.array(), log_w=msg.log_w.array())
    except (MessageError, ValueError) as e:
        raise StageInputError(f"particles {msg.header.seq}: {e}") from None


def particles_msg(header, kind: str, cloud: ParticleCloud) -> Particles:
    return Particles(header=header, kind=kind, alpha=NDArray.of(cloud.alpha), k=NDArray.of(cloud.k),
                     log_w=NDArray.of(cloud.log_w))


class ProposalStage(Stage):
    kind = "particle.proposal"
    Params = ProposalParams
    inputs = {"particles": Particles}
    outputs = {"proposals": Particles}

    def __init__(self, params: ProposalParams, ctx) -> None:
        super().__init__(params, ctx)
        model = ctx.resources.get("model")
        self.fixed_alpha = False
        if model is not None:
            if not isinstance(model, M2Model):
                raise ValueError(f"stage {ctx.name!r}: model {params.model!r} is a {type(model).__name__}, "
                                 "not an M2 model")
            self.markov = model.markov
            self.dynamics = model.dynamics
            # patch exemplars are tracked with no alpha transformations (sec. 5.2)
            self.fixed_alpha = model.kind == "patch"
        else:
            self.markov = np.ones((1, 1))
            self.dynamics = dyn.random_walk(params.std_xy, params.std_theta, params.std_log_s)
        self.done = 0

    def step(self, seq: int, inputs: Mapping[str, Message | None]) -> list[Output]:
        msg = inputs["particles"]
        assert isinstance(msg, Particles)
        cloud = cloud_of(msg)
        t = seq + 1
        rng = frame_rng(self.params.seed, self.ctx.stream, t, PURPOSE)  # type: ignore[attr-defined]
        if cloud.k.max(initial=0) >= self.markov.shape[0]:
            raise StageInputError(f"particles {seq}: exemplar index beyond the model's K={self.markov.shape[0]}")
        # k_t ~ M[k_{t-1}], alpha_t ~ AR(1)(alpha_{t-1})
        k = sample_markov(cloud.k, self.markov, rng)
        alpha = cloud.alpha.copy() if self.fixed_alpha else self.dynamics.predict(cloud.alpha, rng)
        out = ParticleCloud(alpha=alpha, k=k, log_w=np.zeros(cloud.n))
        self.done += 1
        return [("proposals", particles_msg(self.header(t, msg.header.stamp_ns), "proposal", out))]

    def summary(self) -> dict:
        return {"proposed": self.done}

    def snapshot(self) -> bytes:
        return msgspec.msgpack.encode(_ProposalSnapshot(version=SNAPSHOT_VERSION, done=self.done))

    def restore(self, data: bytes) -> None:
        try:
            snap = msgspec.msgpack.decode(data, type=_ProposalSnapshot)
        except msgspec.DecodeError as e:
            raise ValueError(f"stage {self.ctx.name!r}: not a proposal snapshot: {e}") from None
        if snap.version != SNAPSHOT_VERSION:
            raise ValueError(f"stage {self.ctx.name!r}: proposal snapshot version {snap.version}, expected "
                             f"{SNAPSHOT_VERSION}")
        self.done = snap.done
