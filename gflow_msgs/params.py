"""A stage's parameters derived from its tracker's parameter dataclass, never copied from it.

These structs are the contract between graph files (recorded with every run) and the stages, so
they sit with the messages and, like them, import nothing of gflow: the dataclass is an argument.

A tracker's parameters live in one frozen dataclass in ``gflow_core`` (for G-flow,
:class:`gflow_core.gflow.GFlowParams`): names, types, defaults, checks and help. A stage of that
tracker takes every one of them under the same name, plus the few fields of its own (the seed,
the initial box, its shard): :func:`stage_params` builds the stage's ``msgspec`` struct from the
two, so graph files are validated against the dataclass (unknown names, wrong types, the
dataclass's own checks) and a default cannot differ between the core and a stage.

A graph names its tracker's parameters once, in its ``tracker:`` block
(:mod:`pipeline.runtime.tracker_block`): :func:`block_params` is the struct that block is
validated with (the dataclass's fields alone), and :func:`tracker_of` says which dataclass a
stage's struct takes its fields from, so the graph hands every stage of that tracker the one
block and keeps only the stage's own fields per stage.
"""

from __future__ import annotations

import dataclasses
import math
import typing
from typing import Any, TypeVar

import msgspec

__all__ = ["Params", "StageFields", "SeedBoxFields", "check_init", "stage_params", "tracker_params", "core_params",
           "tracker_of", "block_params"]

F = TypeVar("F", bound="StageFields")
T = TypeVar("T")


class Params(msgspec.Struct, forbid_unknown_fields=True, frozen=True, kw_only=True):
    """Base of every stage's parameter struct: unknown keys are errors, not silently ignored."""


class StageFields(Params, frozen=True):
    """Base of the fields a stage adds to its tracker's parameters (declared as a subclass)."""

    def check(self, tracker: Any) -> None:
        """Checks of the stage's own fields against the tracker's parameters (``ValueError``)."""

    def box_needs(self) -> tuple[int, str]:
        """(pixels a side of the first frame the initial box must cover for this stage, what they are for):
        checked against the first frame before a run starts. ``(1, "")``: any pixel will do."""
        return 1, ""


class SeedBoxFields(StageFields, frozen=True):
    """The fields most tracker stages add: ``seed`` (frame ``t`` draws from ``[seed, crc32(stream), t,
    ...]``) and ``init``, the (x, y, w, h) initial box of the target in the first frame, 0-based pixels."""

    seed: int = 0
    init: tuple[float, float, float, float] | None = None

    def check(self, tracker: Any) -> None:
        if self.seed < 0:
            raise ValueError(f"seed must be >= 0, got {self.seed}")
        check_init(self.init)

    def initial_box(self, who: str, why: str = "") -> tuple[float, float, float, float]:
        """``init``; when there is none, ``ValueError`` in one line saying that ``who`` needs it (``why``)."""
        if self.init is None:
            raise ValueError(f"{who} needs an initial box{why}: set init: [x, y, w, h]")
        return self.init


def check_init(init: tuple[float, float, float, float] | None) -> None:
    """``ValueError`` for an initial box (x, y, w, h) with NaN or infinite values or without a positive
    width and height (None: no box, nothing to check)."""
    if init is not None:
        if not all(math.isfinite(v) for v in init):
            raise ValueError(f"init box has NaN or infinite values: {init}")
        if not (init[2] > 0 and init[3] > 0):
            raise ValueError(f"init box must have positive width and height, got w={init[2]}, h={init[3]} in {init}")


def refuse_nonfinite(values: typing.Mapping[str, Any], tracker: type | None = None) -> None:
    """``ValueError`` naming the first of ``values`` that is NaN, which no parameter means, or infinite (a number or
    an item of a list), which only a parameter of the dataclass ``tracker`` declared to take it means (its field's
    metadata ``inf``: what inf means, ``gflow_core.params.param``). A check such as ``x > 0`` is false for NaN only
    where written ``not x <= 0``, and true for inf, so a tracker's own checks pass them: a graph's ``.nan`` failed
    every frame of the run instead of the graph, and ``--set tracker.kappa=inf`` dcf's from its second frame on."""
    takes_inf = {f.name for f in dataclasses.fields(tracker) if f.metadata.get("inf")} if tracker is not None else set()
    for name, v in values.items():
        items = v if isinstance(v, (tuple, list)) else (v,)
        if any(isinstance(x, float) and math.isnan(x) for x in items):
            raise ValueError(f"{name} must be a number, got nan")
        if name not in takes_inf and any(isinstance(x, float) and math.isinf(x) for x in items):
            shown = f"[{', '.join(str(x) for x in items)}]" if items is v else str(v)
            raise ValueError(f"{name} must be a finite number, got {shown}")


