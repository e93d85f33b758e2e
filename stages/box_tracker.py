"""The stages of a particle-filter tracker on the protocol: a filter stage and a proposal stage for
any tracker whose state is a particle cloud, driven through the tracker's protocol object
(:class:`gflow_core.tracker.TrackingFilter`).

The stages of every tracker whose spec has box stages (the correlation-filter tracker, the
appearance tracker; :mod:`stages.spec_box`) are registrations
of these two classes: each sets its ``kind``, its ``Params`` (made of the tracker's parameter
dataclass) and what its spec says (:class:`gflow_core.spec.TrackerSpec`): the filter its protocol
object and the spec's :class:`gflow_core.spec.BoxStages` (the particles' conversions), the proposal
the spec's ``BoxStages`` (the random walk); the filter also its :class:`~gflow_msgs.snapshots.SnapshotCodec`. The contour trackers (:mod:`stages.particle_filter`,
:mod:`stages.particle_proposal`) and M2 with a patch model (:mod:`stages.patch_filter`) are
registrations too: their filters read the preprocess stage's ``features``
(:class:`FeaturesFilterStage`) and override the steps named below (``_observe``, ``_first_observation``, ``_proposed``, ``_coast``, ``_last``,
``_posterior``, ``snapshot`` / ``restore``); their proposal is a proposal of whole clouds
(``BoxProposalStage._clouds``: the exemplar index k travels with alpha).

* :class:`BoxFilterStage` -- inputs ``frames`` of frame t and ``proposals`` for frame t (a random walk
  on alpha = (x, y, theta, s); theta is ignored and s = exp(log s)); outputs ``particles`` (the
  resampled posterior of t, alpha = (x, y, 0, s)) and ``estimate``: the box, the posterior's mean and
  std of alpha, the ESS, the data path ``state`` -- ``init``, ``track``, ``occluded``, ``lost``,
  ``redetect`` or ``coast`` -- and what the tracker judges of the target: ``confidence`` (P(visible))
  and ``target_state`` (``tracked``, ``occluded``, ``lost``). A missing, undecodable, uniform or
  wrongly sized frame, or missing proposals, make it coast and are reported; they never stop the
  stream. The frame's observation (``TRACKER.observe``) is the stage's ``prepare`` work
  (:mod:`stages.base`). Its snapshot is the tracker's :class:`~gflow_msgs.snapshots.SnapshotCodec` Struct.
* :class:`BoxProposalStage` -- input ``particles``, the resampled posterior of frame t-1; output
  ``proposals``, the particles for frame t from the tracker's random walk drawn with
  ``FrameRng(seed, crc32(stream), t).stream(PURPOSE_WALK)``; its std is relative to the size of the
  initial box ``init``. With ``timed`` it also reads the frames and joins frame t + 1 with the
  posterior of t, so the noise grows with the time between the two frames' capture stamps
  (:mod:`stages.time_step`). It keeps no state that its outputs depend on; its snapshot holds the
  step counter.

The proposal stage calls the tracker's walk on the message's particles rather than
``TRACKER.propose`` (which takes the tracker's state): the state lives in the filter's process.
"""

from __future__ import annotations

from abc import abstractmethod
from typing import Any, Callable, ClassVar, Mapping, cast

import numpy as np

from gflow_core.features import to_grey
from gflow_core.m2.tracking import ParticleCloud
from gflow_core.tracker import Estimate as TrackerEstimate
from gflow_core.spec import BoxStages
from gflow_core.tracker import Box, FilterSide, FrameRng, UnusableFrame, unseen
from gflow_core.visibility import load_gamma

from .base import Output, Stage, StageContext, StageInputError
from gflow_msgs.messages import (Estimate, Features, Frame, Header, Message, MessageError, Particles,
                                 estimate_of, particles_msg)
from gflow_msgs.snapshots import CounterSnapshot, SnapshotCodec, decoded
from .time_step import time_step
from gflow_msgs.params import SeedBoxFields, core_params

__all__ = ["BoxFilterStage", "FeaturesFilterStage", "BoxProposalStage", "cloud_of"]

