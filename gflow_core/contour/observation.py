"""What the contour filter reads of a frame's features, and what it refuses: one definition of the
rules that both make its observation (:class:`.tracker.ContourObservation`) -- the Python API's
tracker from the frame (:meth:`.protocol.ContourTracker.features`) and the pipeline's filter stage
from the preprocess stage's message (``stages/particle_filter.py``).

* the chamfer image is usable when it is (H, W), not empty and finite (:func:`usable_chamfer`);
  else the frame has no evidence;
* a frame with fewer than ``min_edges`` edge pixels is blank (:func:`is_blank`, M2 sec. 5.1.2);
* the grey image is read only where a cue needs it (:func:`reads_grey`) and used when it is (H, W)
  with both sides at least 3 pixels (:func:`usable_grey`);
* a learned model's sigma_k and d_k hold only for chamfer images of its profile (:func:`same_profile`);
* a proposed exemplar index must lie within the model's K (:func:`exemplar_error`).
"""

from __future__ import annotations

import numpy as np

from .params import ContourParams
from .tracker import ContourSetup
from ..m2.model import M2Model
from ..m2.tracking import ParticleCloud

__all__ = ["usable_chamfer", "usable_grey", "reads_grey", "is_blank", "same_profile", "exemplar_error"]


def usable_chamfer(chamfer: np.ndarray) -> bool:
    """Whether a chamfer image can be weighed: (H, W), not empty, every value finite."""
    return chamfer.ndim == 2 and chamfer.size > 0 and bool(np.isfinite(chamfer).all())


def usable_grey(grey: np.ndarray) -> bool:
    """Whether a grey image can feed the grey-level cues: (H, W) with both sides at least 3 pixels."""
    return grey.ndim == 2 and min(grey.shape) >= 3


def reads_grey(params: ContourParams, placed: ContourSetup) -> bool:
    """Whether a cue reads the frame's grey levels: the lost guard, or a learned model's appearance
    kernels."""
    return params.lost_guard or placed.app0 is not None


def reads_colour(params: ContourParams) -> bool:
    """Whether a cue reads a colour frame's bins: the lost guard, when it weighs colour."""
    return params.lost_guard and params.lost_colour


def is_blank(params: ContourParams, edges: np.ndarray) -> bool:
    """Fewer than ``min_edges`` edge pixels in the (H, W) edge map: a blank frame, no evidence
    (sec. 5.1.2, fig. 7)."""
    return params.min_edges > 0 and int(np.count_nonzero(edges)) < params.min_edges


def same_profile(model: M2Model, profile: str, g0: float) -> bool:
    """Whether chamfer images made with ``profile`` (and ``g0``) are the distances ``model`` was learned
    on, so its sigma_k and d_k hold for them."""
    return profile == model.profile and (model.profile != "truncated" or bool(np.isclose(g0, model.g0)))


def exemplar_error(cloud: ParticleCloud, K: int) -> str:
    """What is wrong with a proposed cloud's exemplar indices for a model of ``K`` exemplars ("": nothing)."""
    if cloud.k.size and cloud.k.max() >= K:
        return f"exemplar index {int(cloud.k.max())} beyond the model's K={K}"
    return ""
