"""Filter stage of the appearance tracker: M2 with online exemplars (the default tracker).

The mathematics is :mod:`gflow_core.appearance` (its docstring lists the departures from
Toyama & Blake 2002). This stage adapts it to the pipeline's particle messages:

* Inputs: ``frames`` of frame t (colour or grey; the appearance channels are computed here
  from the grey levels) and ``proposals`` for frame t from ``particle.proposal`` (a random
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
the moments of the target's and the clutter's distance distributions, the hidden-frame count
and counters, as msgpack of a small Struct (version 2).
"""

from __future__ import annotations

from dataclasses import fields
from typing import Mapping

import msgspec
import numpy as np

from gflow_core import features
from gflow_core import appearance as ap
from gflow_core.m2.tracking import ParticleCloud

from .base import Output, Params, Stage, StageInputError
from .messages import Estimate, Frame, Message, MessageError, NDArray, Particles
from .particle_proposal import cloud_of, particles_msg
from .rng import frame_rng
from .time_step import time_step

__all__ = ["AppearanceFilterStage", "AppearanceFilterParams"]

PURPOSE_INIT = 0x51A1
PURPOSE_STEP = 0x51A2
SNAPSHOT_VERSION = 2
_DEFAULTS = ap.AppearanceParams()


class AppearanceFilterParams(Params):
    """Appearance filter settings; every field but ``init`` and ``seed`` is the field of the
    same name of :class:`gflow_core.appearance.AppearanceParams` (see it for meanings)."""

    init: tuple[float, float, float, float] | None = None
    seed: int = 0
    particles: int = _DEFAULTS.particles
    lam: float = _DEFAULTS.lam
    max_area: int = _DEFAULTS.max_area
    update_rate: float = _DEFAULTS.update_rate
    n_scales: int = _DEFAULTS.n_scales
    scale_step: float = _DEFAULTS.scale_step
    std_log_s: float = _DEFAULTS.std_log_s
    detect_fraction: float = _DEFAULTS.detect_fraction
    detect_std: float = _DEFAULTS.detect_std
    motion_prior: float = _DEFAULTS.motion_prior
    search: float = _DEFAULTS.search
    velocity_memory: float = _DEFAULTS.velocity_memory
    max_log_scale: float = _DEFAULTS.max_log_scale
    hidden_prior: float = _DEFAULTS.hidden_prior
    hidden_speed: float = _DEFAULTS.hidden_speed
    scale_from_recent: bool = _DEFAULTS.scale_from_recent
    adapt_max: float = _DEFAULTS.adapt_max
    slow_rate: float = _DEFAULTS.slow_rate
    scale_search: int = _DEFAULTS.scale_search
    scale_search_step: float = _DEFAULTS.scale_search_step
    scale_change_std: float = _DEFAULTS.scale_change_std
    scale_anchor_weight: float = _DEFAULTS.scale_anchor_weight
    scale_lam: float = _DEFAULTS.scale_lam
    scale_refine: int = _DEFAULTS.scale_refine
    scale_gain: float = _DEFAULTS.scale_gain
    refine_position: bool = _DEFAULTS.refine_position
    scale_consistency: float = _DEFAULTS.scale_consistency
    scale_min_score: float = _DEFAULTS.scale_min_score
    scale_gate: float = _DEFAULTS.scale_gate
    warmup: int = _DEFAULTS.warmup
    min_std: float = _DEFAULTS.min_std
    target_rate: float = _DEFAULTS.target_rate
    clutter_rate: float = _DEFAULTS.clutter_rate
    search_start: float = _DEFAULTS.search_start
    search_growth: float = _DEFAULTS.search_growth
    search_scales: tuple[float, ...] = _DEFAULTS.search_scales
    search_area: int = _DEFAULTS.search_area
    hidden_after: int = _DEFAULTS.hidden_after
    reappear: float = _DEFAULTS.reappear

    def __post_init__(self) -> None:
        if self.init is not None and not (self.init[2] > 0 and self.init[3] > 0):
            raise ValueError(f"init box must have positive width and height, got {self.init}")
        self.core()  # the core's own checks, before anything starts

    def core(self) -> ap.AppearanceParams:
        return ap.AppearanceParams(**{f.name: getattr(self, f.name) for f in fields(ap.AppearanceParams)})


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
    steps: int = 0
    last: dict = {}


def _alpha(parts: np.ndarray) -> np.ndarray:
    """(N, 3) (x, y, log s) -> (N, 4) alpha = (x, y, 0, s)."""
    return np.column_stack([parts[:, 0], parts[:, 1], np.zeros(len(parts)), np.exp(parts[:, 2])])


def _posterior(header, parts: np.ndarray) -> Particles:
    """The resampled posterior (N, 3) as a Particles message (k = 0, equal weights)."""
    n = len(parts)
    return particles_msg(header, "posterior", ParticleCloud(alpha=_alpha(parts), k=np.zeros(n, np.int64),
                                                            log_w=np.zeros(n)))