PROPOSAL_SNAPSHOT_VERSION = 1  # a proposal stage's snapshot: its step counter (CounterSnapshot)

#: a proposal of whole clouds: (the posterior of t-1, rng, dt) -> the proposal of t
CloudProposal = Callable[[ParticleCloud, np.random.Generator, float], ParticleCloud]


def cloud_of(msg: Particles) -> ParticleCloud:
    """Unpack a Particles message into a validated ParticleCloud."""
    try:
        return ParticleCloud(alpha=msg.alpha.array(), k=msg.k.array(), log_w=msg.log_w.array())
    except (MessageError, ValueError) as e:
        raise StageInputError(f"particles {msg.header.seq}: {e}") from None


class BoxFilterStage(Stage[SeedBoxFields]):
    """The filter stage of a tracker on the protocol (module docstring); a subclass sets ``kind``,
    ``Params`` (:func:`~gflow_msgs.params.stage_params` of the tracker's parameter dataclass),
    ``tracker``, ``box`` and ``codec``. A tracker that reads another message than the frames (the
    contour trackers' features) sets ``port`` and its ports and overrides the ``_observe`` family;
    one whose snapshot is not a :class:`~gflow_msgs.snapshots.SnapshotCodec`'s overrides ``snapshot`` / ``restore``."""

    #: the filter side of the tracker's protocol (``observe``, ``init``, ``update``, ``coast``)
    tracker: ClassVar[FilterSide[Any, Any, Any, Any]]
    #: the particles' conversions and the proposal of the tracker's spec (None: a stage that overrides
    #: ``_proposal``, ``_proposed`` and ``_posterior``)
    box: ClassVar[BoxStages | None] = None
    #: how the state travels in the snapshot (None: a stage with ``snapshot`` / ``restore`` of its own)
    codec: ClassVar[SnapshotCodec | None] = None
    #: whether the tracker needs the initial box (a patch model's may crop the whole frame)
    needs_init: ClassVar[bool] = True
    #: whether the tracker calls SciPy's gamma functions (ChiSquare's) on ordinary frames, so that they are imported
    #: with its modules: chamfer's lost guard does within a few dozen frames. The default tracker (dcf) calls them only
    #: in a search for a hidden target, and keeps SciPy out of its start-up (tests/test_cli_lazy_imports.py)
    preload_gamma: ClassVar[bool] = False
    #: the input port of the frame's observation (its message type is ``inputs[port]``)
    port: ClassVar[str] = "frames"
    inputs = {"frames": Frame, "proposals": Particles}
    outputs = {"particles": Particles, "estimate": Estimate}
    drivers = frozenset({"frames"})
    prepare_ports = frozenset({"frames"})

    def __init__(self, params: SeedBoxFields, ctx: StageContext) -> None:
        super().__init__(params, ctx)
        if self.needs_init:
            params.initial_box(f"the {self.label} filter")
        self.core: Any = core_params(params)
        self.state: Any = None
        self.shape: tuple[int, ...] | None = None
        self.steps = 0
        self.last: dict = {}

    def check_prepare(self) -> None:
        """Also the tracker's modules, imported when a runner takes the stage (a stage process before it
        says it is ready), not on its first frame: a stage built only to check a graph never imports them.
        SciPy's gamma functions too, with ``preload_gamma``: they are imported where they are called, which
        was otherwise on the frame of the first judgement (about 0.25 s of CPU)."""
        super().check_prepare()
        assert self.tracker is not None
        if self.preload_gamma:
            load_gamma()

    def required(self, seq: int) -> frozenset[str]:
        return frozenset({self.port}) if self.state is None else frozenset(self.inputs)

    def prepare(self, port: str, msg: Message) -> tuple[tuple[int, ...], Any]:
        """(the frame's grey (H, W), the tracker's observation or the UnusableFrame a uniform frame
        raised). Raises MessageError or ValueError for an image that cannot be read."""
        assert isinstance(msg, Frame)
        image = msg.image.array()
        try:
            obs = self.tracker.observe(self.core, image)
            return obs.grey.shape, obs
        except UnusableFrame as e:
            return to_grey(image).shape, e

    def _observe(self, frame: Any, seq: int) -> Any:
        """The tracker's observation of the frame, or None (reported) when the frame cannot be used."""
        got = self.observed("frames", frame, seq, "coasting")
        if got is None or not self.same_size("frames", seq, got[0], self.shape, "coasting"):
            return None
        if isinstance(got[1], UnusableFrame):
            self.report("blank_frame", f"frame {seq}: uniform frame, no evidence; coasting", seq)
            return None
        return got[1]

    def _first_observation(self, seq: int, msg: Any) -> Any:
        """The observation the tracker starts from (StageInputError when there is none)."""
        obs = self._observe(msg, seq)
        if obs is None or msg is None:
            raise StageInputError(f"frame {seq}: cannot initialise on this frame")
        return obs

    def _started(self, obs: Any) -> None:
        """After the first frame: the size every frame must have."""
        self.shape = obs.grey.shape

    def _proposed(self, seq: int, prop: Message | None) -> Any:
        """The proposed particles of the ``proposals`` message (the last posterior's, reported, when
        there are none or they are unusable)."""
        box, st = self.box, self.state
        assert box is not None
        if not isinstance(prop, Particles):
            self.report("missing_proposals", f"frame {seq}: no proposals arrived; reusing the last posterior", seq)
            return box.particles(st)
        n, alpha = self.core.particles, cloud_of(prop).alpha
        if alpha.shape[0] != n or not np.isfinite(alpha).all() or not (alpha[:, 3] > 0).all():
            self.report("bad_proposals", f"proposals {seq}: {alpha.shape[0]} particles (expected "
                        f"{n}), non-finite or non-positive scale; reusing the last posterior", seq)
            return box.particles(st)
        return box.particles_of(alpha)

    def _coast(self, proposed: Any, rng: FrameRng) -> tuple[Any, TrackerEstimate]:
        """The state and estimate of a frame that could not be used."""
        return self.tracker.coast(self.core, self.state, rng)

    def _last(self, header: Header, est: TrackerEstimate) -> dict:
        """The last estimate's summary (:meth:`summary`, the snapshot)."""
        e = est.extras
        return {"seq": header.seq, "box": [round(v, 2) for v in est.box], "ess": round(float(e["ess"]), 1),
                "state": est.phase, "score": round(float(e["score"]), 4),
                "confidence": round(float(est.confidence), 4), "target_state": est.target_state}

    def _posterior(self) -> ParticleCloud:
        """The posterior cloud of the state (alpha, k, log w)."""
        assert self.box is not None
        parts = self.box.particles(self.state)
        n = len(parts)
        return ParticleCloud(alpha=self.box.alpha_of(parts), k=np.zeros(n, np.int64), log_w=np.zeros(n))

    def _outputs(self, header: Header, est: TrackerEstimate, proposed: Any = None) -> list[Output]:
        """The posterior and the estimate messages of the tracker's estimate (``proposed``: the
        particles the update weighed; None on the first frame)."""
        assert self.state is not None
        self.steps += 1
        self.last = self._last(header, est)
        return [("particles", particles_msg(header, "posterior", self._posterior())),
                ("estimate", estimate_of(header, est))]

    def _initialise(self, seq: int, msg: Any) -> list[Output]:
        p = self.params
        obs = self._first_observation(seq, msg)
        try:  # init is None only where needs_init is not set: the tracker takes none
            self.state, est = self.tracker.init(self.core, obs, cast(Box, p.init), self.rng(seq),
                                                self.resources)
        except ValueError as e:  # a box outside the frame, a frame too small for the tracker's cells
            raise StageInputError(f"frame {seq}: {e}") from None
        self._started(obs)
        return self._outputs(msg.header, est)

    #: what the tracker's ``init`` is given besides the frame
    resources: Mapping[str, Any] = {}

    def step(self, seq: int, inputs: Mapping[str, Message | None]) -> list[Output]:
        msg = inputs.get(self.port)
        msg = msg if isinstance(msg, self.inputs[self.port]) else None
        if self.state is None:
            return self._initialise(seq, msg)
        rng = self.rng(seq)
        prop = inputs.get("proposals")
        proposed = self._proposed(seq, prop)
        obs = self._observe(msg, seq)
        header = self.header_of(msg, seq)
        if obs is None:
            self.state, est = self._coast(proposed, rng)
            return self._outputs(header, unseen(est), proposed)  # no image used: the target was not seen
        # periods since the posterior the proposals came from (its stamp: the proposal stage keeps it)
        dt = time_step(self.ctx, header.stamp_ns, prop.header.stamp_ns) if isinstance(prop, Particles) else 1.0
        self.state, est = self.tracker.update(self.core, self.state, self._proposal(proposed, dt), obs, rng)
        return self._outputs(header, est, proposed)

    def _proposal(self, proposed: Any, dt: float) -> Any:
        """The ``update`` argument of the proposed particles, ``dt`` periods after the posterior they came
        from (the spec's ``proposal``)."""
        assert self.box is not None
        return self.box.proposal(proposed, dt)

    @property
    def label(self) -> str:
        """The tracker's name in reports: the stage kind's first part (``dcf`` of ``dcf.filter``)."""
        return self.kind.split(".")[0]

    def summary(self) -> dict:
        """The last estimate (seq, box, ESS, state, the tracker's score at the estimate) and the step count."""
        return dict(self.last, steps=self.steps)

    # -- snapshot / restore: the tracker's SnapshotCodec in the stage's snapshot struct ---------
    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if cls.codec is not None:
            cls.snapshot_struct, cls.snapshot_versions = cls.codec.struct, (cls.codec.version,)

    def snapshot_fields(self) -> dict[str, Any]:
        assert self.codec is not None
        return self.codec.snapshot(self.state, self.steps, self.last)

    def restore_fields(self, snap: Any) -> None:
        assert self.codec is not None
        self.steps, self.last = snap.steps, dict(snap.last)
        try:
            self.state, self.shape = self.codec.restored(snap, self.core, self.last), None
        except ValueError as e:
            raise ValueError(f"stage {self.ctx.name!r}: bad {self.label} snapshot: {e}") from None