def stage_params(name: str, tracker: type, fields: type[F], module: str, doc: str = "", *,
                 of_tracker: bool = True, only: tuple[str, ...] | None = None) -> type[F]:
    """The ``msgspec`` struct ``name`` with every field of the dataclass ``tracker`` (type and
    default as declared there) and those of ``fields``. Making one runs ``tracker``'s checks, then
    ``fields.check``: a bad value is a ``ValueError`` (``msgspec.ValidationError`` through
    ``msgspec.convert``) naming the parameter.

    ``of_tracker``: the struct is a stage of the tracker whose parameters ``tracker`` holds
    (:func:`tracker_of` names it, and a graph's tracker block feeds the stage). False for a stage
    that reads settings a dataclass declares without being a stage of a tracker (the preprocess
    stage, of :class:`gflow_core.contour.params.EdgeParams`): its values stay its own.

    ``only``: the struct takes these fields of ``tracker`` alone (a stage that reads a few of a
    tracker's settings, as the generic proposal its random walk); it is then no stage of the
    tracker (``of_tracker`` is ignored), and its checks are ``tracker``'s with the other fields at
    their defaults."""
    hints = typing.get_type_hints(tracker)
    own = {f.name for f in msgspec.structs.fields(fields)}
    taken = [f for f in dataclasses.fields(tracker) if only is None or f.name in only]
    if only is not None and len(taken) != len(only):
        raise TypeError(f"{tracker.__name__} has no field {sorted(set(only) - {f.name for f in taken})}")
    clash = sorted(own & {f.name for f in taken})
    if clash:
        raise TypeError(f"{fields.__name__} redeclares {', '.join(clash)} of {tracker.__name__}")
    spec = [(f.name, hints[f.name], f.default) for f in taken]
    of_tracker = of_tracker and only is None

    def __post_init__(self: F) -> None:
        values = {f.name: getattr(self, f.name) for f in taken}
        self.check(tracker(**values))
        refuse_nonfinite(values, tracker)

    struct = msgspec.defstruct(name, spec, bases=(fields,), module=module, kw_only=True, frozen=True,
                               forbid_unknown_fields=True,
                               namespace={"__post_init__": __post_init__, "__doc__": doc or fields.__doc__,
                                          **({"__gflow_tracker__": tracker} if of_tracker else {})})
    return typing.cast("type[F]", struct)


def tracker_of(struct: type) -> type | None:
    """The tracker's parameter dataclass whose fields the stage struct ``struct`` takes
    (:func:`stage_params`), or None for a stage of no tracker."""
    return typing.cast("type | None", getattr(struct, "__gflow_tracker__", None))


_blocks: dict[type, type[StageFields]] = {}


def block_params(tracker: type) -> type[StageFields]:
    """The ``msgspec`` struct of a graph's ``tracker:`` block for the dataclass ``tracker``: its
    fields alone, converted and checked as a stage of that tracker converts and checks them."""
    if tracker not in _blocks:
        _blocks[tracker] = stage_params(f"{tracker.__name__}Block", tracker, StageFields, __name__,
                                        f"The tracker block of {tracker.__name__}.")
    return _blocks[tracker]


def tracker_params(params: Params, tracker: type[T]) -> T:
    """The tracker's dataclass of a stage's parameters (the fields of the same names)."""
    return tracker(**{f.name: getattr(params, f.name) for f in dataclasses.fields(typing.cast(Any, tracker))})


def core_params(params: Params) -> Any:
    """The tracker's dataclass of the parameters of one of its stages (the dataclass :func:`stage_params`
    made the stage's struct of: :func:`tracker_of`)."""
    tracker = tracker_of(type(params))
    if tracker is None:
        raise TypeError(f"{type(params).__name__} is not the parameters of a tracker's stage")
    return tracker_params(params, tracker)
