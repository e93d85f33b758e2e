"""The stages' snapshots: what each stage keeps between frames, as it is written into a recording.

A stage's ``snapshot()`` is one msgpack encode of one of these Structs, carried in the ``data`` of a
:class:`~gflow_msgs.messages.Snapshot` message; ``gflow rerun --from SEQ`` restores it and
``gflow rerun --check`` compares its bytes, so each Struct is part of the recording format: fields
are never renamed, retyped or reordered, and a new field gets a default and goes at the end (the
stage's snapshot version says which fields a snapshot has). Arrays are :class:`NDArray`; a Struct
may nest a message (:class:`~gflow_msgs.gflow.ExpertStates`). The version numbers, and what each
stage reads of older versions, are the stages' (``stages/``); :func:`versioned_snapshot` reads one
back and checks its version.
"""

from __future__ import annotations

from typing import Any, TypeVar

import msgspec

from .base import NDArray
from .gflow import ExpertStates

__all__ = ["PreprocessSnapshot", "CounterSnapshot", "BoxFilterSnapshot", "AppearanceFilterSnapshot",
           "GFlowProposalSnapshot", "GFlowFilterSnapshot", "versioned_snapshot", "article"]


class PreprocessSnapshot(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """The preprocess stage: the Canny thresholds calibrated on the first frame, and the frame counter."""

    version: int
    done: int
    thresholds: tuple[float, float] | None


class CounterSnapshot(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """A box tracker's proposal stage: its step counter (its outputs depend on no other state)."""

    version: int
    done: int


class BoxFilterSnapshot(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """The filter stage of a tracker whose spec gives its state as arrays and values
    (``gflow_core.spec.BoxStages.to_arrays``), with the step count and the last estimate's summary."""

    version: int
    initialised: bool
    arrays: dict[str, NDArray] = {}
    values: dict[str, Any] = {}
    steps: int = 0
    last: dict = {}


class AppearanceFilterSnapshot(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """The appearance tracker's filter stage (version 4): its exemplars, particle cloud, velocity,
    distance and colour distributions, hidden-frame count and counters."""

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


class GFlowProposalSnapshot(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Everything a G-flow proposal stage keeps between frames (version 2; arrays as NDArray)."""

    version: int
    image_shape: tuple[int, int] | None
    digest: str
    init_seq: int  # -1: not initialised
    prev_seq: int  # the background replica's fields (BackgroundReplica.fields), arrays as NDArray
    prev_grey: NDArray | None
    bg_seq: int
    bg_tile: int
    bg_table: NDArray | None
    bg_mean: NDArray | None
    bg_var: NDArray | None
    steps: int
    init_error: str


class GFlowFilterSnapshot(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Everything the G-flow filter stage keeps between frames (version 2). ``state`` has no backgrounds."""

    version: int
    image_shape: tuple[int, int] | None
    digest: str
    state: ExpertStates | None
    steps: int
    coasted: int
    init_error: str
    confidence: float = 1.0  # of the last observed frame
    target_state: str = "tracked"
    anchor: NDArray | None = None  # lost guard (version 2): (th, tw, 4) channels of the initial box
    anchor_colour: NDArray | None = None  # ... (N_BINS,) its colour histogram
    lost_target: tuple[float, float, int] = (0.0, 0.0, 0)  # ... moments m1, m2, count of the target's distance
    lost_clutter: tuple[float, float, int] = (0.0, 0.0, 0)  # ... and of the clutter's best distance
    lost_ctarget: tuple[float, float, int] = (0.0, 0.0, 0)  # ... of the target's colour distance
    lost_cclutter: tuple[float, float, int] = (0.0, 0.0, 0)  # ... and of the clutter's best colour distance
    lost_runs: tuple[int, int] = (0, 0)  # ... found frames, consecutive lost frames
    held: tuple[float, ...] | None = None  # ... box (x, y, w, h) and pose (P) of the last found frame
    fit_level: tuple[float, float, int] = (0.0, 0.0, 0)  # ... moments of the first look's misfit when found
    look_clutter: tuple[float, float, int] = (0.0, 0.0, 0)  # ... and of its best misfit beside the target then


T = TypeVar("T")


def versioned_snapshot(data: bytes, struct: type[T], stage: str, what: str, version: int | tuple[int, ...]) -> T:
    """A stage's snapshot decoded as ``struct`` (a ``msgspec.Struct`` with a ``version`` field) and
    checked to be of ``version`` (or one of several a stage still reads); ``ValueError`` in one line naming
    the stage and ``what`` (``not a preprocess snapshot: ...``, ``preprocess snapshot version 3, expected
    2``) otherwise."""
    try:
        snap = msgspec.msgpack.decode(data, type=struct)
    except msgspec.DecodeError as e:
        raise ValueError(f"stage {stage!r}: not {article(what)} {what} snapshot: {e}") from None
    found, versions = getattr(snap, "version"), version if isinstance(version, tuple) else (version,)
    if found not in versions:
        raise ValueError(f"stage {stage!r}: {what} snapshot version {found}, expected "
                         f"{' or '.join(map(str, versions))}")
    return snap


def article(word: str) -> str:
    """'an' before a vowel, else 'a'."""
    return "an" if word[:1].lower() in "aeiou" else "a"