class FeaturesFilterStage(BoxFilterStage):
    """A filter stage whose observation is the preprocess stage's ``features`` (the contour and patch
    filters): missing or unusable features are weighed as no evidence (the tracker's ``update`` of the
    proposals with no observation), missing proposals reuse the last posterior. A subclass gives
    ``_features``, the observation of a features message."""

    port = "features"
    inputs = {"features": Features, "proposals": Particles}
    drivers = frozenset({"features"})
    prepare_ports = frozenset()

    @abstractmethod
    def _features(self, feat: Features, seq: int) -> Any:
        """The tracker's observation of a features message (None, reported: unusable)."""

    def _observe(self, feat: Any, seq: int) -> Any:
        if feat is None:
            return self.observed("features", None, seq, "coasting on the dynamics")
        return self._features(feat, seq)

    def _first_observation(self, seq: int, feat: Any) -> Any:
        if not isinstance(feat, Features):
            raise StageInputError(f"frame {seq}: cannot initialise without features")
        obs = self._observe(feat, seq)
        if obs is None:
            raise StageInputError(f"frame {seq}: cannot initialise on unusable features")
        return obs

    def _started(self, obs: Any) -> None:
        """Features are not held to the first frame's size (each array is checked where it is read)."""

    def _restored(self, data: bytes, decode: Callable[[bytes], Any], state_of: Callable[[Any], Any]) -> Any:
        """A snapshot of the tracker's own codec (``decode``) restored: sets the state ``state_of`` the decoded
        snapshot gives and returns that snapshot; ValueError in one line naming the stage otherwise."""
        snap = decoded(data, decode, self.ctx.name, self.kind)
        try:
            self.state = state_of(snap)
        except ValueError as e:
            raise ValueError(f"stage {self.ctx.name!r}: {e}") from None
        return snap

    def _proposed(self, seq: int, prop: Message | None) -> Any:
        """The proposed cloud (a subclass may take what its tracker's ``update`` takes of it)."""
        if isinstance(prop, Particles):
            return cloud_of(prop)
        # the proposals of this frame were lost: weigh the last posterior instead, so the
        # proposal -> filter cycle keeps turning
        self.report("missing_proposals", f"frame {seq}: no proposals arrived; reusing the last posterior", seq)
        return self._posterior()

    def _coast(self, proposed: Any, rng: FrameRng) -> tuple[Any, TrackerEstimate]:
        """No usable features: the proposals weighed by no evidence (the posterior is the prior)."""
        return self.tracker.update(self.core, self.state, proposed, None, rng)

    def _proposal(self, proposed: Any, dt: float) -> Any:
        """The proposed particles are the ``update`` argument."""
        return proposed


