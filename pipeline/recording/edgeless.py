"""Why a frame that was read held no evidence for a contour tracker: a blank frame, or a frame
whose edges the fixed Canny thresholds do not reach.

The contour trackers coast on a frame whose edge map has fewer than ``min_edges`` edge pixels
(M2 sec. 5.1.2: a blank frame). With fixed thresholds (the preprocess stage's ``canny_low`` /
``canny_high``: an m2 model's own, 50/150 in the m2 graph) a dim or low-contrast frame has no edge
at them either, though it is not blank. This module re-reads such frames from the source and
tells the two apart: a frame holds edges when Canny at thresholds chosen from its own gradients
(:func:`gflow_core.features.edge_map` without thresholds, at the stage's ``canny_percentile``)
finds at least ``min_edges`` pixels; a blank (uniform) frame finds none there either. The edges are
read as the tracker read them: with ``match_resolution``, on the frame resampled by ``model_scale``
and counted on the frame's grid (:func:`gflow_core.features.edges_and_chamfer`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import msgspec
import numpy as np

from gflow_core import features
from stages.source import SourceParams

from pipeline.io.frame_readers import open_reader

__all__ = ["EdgelessFrames", "edgeless_frames"]


@dataclass(frozen=True)
class EdgelessFrames:
    """Coasted frames that are not blank: they hold edges, but not at the fixed Canny thresholds."""

    frames: set[int]
    low: float
    high: float
    min_edges: int
    whose: str = "the fixed"  # "the model's" when a learned model's file gave them


def _param(plan: Any, name: str) -> tuple[str, Any] | None:
    """(stage name, value) of the first stage of ``plan`` whose parameters (its own and those of
    the graph's tracker block) have ``name`` set."""
    for sname in plan.stages:
        params = plan.stage_params(sname)
        if params.get(name) is not None:
            return sname, params[name]
    return None


def edgeless_frames(plan: Any, coasted: list[int]) -> EdgelessFrames | None:
    """The frames of ``coasted`` (read, yet without evidence) that hold edges at thresholds chosen
    from their own gradients but fewer than ``min_edges`` at the preprocess stage's fixed ones.

    None when the run had no fixed thresholds (they are then chosen per frame or calibrated, and
    a frame without edges is blank), when the source cannot be read again (a live stream), or
    when no frame of ``coasted`` holds edges.
    """
    pre = next((s.params for s in plan.stages.values() if s.kind == "preprocess"), None)
    src = next((s for s in plan.stages.values() if s.is_source()), None)
    edges = _param(plan, "min_edges")
    if not coasted or pre is None or src is None or edges is None:
        return None
    low, high = pre.get("canny_low"), pre.get("canny_high")
    if low is None or high is None or int(edges[1]) <= 0:
        return None
    try:
        sp = msgspec.convert(src.params, SourceParams)
    except msgspec.ValidationError:
        return None
    if sp.kind not in ("folder", "video", "mcap"):
        return None
    want = set(coasted)
    sp = msgspec.structs.replace(sp, start=max(sp.start, min(want)), stop=max(want) + 1)
    # the resolution the tracker read the edges at: with match_resolution, the frame resampled by model_scale (a
    # fine texture it smooths away is blank there at any thresholds, and was said to be "not blank")
    f = float(pre.get("model_scale") or 1.0) if pre.get("match_resolution") else 1.0
    found: set[int] = set()
    try:
        for raw in open_reader(sp, plan.base_dir):
            if raw.index in want and raw.image is not None:
                grey = features.to_grey(raw.image)
                # the tracker's edge map, but at thresholds chosen from the frame's own gradients
                own, _ = features.edges_and_chamfer(grey, None, float(pre.get("blur", 1.0)),
                                                    float(pre.get("canny_percentile", 80.0)),
                                                    pre.get("profile", "truncated"), float(pre.get("g0", 100.0)), f)
                if int(np.count_nonzero(own)) >= int(edges[1]):
                    found.add(raw.index)
            if raw.index >= max(want):
                break
    except (OSError, ValueError):  # the source moved or changed since the run: say what is known
        return None
    whose = "the model's" if _param(plan, "model") else "the fixed"
    return EdgelessFrames(found, float(low), float(high), int(edges[1]), whose) if found else None
