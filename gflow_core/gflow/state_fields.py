"""A :class:`.tracker.GFlowState` beyond its experts as flat snapshot fields, and back.

A process that keeps G-flow's posterior between frames and snapshots it (the pipeline's filter
stage) stores the experts as the arrays that travel between processes (:func:`.split.expert_state`
rebuilds them) and the rest as the fields :func:`state_fields` makes: the target's confidence and
state of the last frame with evidence and, when the lost guard runs, its anchor, its state
(:mod:`gflow_core.m2.lost_state`, the names every filter with the guard uses) and the running
moments of the first look's misfit (``fit_level``, ``look_clutter``) and, when the online guard runs, its
model of the face (``online``, ``online_values``: :mod:`.online_fields`). Arrays are numpy arrays; the
caller packs them into its snapshot's format.
"""

from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from ..m2.lost_state import anchor_of, guard_fields, lost_of, moments
from ..visibility import ChiSquare
from .filter import ExpertState
from .online_fields import face_fields, face_of_fields
from .online_guard import OnlineParams
from .tracker import GFlowState, ModelSetup

__all__ = ["STATE_FIELDS", "state_fields", "state_of_fields"]

#: every field :func:`state_fields` can make (the guard's only with an anchor)
STATE_FIELDS = ("confidence", "target_state", "anchor", "anchor_colour", "lost_target", "lost_clutter", "lost_ctarget",
                "lost_cclutter", "lost_runs", "held", "fit_level", "look_clutter", "online", "online_values")


def state_fields(state: GFlowState | None) -> dict[str, Any]:
    """``state``'s confidence and target state (1.0 and "tracked" before the first frame, None) and,
    with a lost guard's anchor, the guard's fields: ``anchor`` (th, tw, 4) and ``anchor_colour``
    (N_BINS,) or None, the moments (m1, m2, n) ``lost_target``, ``lost_clutter``, ``lost_ctarget``,
    ``lost_cclutter``, ``fit_level``, ``look_clutter``, ``lost_runs`` (found, lost run) and ``held``; with
    the online guard's model, ``online`` (N,) float64 and ``online_values`` (:func:`.online_fields.face_fields`)."""
    if state is None:
        return {"confidence": 1.0, "target_state": "tracked"}
    out: dict[str, Any] = {"confidence": state.confidence, "target_state": state.target_state}
    if state.anchor is not None:
        out.update(guard_fields(state.anchor, state.lost), fit_level=moments(state.fit_level),
                   look_clutter=moments(state.look_clutter))
    if state.online is not None:
        out["online"], out["online_values"] = face_fields(state.online)
    return out


def state_of_fields(setup: ModelSetup, experts: ExpertState, fields: Mapping[str, Any],
                    online: OnlineParams | None = None) -> GFlowState:
    """The state of :func:`state_fields`' ``fields`` (arrays copied: the guard updates its anchor in
    place) with ``experts``. Without ``anchor`` (a snapshot made before the guard) the guard is off
    for the rest of the run. With the online guard's settings ``online`` and its model in ``fields``,
    the model restored; without either (the guard off, or a snapshot made before the model was kept)
    none, so the guard starts its model afresh on the next frame.

    Raises ValueError naming what is wrong with the anchor's arrays or the online model's."""
    ch = fields.get("anchor")
    hist = fields.get("anchor_colour") if ch is not None else None
    anchor = anchor_of(None if ch is None else np.array(ch), None if hist is None else np.array(hist),
                       (float(setup.box[2]), float(setup.box[3])))
    confidence, target_state = float(fields["confidence"]), str(fields["target_state"])
    if anchor is None:
        return GFlowState(setup, experts, confidence, target_state)
    lost = lost_of(fields["lost_target"], fields["lost_clutter"], fields["lost_runs"], fields["held"],
                   fields["lost_ctarget"], fields["lost_cclutter"])
    face = None
    if online is not None and fields.get("online") is not None:
        face = face_of_fields(fields["online"], fields.get("online_values") or {}, online)
    return GFlowState(setup, experts, confidence, target_state, anchor, lost, ChiSquare(*fields["fit_level"]),
                      ChiSquare(*fields["look_clutter"]), face)