class BoxProposalStage(Stage[SeedBoxFields]):
    """The proposal stage of a box tracker (module docstring); a subclass sets ``kind``, ``Params``
    (:func:`~gflow_msgs.params.stage_params` of the tracker's parameter dataclass, with the field
    ``timed``), and ``box``, the random walk of the tracker's spec. A tracker whose particles carry
    more than alpha (the contour trackers' exemplar index k) sets ``purpose`` and overrides
    ``_clouds`` instead: its proposal of whole clouds."""

    #: the random walk and its draws' constant, of the tracker's spec
    box: ClassVar[BoxStages]
    inputs = {"particles": Particles}
    outputs = {"proposals": Particles}
    input_offsets = {"frames": -1}  # timed: frame t + 1 joins the posterior of t

    @classmethod
    def ports(cls, params: SeedBoxFields) -> tuple[Mapping[str, type], Mapping[str, type]]:
        timed = bool(getattr(params, "timed", False))
        return ({"particles": Particles, "frames": Frame} if timed else cls.inputs), cls.outputs

    def __init__(self, params: SeedBoxFields, ctx: StageContext) -> None:
        super().__init__(params, ctx)
        self.done = 0
        self.propose: CloudProposal = self._clouds(params, ctx)

    @property
    def purpose(self) -> int:
        """The constant of the proposal's draws (``FrameRng.stream(purpose)``)."""
        return self.box.purpose

    def _clouds(self, params: Any, ctx: StageContext) -> CloudProposal:
        """The proposal of whole clouds, made once from the stage's parameters and resources
        (``ValueError`` for unusable ones); a ``ValueError`` it raises on a cloud is the input's error.
        Here: the spec's walk of alpha, relative to the initial box's size."""
        box = params.initial_box(f"the {self.kind.split('.')[0]} proposal",
                                 " (its random walk is relative to the box's size)")
        walk = self.box.walk
        self.core: Any = core_params(params)
        core: Any = self.core
        size0 = (float(box[2]), float(box[3]))

        def propose(cloud: ParticleCloud, rng: np.random.Generator, dt: float) -> ParticleCloud:
            alpha = walk(core, cloud.alpha, size0, rng, dt)
            return ParticleCloud(alpha=alpha, k=np.zeros(cloud.n, np.int64), log_w=np.zeros(cloud.n))

        return propose

    def step(self, seq: int, inputs: Mapping[str, Message | None]) -> list[Output]:
        msg, frame = inputs["particles"], inputs.get("frames")
        assert isinstance(msg, Particles)
        cloud = cloud_of(msg)
        # the periods from the posterior of t-1 to frame t (1 unless ``timed`` joined frame t as ``frames``)
        dt = time_step(self.ctx, frame.header.stamp_ns, msg.header.stamp_ns) if isinstance(frame, Frame) else 1.0
        t = seq + 1
        rng = self.rng(t).stream(self.purpose)
        try:
            out = self.propose(cloud, rng, dt)
        except ValueError as e:
            raise StageInputError(f"particles {seq}: {e}") from None
        self.done += 1
        return [("proposals", particles_msg(self.header(t, msg.header.stamp_ns), "proposal", out))]

    def summary(self) -> dict[str, Any]:
        return {"proposed": self.done}

    snapshot_struct = CounterSnapshot
    snapshot_versions = (PROPOSAL_SNAPSHOT_VERSION,)
    snapshot_what = "proposal"

    def snapshot_fields(self) -> dict[str, Any]:
        return {"done": self.done}

    def restore_fields(self, snap: CounterSnapshot) -> None:
        self.done = snap.done
