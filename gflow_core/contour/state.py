"""The contour filter's state as it travels in a snapshot: one msgspec Struct
(:class:`ContourSnapshot`), encoded and decoded in one call (:func:`encode`, :func:`decode`).

Arrays are fields of type ``np.ndarray`` (:mod:`gflow_core.m2.snapshot_arrays`), encoded to the
bytes the pipeline's message arrays encode to, so a snapshot is the same bytes as the
field-by-field snapshots of the filter stage before it. :func:`snapshot_of` is the snapshot of a :class:`.tracker.ContourState` and the stage's
counters; :func:`state_of` the state of a snapshot of any version this code reads.

Versions: 5 (this one); 1 (no online bank) and 2 (an older lost guard: a level and thresholds,
not restored: the guard starts afresh); 3 (a guard that weighs no colour: it restores without); 1-4
(before the template update: the template is the first one, and the lost guard's anchor the first
anchor).
"""

from __future__ import annotations

from typing import Any

import msgspec
import numpy as np

from ..m2.appearance_metric import OnlineBank
from ..m2.lost import LostState
from ..m2.lost_state import anchor_of, guard_fields, lost_of
from ..m2.snapshot_arrays import snapshot_codec
from ..m2.tracking import ParticleCloud
from ..tracker import Box
from .params import ContourParams
from .tracker import ContourSetup, ContourState, restore_model

__all__ = ["ContourSnapshot", "SNAPSHOT_VERSION", "encode", "decode", "snapshot_of", "state_of", "last_of"]

SNAPSHOT_VERSION = 5
_VERSIONS = (1, 2, 3, 4, SNAPSHOT_VERSION)