class AppearanceFilterStage(Stage):
    kind = "appearance.filter"
    Params = AppearanceFilterParams
    inputs = {"frames": Frame, "proposals": Particles}
    outputs = {"particles": Particles, "estimate": Estimate}
    drivers = frozenset({"frames"})
    prepare_ports = frozenset({"frames"})

    def __init__(self, params: AppearanceFilterParams, ctx) -> None:
        super().__init__(params, ctx)
        if params.init is None:
            raise ValueError("the appearance filter needs an initial box: set init: [x, y, w, h]")
        self.core = params.core()
        self.state: ap.AppearanceState | None = None
        self.shape: tuple[int, int] | None = None
        self.steps = 0
        self.last: dict = {}

    def required(self, seq: int) -> frozenset[str]:
        return frozenset({"frames"}) if self.state is None else frozenset(self.inputs)

    def prepare(self, port: str, msg: Message) -> tuple[np.ndarray, np.ndarray | ValueError]:
        """(grey (H, W) uint8, appearance channels (H, W, 4) float32) of a frame; the channels are
        the ValueError they raised, if any (raised by ``step`` only for a frame it would use).
        Raises MessageError or ValueError for an image that cannot be read."""
        assert isinstance(msg, Frame)
        grey = features.to_grey(msg.image.array())
        try:
            return grey, ap.features(grey)
        except ValueError as e:
            return grey, e

    def _grey(self, frame: Frame | None, seq: int) -> tuple[np.ndarray, np.ndarray] | None:
        """The frame's grey levels and appearance channels, or None (reported) when the frame
        cannot be used."""
        if frame is None:
            self.report("missing_frame", f"frame {seq}: no frame arrived; coasting", seq)
            return None
        try:
            grey, feat = self.prepared("frames", frame)
        except (MessageError, ValueError) as e:
            self.report("bad_frame", f"frame {seq}: {e}; coasting", seq)
            return None
        if self.shape is not None and grey.shape != self.shape:
            self.report("bad_frame", f"frame {seq}: {grey.shape[1]}x{grey.shape[0]} but the stream is "
                        f"{self.shape[1]}x{self.shape[0]}; coasting", seq)
            return None
        if grey.size == 0 or int(grey.max()) == int(grey.min()):
            self.report("blank_frame", f"frame {seq}: uniform frame, no evidence; coasting", seq)
            return None
        if isinstance(feat, ValueError):
            raise feat
        return grey, feat

    def _estimate(self, header, box, alpha, mean, std, ess, log_ev, state, score, confidence: float = 1.0,
                  target_state: str = "tracked") -> Estimate:
        p: AppearanceFilterParams = self.params  # type: ignore[assignment]
        x, y, w, h = box
        outline = np.array([[x, y], [x + w, y], [x + w, y + h], [x, y + h]], dtype=np.float32)
        self.last = {"seq": header.seq, "box": [round(v, 2) for v in box], "ess": round(float(ess), 1),
                     "state": state, "score": round(float(score), 4), "confidence": round(float(confidence), 4),
                     "target_state": target_state}
        return Estimate(header=header, box=tuple(float(v) for v in box), alpha=tuple(float(v) for v in alpha), k=0,
                        mean=tuple(float(v) for v in mean), std=tuple(float(v) for v in std), ess=float(ess),
                        n=p.particles, log_evidence=float(log_ev), contour=NDArray.of(outline), state=state,
                        confidence=float(confidence), target_state=target_state)

    def _initialise(self, seq: int, frame: Frame | None) -> list[Output]:
        p: AppearanceFilterParams = self.params  # type: ignore[assignment]
        try:
            got = self._grey(frame, seq)
        except ValueError as e:  # the channels of a frame too small for them
            raise StageInputError(f"frame {seq}: {e}") from None
        if got is None or frame is None:
            raise StageInputError(f"frame {seq}: cannot initialise on this frame")
        grey, feat = got
        try:
            st = ap.initialise(feat, p.init, self.core, frame_rng(p.seed, self.ctx.stream, seq,  # type: ignore[arg-type]
                                                                                 PURPOSE_INIT))
        except ValueError as e:
            raise StageInputError(f"frame {seq}: {e}") from None
        self.state, self.shape = st, grey.shape
        a = np.array([st.centre[0], st.centre[1], 0.0, 1.0])
        box = ap.box_of(st.centre, st.log_s, st.size0)
        est = self._estimate(frame.header, box, a, a, np.zeros(4), float(p.particles), 0.0, "init", 1.0)
        self.steps += 1
        return [("particles", _posterior(frame.header, st.particles)), ("estimate", est)]

    def _coast(self, seq: int, frame: Frame | None) -> list[Output]:
        """No usable frame: carry the posterior over unchanged."""
        st = self.state
        assert st is not None
        p: AppearanceFilterParams = self.params  # type: ignore[assignment]
        header = frame.header if frame is not None else self.header(seq, 0)
        a = np.array([st.centre[0], st.centre[1], 0.0, float(np.exp(st.log_s))])
        box = ap.box_of(st.centre, st.log_s, st.size0)
        # no evidence this frame: the target is where it was judged to be, with no confidence
        judged = "tracked" if st.hidden_run == 0 else str(self.last.get("target_state", "occluded"))
        est = self._estimate(header, box, a, a, np.zeros(4), float(p.particles), 0.0, "coast", 0.0, 0.0, judged)
        self.steps += 1
        return [("particles", _posterior(header, st.particles)), ("estimate", est)]

    def step(self, seq: int, inputs: Mapping[str, Message | None]) -> list[Output]:
        frame = inputs.get("frames")
        frame = frame if isinstance(frame, Frame) else None
        if self.state is None:
            return self._initialise(seq, frame)
        p: AppearanceFilterParams = self.params  # type: ignore[assignment]
        st = self.state
        prop = inputs.get("proposals")
        if isinstance(prop, Particles):
            cloud = cloud_of(prop)
            alpha = cloud.alpha
            if alpha.shape[0] != p.particles or not np.isfinite(alpha).all() or not (alpha[:, 3] > 0).all():
                self.report("bad_proposals", f"proposals {seq}: {alpha.shape[0]} particles (expected "
                            f"{p.particles}), non-finite or non-positive scale; reusing the last posterior", seq)
                proposed = st.particles
            else:
                proposed = np.column_stack([alpha[:, 0], alpha[:, 1], np.log(alpha[:, 3])])
        else:
            self.report("missing_proposals", f"frame {seq}: no proposals arrived; reusing the last posterior", seq)
            proposed = st.particles
        got = self._grey(frame, seq)
        if got is None:
            return self._coast(seq, frame)
        assert frame is not None
        # periods since the posterior the proposals came from (its stamp: the proposal stage keeps it)
        dt = time_step(self.ctx, frame.header.stamp_ns, prop.header.stamp_ns) if isinstance(prop, Particles) else 1.0
        res = ap.step(st, got[1], proposed, self.core, frame_rng(p.seed, self.ctx.stream, seq, PURPOSE_STEP), dt)
        self.state = res.state
        self.steps += 1
        nst = res.state
        a = np.array([nst.centre[0], nst.centre[1], 0.0, float(np.exp(nst.log_s))])
        mean = np.array([res.mean[0], res.mean[1], 0.0, float(np.exp(res.mean[2]))])
        std = np.array([res.std[0], res.std[1], 0.0, float(res.std[2])])
        path = ("redetect" if res.redetected else "track") if res.target_state == "tracked" else res.target_state
        est = self._estimate(frame.header, res.box, a, mean, std, res.ess, res.log_evidence, path, res.score,
                             res.confidence, res.target_state)
        return [("particles", _posterior(frame.header, nst.particles)), ("estimate", est)]

    def summary(self) -> dict:
        """The last estimate (seq, box, ESS, state, appearance score r) and the step count."""
        return dict(self.last, steps=self.steps)

    # -- snapshot / restore ---------------------------------------------------------------
    def snapshot(self) -> bytes:
        st = self.state
        if st is None:
            return msgspec.msgpack.encode(_Snapshot(version=SNAPSHOT_VERSION, initialised=False, steps=self.steps))
        return msgspec.msgpack.encode(_Snapshot(
            version=SNAPSHOT_VERSION, initialised=True, size0=(float(st.size0[0]), float(st.size0[1])),
            res=(int(st.res[0]), int(st.res[1])), anchor=NDArray.of(st.anchor), recent=NDArray.of(st.recent),
            slow=NDArray.of(st.slow), particles=NDArray.of(st.particles), centre=(float(st.centre[0]), float(st.centre[1])),
            log_s=float(st.log_s), velocity=(float(st.velocity[0]), float(st.velocity[1])),
            target=(st.target.m1, st.target.m2, st.target.n), clutter=(st.clutter.m1, st.clutter.m2, st.clutter.n),
            hidden_run=int(st.hidden_run), steps=self.steps, last=self.last))

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
        except (AssertionError, MessageError, ValueError) as e:
            raise ValueError(f"stage {name!r}: bad appearance snapshot: {e}") from None
        self.state = ap.AppearanceState(size0=np.array(snap.size0), res=(snap.res[0], snap.res[1]), anchor=anchor,
                                        recent=recent, particles=parts, centre=np.array(snap.centre),
                                        log_s=snap.log_s, velocity=np.array(snap.velocity), slow=slow,
                                        target=ap.ChiSquare(*snap.target), clutter=ap.ChiSquare(*snap.clutter),
                                        hidden_run=snap.hidden_run)
        self.shape = None
