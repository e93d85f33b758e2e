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

import functools
from dataclasses import dataclass
from typing import Any, Callable, Mapping, TypeVar

import msgspec
import numpy as np

from .base import MessageError, NDArray
from .gflow import ExpertStates

__all__ = ["PreprocessSnapshot", "CounterSnapshot", "BoxFilterSnapshot", "AppearanceFilterSnapshot",
           "GFlowProposalSnapshot", "GFlowFilterSnapshotV2", "GFlowFilterSnapshot", "versioned_snapshot", "article", "SnapshotCodec",
           "arrays_codec", "decoded"]


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


class GFlowFilterSnapshotV2(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Everything the G-flow filter stage keeps between frames without the online guard's model (versions 1
    and 2; written as version 2 whenever there is no such model, so that its bytes are those of the runs
    recorded before version 3). ``state`` has no backgrounds."""

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


class GFlowFilterSnapshot(GFlowFilterSnapshotV2, frozen=True, forbid_unknown_fields=True):
    """The G-flow filter stage's snapshot with the online guard's model of the face (version 3); every
    version decodes as it (a version-2 snapshot with ``online`` None)."""

    online: NDArray | None = None  # online guard (version 3): its model's arrays, one flat float64 vector
    online_values: dict[str, Any] | None = None  # ... their names and shapes, and the model's plain values


T = TypeVar("T")


def versioned_snapshot(data: bytes, struct: type[T], stage: str, what: str, version: int | tuple[int, ...]) -> T:
    """A stage's snapshot decoded as ``struct`` (a ``msgspec.Struct`` with a ``version`` field) and
    checked to be of ``version`` (or one of several a stage still reads); ``ValueError`` in one line naming
    the stage and ``what`` (``not a preprocess snapshot: ...``, ``preprocess snapshot version 3, expected
    2``) otherwise."""
    snap = decoded(data, functools.partial(msgspec.msgpack.decode, type=struct), stage, what)
    found, versions = getattr(snap, "version"), version if isinstance(version, tuple) else (version,)
    if found not in versions:
        raise ValueError(f"stage {stage!r}: {what} snapshot version {found}, expected "
                         f"{' or '.join(map(str, versions))}")
    return snap


def decoded(data: bytes, decode: Callable[[bytes], T], stage: str, what: str) -> T:
    """``decode(data)``; ``ValueError`` in one line naming the stage and ``what`` (``not a preprocess
    snapshot: ...``) for bytes it cannot decode (``msgspec.DecodeError``)."""
    try:
        return decode(data)
    except msgspec.DecodeError as e:
        raise ValueError(f"stage {stage!r}: not {article(what)} {what} snapshot: {e}") from None


def article(word: str) -> str:
    """'an' before a vowel, else 'a'."""
    return "an" if word[:1].lower() in "aeiou" else "a"



@dataclass(frozen=True)
class SnapshotCodec:
    """How a tracker's state travels in its filter stage's snapshot.

    ``struct`` is a ``msgspec.Struct`` with the fields ``version: int``, ``initialised: bool``,
    ``steps: int = 0`` and ``last: dict = {}`` besides the tracker's own (each with a default);
    ``version`` the version this code writes and reads; ``fields(state)`` the tracker's fields of a
    snapshot of ``state``; ``state(snap, params, last)`` the state of a decoded snapshot (``last`` is
    the last estimate's summary), raising ``ValueError``, ``KeyError``, ``IndexError``,
    ``TypeError``, ``AssertionError`` or :class:`~gflow_msgs.base.MessageError` for bad content."""

    struct: type[Any]
    version: int
    fields: Callable[[Any], dict[str, Any]]
    state: Callable[[Any, Any, dict], Any]

    def snapshot(self, state: Any, steps: int, last: dict) -> dict[str, Any]:
        """The fields of :attr:`struct` but ``version`` for a filter stage's ``state`` (None: not initialised),
        its step count and its last estimate's summary."""
        if state is None:
            return {"initialised": False, "steps": steps}
        return {"initialised": True, **self.fields(state), "steps": steps, "last": last}

    def restored(self, snap: Any, params: Any, last: dict) -> Any:
        """The state of a decoded snapshot (None: not initialised); ``ValueError`` for bad content."""
        if not snap.initialised:
            return None
        try:
            return self.state(snap, params, last)
        except (AssertionError, KeyError, IndexError, TypeError, MessageError, ValueError) as e:
            raise ValueError(str(e)) from None


ToArrays = Callable[[Any], tuple[Mapping[str, np.ndarray], Mapping[str, Any]]]
FromArrays = Callable[[dict[str, np.ndarray], dict[str, Any], Any], Any]


def arrays_codec(to_arrays: ToArrays, from_arrays: FromArrays, version: int, struct: str = "") -> SnapshotCodec:
    """The codec of a state a tracker gives as arrays and plain values (``to_arrays(state)`` -> (arrays,
    values); ``from_arrays(arrays, values, params)`` -> state): :class:`BoxFilterSnapshot`, whose fields
    ``arrays`` and ``values`` hold them, or, when ``struct`` names a Struct of this module (a format older
    than the generic one: :class:`AppearanceFilterSnapshot`), that Struct with the arrays and values as its
    own fields, ``from_arrays`` then handed its array fields and every other one (``last`` among them).
    ``ValueError`` when ``struct`` names none."""
    if not struct:
        def fields(state: Any) -> dict[str, Any]:
            arrays, values = to_arrays(state)
            return {"arrays": {k: NDArray.of(np.asarray(v)) for k, v in arrays.items()}, "values": dict(values)}

        def state_of(snap: Any, params: Any, last: dict) -> Any:
            return from_arrays({k: v.array() for k, v in snap.arrays.items()}, dict(snap.values), params)

        return SnapshotCodec(BoxFilterSnapshot, version, fields, state_of)
    own = globals().get(struct)
    if not (isinstance(own, type) and issubclass(own, msgspec.Struct)):
        raise ValueError(f"gflow_msgs.snapshots has no snapshot Struct {struct!r}")

    def flat(state: Any) -> dict[str, Any]:
        arrays, values = to_arrays(state)
        return {**{k: NDArray.of(np.asarray(v)) for k, v in arrays.items()}, **values}

    def of_flat(snap: Any, params: Any, last: dict) -> Any:
        fields = msgspec.structs.asdict(snap)
        arrays = {k: v.array() for k, v in fields.items() if isinstance(v, NDArray)}
        return from_arrays(arrays, {k: v for k, v in fields.items() if k not in arrays}, params)

    return SnapshotCodec(own, version, flat, of_flat)
