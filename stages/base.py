"""The stage contract: a plain class whose ``step()`` maps input messages to output messages.

A stage knows nothing about zenoh, files or clocks. The runner in ``pipeline/`` joins its
inputs by sequence number, calls ``step(seq, inputs)`` in ascending ``seq`` order, and
publishes what it returns. The same stage object therefore runs in-process (tests,
``--inline``), as its own process over zenoh, and fed from an MCAP recording.

Join semantics (implemented by ``pipeline.runtime.join.SeqJoin``)
---------------------------------------------------------
* ``inputs`` maps port name -> message type. Each port carries increasing ``seq``.
* ``required(seq)`` names the ports that must be present for ``seq`` to run (default:
  all). A port that has moved past ``seq`` without delivering it counts as *missing*;
  the stage then gets ``None`` for it (a dropped or skipped message) and decides what to do.
* ``drivers`` are the ports whose end-of-stream ends the stage (default: all ports).
* ``input_offsets`` shifts a port's sequence numbers before the join: with
  ``{"state": 1}``, the state message of frame t-1 is joined with the frames of t.
* ``ports(params)`` may give an instance its own ports (a filter fed by N proposal
  shards has N proposal ports); by default they are the class's ``inputs``/``outputs``.
* ``prepare_ports`` / ``prepare(port, msg)``: per-message work that depends on that one
  message alone (the features of a frame, say). ``step`` asks for it with
  ``self.prepared(port, msg)``; a runner may have computed it ahead, on another thread, as
  soon as the message arrived -- while ``step`` ran for an earlier frame -- and otherwise it is
  computed there and then. Either way the result is the same, so outputs do not depend on
  whether, or when, the runner prepared anything.
* Errors in one input are reported with ``self.report(...)`` (or by raising
  :class:`StageInputError`); the runner publishes them on the error topic and the stage
  keeps running.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Any, Callable, ClassVar, Generic, Mapping, TypeVar

import msgspec

from gflow_core.tracker import FrameRng, tracker_rng
from gflow_msgs.messages import Header, Message
from gflow_msgs.params import Params
from gflow_msgs.snapshots import versioned_snapshot

__all__ = ["Stage", "StageContext", "StageInputError", "Output", "Params"]

class StageInputError(ValueError):
    """An input a stage cannot use (bad shape, NaNs, empty edge map...). The stage skips it."""


@dataclass(frozen=True)
class StageContext:
    """Where a stage instance sits: its name in the graph and the stream it serves.

    ``resources`` holds what the pipeline loaded for the stage from files named in its
    parameters (a learned model as a dict of arrays, for example): stages never open files.
    ``frame_period_ns`` is the nominal frame period of a source whose frames carry host
    capture stamps (a live source), the unit of :func:`stages.time_step.time_step`; 0 when
    the stamps are media time (files: one period apart by construction).
    """

    name: str
    stream: str
    resources: Mapping[str, Any] = field(default_factory=dict)
    frame_period_ns: float = 0.0


# (output port, message): a message of gflow_msgs.messages, or a Foxglove message on a viewer's topic
Output = tuple[str, Any]

#: a stage's parameter struct
P = TypeVar("P", bound=Params)
_Params = Params  # the base struct, inside Stage's body where ``Params`` is the class attribute


@dataclass
class _Reports:
    items: list[tuple[str, str, int]] = field(default_factory=list)


class Stage(ABC, Generic[P]):
    """Base class of every stage, generic over its parameter struct ``P`` (``self.params: P``).
    Subclasses set ``kind``, ``Params`` (the struct ``P``), ``inputs``, ``outputs``:
    ``class PreprocessStage(Stage[PreprocessParams])``."""

    kind: ClassVar[str]
    Params: ClassVar[type[_Params]]
    #: {port: message type}; an instance's own (:meth:`ports`) replace the class's
    inputs: Mapping[str, type] = {}
    outputs: Mapping[str, type] = {}
    drivers: ClassVar[frozenset[str] | None] = None
    input_offsets: ClassVar[Mapping[str, int]] = {}
    #: input ports whose messages ``prepare`` may be called on ahead of their step
    prepare_ports: frozenset[str] = frozenset()  # a stage may choose its own from its parameters
    #: the ``msgspec.Struct`` of the stage's snapshot, with a ``version`` field (:mod:`gflow_msgs.snapshots`;
    #: None: a stage that keeps no state between frames, or encodes its snapshot itself)
    snapshot_struct: ClassVar[type[Any] | None] = None
    #: the snapshot versions :meth:`restore` reads, oldest first; the last is the one :meth:`snapshot` writes
    snapshot_versions: ClassVar[tuple[int, ...]] = (1,)

    def __init__(self, params: P, ctx: StageContext) -> None:
        self.params: P = params
        self.ctx = ctx
        self._reports = _Reports()
        # (port, header seq) -> a callable giving prepare(port, msg)'s result (or raising its
        # exception): what a runner computed ahead (pipeline.runtime.stage_host.StageHost)
        self.ahead: dict[tuple[str, int], Callable[[], Any]] = {}
        ins, outs = type(self).ports(params)
        self.inputs = dict(ins)
        self.outputs = dict(outs)

    @classmethod
    def ports(cls, params: P) -> tuple[Mapping[str, type], Mapping[str, type]]:
        """(inputs, outputs) of an instance with these parameters: {port: message type}."""
        return cls.inputs, cls.outputs

    # -- called by the runner -------------------------------------------------------------
    def required(self, seq: int) -> frozenset[str]:
        """Ports that must be present for ``seq`` to run. Default: every input port."""
        return frozenset(self.inputs)

    @abstractmethod
    def step(self, seq: int, inputs: Mapping[str, Message | None]) -> list[Output]:
        """Map the joined inputs of ``seq`` to outputs ``[(port, message), ...]``."""

    def prepare(self, port: str, msg: Message) -> Any:
        """The work on one input message of a port in ``prepare_ports`` that depends on that
        message alone, never on the stage's state (it may run on another thread while ``step``
        runs). Exceptions propagate to :meth:`prepared`. A stage with ``prepare_ports`` overrides
        it (:meth:`check_prepare`, called by every runner when it takes the stage)."""
        raise TypeError(f"stage kind {self.kind!r} calls prepared() but does not implement prepare()")

    def check_prepare(self) -> None:
        """TypeError when the stage lists ``prepare_ports`` (they may depend on its parameters,
        so this is checked on the instance) but does not implement :meth:`prepare`."""
        if self.prepare_ports and type(self).prepare is Stage.prepare:
            raise TypeError(f"stage kind {self.kind!r} lists prepare_ports {sorted(self.prepare_ports)} "
                            "but does not implement prepare()")

    def prepared(self, port: str, msg: Message) -> Any:
        """``prepare(port, msg)``: the result a runner computed ahead when there is one, else
        computed now. Call it from ``step`` (with the message ``step`` was given)."""
        ahead = self.ahead.pop((port, msg.header.seq), None)
        return ahead() if ahead is not None else self.prepare(port, msg)

    def finish(self) -> list[Output]:
        """Called once when the inputs have ended; may return final outputs."""
        return []

    def summary(self) -> dict[str, Any]:
        """A small, printable summary of the internal state (for stepping and status)."""
        return {}

    def snapshot(self) -> bytes | None:
        """The whole internal state after the last ``step``, as bytes (msgpack of a
        stage-specific struct, never pickle), or None for a stage that keeps no state
        between frames. ``restore(snapshot())`` on a fresh instance with the same
        parameters, then the inputs that follow, must give the same outputs bit for bit.

        By default one encode of :attr:`snapshot_struct` made of :meth:`snapshot_fields` and the
        version the stage writes (the last of :attr:`snapshot_versions`)."""
        if self.snapshot_struct is None:
            return None
        return msgspec.msgpack.encode(self.snapshot_struct(version=self.snapshot_versions[-1],
                                                           **self.snapshot_fields()))

    def restore(self, data: bytes) -> None:
        """Load a state made by :meth:`snapshot`. Stateless stages accept only ``None``.

        By default :attr:`snapshot_struct` decoded and its version checked
        (:func:`gflow_msgs.snapshots.versioned_snapshot`: ``ValueError`` in one line naming the stage
        and :attr:`snapshot_what`), then handed to :meth:`restore_fields`."""
        if self.snapshot_struct is None:
            raise TypeError(f"stage kind {self.kind!r} keeps no state, so it has nothing to restore")
        self.restore_fields(versioned_snapshot(data, self.snapshot_struct, self.ctx.name, self.snapshot_what,
                                               self.snapshot_versions))

    @property
    def snapshot_what(self) -> str:
        """What the stage's snapshot is called in a restore's errors (``gflow.filter snapshot ...``)."""
        return self.kind

    def snapshot_fields(self) -> dict[str, Any]:
        """The fields of :attr:`snapshot_struct` but ``version``: what the stage keeps between frames."""
        raise TypeError(f"stage kind {self.kind!r} names a snapshot struct but gives no snapshot_fields()")

    def restore_fields(self, snap: Any) -> None:
        """Take the state of a decoded :attr:`snapshot_struct` of a version the stage reads."""
        raise TypeError(f"stage kind {self.kind!r} names a snapshot struct but gives no restore_fields()")

    def drain_reports(self) -> list[tuple[str, str, int]]:
        """Return and clear the ``(kind, message, seq)`` problems reported since the last call."""
        out, self._reports.items = self._reports.items, []
        return out

    # -- helpers for subclasses -------------------------------------------------------------
    def report(self, kind: str, message: str, seq: int = -1) -> None:
        """Record a problem with an input; the runner publishes it on the error topic."""
        self._reports.items.append((kind, message, seq))

    def header(self, seq: int, stamp_ns: int) -> Header:
        return Header(stream=self.ctx.stream, seq=seq, stamp_ns=stamp_ns)

    def observed(self, port: str, msg: Message | None, seq: int, then: str, missing: bool = True) -> Any:
        """What :meth:`prepare` makes of the input ``msg`` of ``port`` for frame ``seq`` (made ahead or now,
        :meth:`prepared`), or None, reported, when there is none: no message (``missing_frame`` or
        ``missing_features``, when ``missing``) or one :meth:`prepare` cannot read (it raised ``ValueError``,
        :class:`StageInputError` and ``MessageError`` among them: ``bad_frame`` or ``bad_features``), each
        report ending with ``then``, what the stage does without it."""
        noun = "frame" if port == "frames" else port
        if msg is None:
            if missing:
                self.report(f"missing_{noun}", f"frame {seq}: no {noun} arrived; {then}", seq)
            return None
        try:
            return self.prepared(port, msg)
        except ValueError as e:
            self.report(f"bad_{noun}", f"frame {seq}: {e}; {then}", seq)
            return None

    def same_size(self, port: str, seq: int, shape: tuple[int, ...], started: tuple[int, ...] | None,
                  then: str) -> bool:
        """Whether frame ``seq``, of ``shape`` (H, W), has the size of the frames the stage started on
        (``started``; None: not started, any size); reported as ``bad_frame`` or ``bad_features`` (the input
        of ``port``) when not: the tracker's state is for frames of that size."""
        if started is None or tuple(shape) == tuple(started):
            return True
        self.report("bad_frame" if port == "frames" else f"bad_{port}",
                    f"frame {seq}: size {shape[1]}x{shape[0]} differs from the {started[1]}x{started[0]} frames "
                    f"the tracker started on; frame skipped; {then}", seq)
        return False

    def learned_model(self, required: bool = True) -> Any:
        """The learned model the pipeline loaded for the stage (resource ``model``, from its ``model``
        parameter), or None when there is none and it is not ``required``; ``ValueError`` in one line
        naming the stage when a required one is missing."""
        model = self.ctx.resources.get("model")
        if model is None and required:
            raise ValueError(f"stage {self.ctx.name!r}: {self.kind} needs a learned model: set model: MODEL.npz "
                             f"(`gflow learn m2`)")
        return model

    def header_of(self, msg: Message | None, seq: int) -> Header:
        """The header of the input ``msg`` of frame ``seq``, or one without a stamp when it did not come."""
        return msg.header if msg is not None else self.header(seq, 0)

    def rng(self, seq: int) -> FrameRng:
        """The tracker's draws of frame ``seq``, ``FrameRng(seed, crc32(stream), seq)``, for a stage whose
        parameters have a ``seed`` (a tracker's stage)."""
        return tracker_rng(getattr(self.params, "seed"), self.ctx.stream, seq)

    def driver_ports(self) -> frozenset[str]:
        return frozenset(self.inputs) if self.drivers is None else self.drivers
