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

:func:`observation_of` applies them to the arrays a features message carries, read by name, and says
what it could not use: the filter stage's observation of the preprocess stage's message.
"""

from __future__ import annotations

import functools
from typing import Callable

import numpy as np

from .params import ContourParams
from .tracker import ContourObservation, ContourSetup
from ..m2.model import M2Model
from ..m2.tracking import ParticleCloud

__all__ = ["usable_chamfer", "usable_grey", "reads_grey", "is_blank", "same_profile", "profile_problem", "exemplar_error",
           "observation_of"]


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


def profile_problem(model: M2Model, profile: str, g0: float) -> str:
    """What is wrong with chamfer images of ``profile`` (and ``g0``) for ``model`` (:func:`same_profile`;
    "": nothing)."""
    if same_profile(model, profile, g0):
        return ""
    return (f"features use the {profile} chamfer profile (g0 {g0:g}) but the model was learned with {model.profile} "
            f"(g0 {model.g0:g}); sigma_k and d_k do not match these distances (set preprocess.profile / g0)")


def exemplar_error(cloud: ParticleCloud, K: int) -> str:
    """What is wrong with a proposed cloud's exemplar indices for a model of ``K`` exemplars ("": nothing)."""
    if cloud.k.size and cloud.k.max() >= K:
        return f"exemplar index {int(cloud.k.max())} beyond the model's K={K}"
    return ""


def observation_of(params: ContourParams, placed: ContourSetup, read: Callable[[str], np.ndarray],
                   bins: Callable[[tuple[int, ...]], tuple[np.ndarray | None, str]],
                   channels: Callable[[], np.ndarray]) -> tuple[ContourObservation, list[str]]:
    """The filter's observation of a frame's features, by the rules above, and what it could not use.

    Parameters
    ----------
    read : field name (``chamfer``, ``edges``, ``grey``) -> the features' array; ``ValueError`` naming what
        is wrong when it cannot be read.
    bins : (H, W) -> the colour bins for a grey image of that shape (None: not sent) and what is wrong
        with them ("": nothing); asked only when the lost guard weighs colour.
    channels : () -> (H, W, 4) the lost guard's orientation channels of the grey image (computed when
        the observation first asks for them).

    Returns
    -------
    The observation, and each problem as "what was wrong; what the filter does without it": a chamfer
    image it cannot weigh (coasting), a grey image a cue cannot read (chamfer only), colour bins that do
    not fit (edges only).
    """
    problems: list[str] = []

    def usable(field: str, ok: Callable[[np.ndarray], bool], says: Callable[[np.ndarray], str],
               then: str) -> np.ndarray | None:
        try:
            a = read(field)
        except ValueError as e:
            problems.append(f"{e}; {then}")
            return None
        if not ok(a):
            problems.append(f"{says(a)}; {then}")
            return None
        return a

    cham = usable("chamfer", usable_chamfer, lambda c: f"chamfer image is {c.shape} {c.dtype} with non-finite values "
                  "or wrong shape", "coasting")
    try:
        edges: np.ndarray | None = read("edges")
    except ValueError:
        edges = None  # the chamfer image decides whether the frame is usable
    blank = cham is not None and edges is not None and is_blank(params, edges)
    grey = (usable("grey", usable_grey, lambda g: f"grey image has shape {g.shape}", "chamfer only")
            if reads_grey(params, placed) else None)
    b = None
    if grey is not None and reads_colour(params):
        b, problem = bins(grey.shape)
        if problem:
            problems.append(f"{problem}; edges only")
    return ContourObservation(edges=edges, chamfer=cham, blank=blank, grey=grey,
                              channels=functools.cache(channels) if grey is not None else None, bins=b), problems