class LastSummary(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """The last estimate's summary (the filter stage's ``summary()``)."""

    seq: int
    alpha: list[float]
    ess: float
    state: str
    k: int


class BankSnapshot(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """The online appearance exemplars (:class:`gflow_core.m2.appearance_metric.OnlineBank`)."""

    patches: np.ndarray  # (n, th, tw, C) float32
    usage: np.ndarray  # (n,) float64
    frame: np.ndarray  # (n,) int64
    last_add: int


class ContourSnapshot(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """Everything the filter carries from one frame to the next, and the stage's counters (``steps``,
    ``warned``: the profile warning was given, ``last``)."""

    version: int
    initialised: bool
    template: np.ndarray | None  # (P, 2) float64, K = 1 chamfer template; None with a learned model
    alpha: np.ndarray | None  # (N, 4) float64 resampled posterior
    k: np.ndarray | None  # (N,) int64
    log_w: np.ndarray | None  # (N,) float64
    steps: int
    warned: bool
    last: LastSummary | None
    bank: BankSnapshot | None = None  # online appearance exemplars (version 2)
    sigma: np.ndarray | None = None  # (K,) chamfer kernel widths after calibration on frame 0
    app_sigma: np.ndarray | None = None  # (K,) appearance kernel widths after calibration
    lost: tuple[float, float, int, int] | None = None  # lost guard (version 2, not restored): level, var, found, lost_run
    lost_target: tuple[float, float, int] | None = None  # lost guard: moments m1, m2, count of the target's distance
    lost_clutter: tuple[float, float, int] | None = None  # ... and of the clutter's best distance
    lost_runs: tuple[int, int] = (0, 0)  # lost guard: found frames, consecutive lost frames
    held: tuple[float, ...] | None = None  # lost guard: box (x, y, w, h), alpha (4) and k of the last found frame
    anchor: np.ndarray | None = None  # lost guard: (th, tw, 4) channels of the initial box
    judged: tuple[float, str] = (1.0, "tracked")  # confidence and target_state of the last estimate
    anchor_colour: np.ndarray | None = None  # lost guard (version 4): (N_BINS,) colour histogram of the initial box
    lost_ctarget: tuple[float, float, int] = (0.0, 0.0, 0)  # ... moments of the target's colour distance
    lost_cclutter: tuple[float, float, int] = (0.0, 0.0, 0)  # ... and of the clutter's best colour distance
    first: np.ndarray | None = None  # (P, 2) float64 (version 5): the first K = 1 template, T_1 of the drift correction
    template_clock: int = 0  # (version 5) the frame the template update counts its frames from
    first_anchor: np.ndarray | None = None  # (th, tw, 4) float32 (version 5): the lost guard's channels of the first box
    first_fit: tuple[float, int] = (0.0, 0)  # (version 5) sum and count of the first template's rho on the first frames


encode, decode = snapshot_codec(ContourSnapshot)


def snapshot_of(st: ContourState | None, steps: int, warned: bool, last: dict) -> ContourSnapshot:
    """The snapshot of a state (None: not initialised) and the stage's counters."""
    c = st.cloud if st is not None else None
    summary = (LastSummary(seq=int(last["seq"]), alpha=list(last["alpha"]), ess=float(last["ess"]),
                           state=str(last["state"]), k=int(last["k"])) if last else None)
    if st is None or c is None:
        return ContourSnapshot(version=SNAPSHOT_VERSION, initialised=False, template=None, alpha=None, k=None,
                               log_w=None, steps=steps, warned=warned, last=summary,
                               **guard_fields(None, LostState()))
    bank = None if st.bank is None else BankSnapshot(patches=st.bank.patches, usage=st.bank.usage,
                                                     frame=st.bank.frame, last_add=st.bank.last_add)
    return ContourSnapshot(
        version=SNAPSHOT_VERSION, initialised=True, template=st.template, alpha=c.alpha, k=c.k, log_w=c.log_w,
        steps=steps, warned=warned, last=summary, bank=bank,
        sigma=st.model.sigma if st.setup.learned is not None else None,
        app_sigma=st.app.sigma if st.app is not None else None, judged=st.judged, first=st.first,
        template_clock=st.template_clock, first_anchor=st.first_anchor, first_fit=st.first_fit,
        **guard_fields(st.anchor, st.lost))


def last_of(snap: ContourSnapshot) -> dict:
    """The stage's summary of the last estimate in a snapshot ({} before the first)."""
    s = snap.last
    return {"seq": s.seq, "alpha": list(s.alpha), "ess": s.ess, "state": s.state, "k": s.k} if s is not None else {}


def _arrays(snap: ContourSnapshot, setup_: ContourSetup) -> tuple[Any, ...]:
    """(cloud, template, first, first_anchor, bank) of a snapshot, checked."""
    cloud = (ParticleCloud(alpha=snap.alpha, k=snap.k, log_w=snap.log_w)
             if snap.alpha is not None and snap.k is not None and snap.log_w is not None else None)
    first = snap.first if snap.first is not None else snap.template
    if first is not None and (first.ndim != 2 or first.shape[1] != 2 or first.shape[0] < 1):
        raise ValueError(f"bad filter snapshot: first template of shape {first.shape}, not (P, 2)")
    bank = None
    if snap.bank is not None:
        b = snap.bank
        bank = OnlineBank(patches=b.patches, usage=b.usage, frame=b.frame, last_add=b.last_add)
        if setup_.app0 is None or bank.patches.shape[1:] != setup_.app0.patches.shape[1:]:
            raise ValueError("bad filter snapshot: online exemplars that do not fit this model's appearance exemplars")
    return cloud, snap.template, first, snap.first_anchor, bank


def state_of(snap: ContourSnapshot, setup_: ContourSetup, params: ContourParams, init: Box | None
             ) -> ContourState | None:
    """The state of a snapshot of any version this code reads (None: not initialised), for the track
    ``setup_`` and its initial box ``init``. Raises ``ValueError`` naming what does not fit."""
    if snap.version not in _VERSIONS:
        raise ValueError(f"filter snapshot version {snap.version}, expected {SNAPSHOT_VERSION}")
    learned = setup_.learned
    if snap.initialised and (snap.template is None) != (learned is not None):
        raise ValueError("the snapshot was taken " + ("without" if snap.template is not None else "with") +
                         " a learned model, but this stage runs " + ("with" if learned is not None else "without") +
                         " one")
    try:
        cloud, template, first, first_anchor, bank = _arrays(snap, setup_)
    except ValueError as e:
        msg = str(e)
        raise ValueError(msg if msg.startswith("bad filter snapshot") else f"bad filter snapshot: {msg}") from None
    if snap.initialised and cloud is None:
        raise ValueError("filter snapshot is initialised but holds no particles")
    if not snap.initialised or cloud is None:
        return None
    try:
        model, app = restore_model(setup_, params, template, snap.sigma, snap.app_sigma)
    except ValueError as e:
        raise ValueError(f"bad filter snapshot: {e}") from None
    if cloud.k.size and cloud.k.max() >= model.K:
        raise ValueError(f"snapshot particles use exemplar {int(cloud.k.max())} but the model has K={model.K}")
    # a snapshot of the older guard (version 1-2, a level and thresholds) restores with a fresh one
    lost = (LostState() if snap.lost_target is None or snap.lost_clutter is None else
            lost_of(snap.lost_target, snap.lost_clutter, snap.lost_runs, snap.held, snap.lost_ctarget,
                    snap.lost_cclutter))
    anchor = None
    if init is not None:
        try:
            anchor = anchor_of(snap.anchor, snap.anchor_colour if snap.anchor is not None else None,
                               (float(init[2]), float(init[3])))
        except ValueError as e:
            raise ValueError(f"bad filter snapshot: {e}") from None
    if first_anchor is None and template is not None and anchor is not None:
        first_anchor = anchor.channels  # before version 5 the anchor was never taken again
    if first_anchor is not None and (anchor is None or first_anchor.shape != anchor.channels.shape):
        raise ValueError(f"bad filter snapshot: first anchor of shape {first_anchor.shape}, not the anchor's")
    return ContourState(setup_, model, cloud, template=template, app=app, bank=bank, lost=lost, anchor=anchor,
                        judged=(float(snap.judged[0]), str(snap.judged[1])), first=first,
                        template_clock=snap.template_clock, first_anchor=first_anchor,
                        first_fit=(float(snap.first_fit[0]), int(snap.first_fit[1])))
