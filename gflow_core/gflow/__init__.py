"""G-flow (Marks, Hershey, Roddey & Movellan, NIPS 2004): the mathematics.

Pure numpy / scipy / OpenCV; no I/O. The names below load their module on first use, so that
reading the parameters (:mod:`.params`, which the command line does at every start) does not
import the mathematics. Modules:

* :mod:`.geometry` -- weak perspective morphable model (eq. 1, 2), pose vector layout,
  tangent-space increments, Jacobians.
* :mod:`.head_model` -- :class:`MorphableModel`, the generic ellipsoid head, box fitting,
  model array (npz) format.
* :mod:`.image` -- frame validation, gradients, bilinear sampling.
* :mod:`.texture` -- diagonal Kalman filters over texels (eq. 7-10).
* :mod:`.pose_opinion` -- eq. 13, 14, 16: Gauss-Newton, Laplace proposal, weights.
* :mod:`.credibility` -- eq. 17, 19, resampling (sec. 3.4), posterior summaries.
* :mod:`.filter` -- :func:`init_state`, :func:`propose`, :func:`update`.
* :mod:`.params` -- :class:`GFlowParams`, the tracker's parameters and their defaults; presets
  :data:`PAPER` and :data:`ELLIPSOID`.
* :mod:`.tracker` -- :class:`GFlowTracker`, G-flow on the protocol of :mod:`gflow_core.tracker`
  (what it reads of a frame, the model placed in the box, the estimate, coasting).
* :mod:`.split` -- G-flow split across processes (the pipeline's stages): the configuration
  digest, the shards, the proposals' background replica.
* :mod:`.special_cases` -- constrained optic flow (eq. 21), template matching (eq. 22).
* :mod:`.synthetic_head` -- synthetic textured-head sequences for tests and benchmarks.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # the names, for type checkers; at run time they load on first use (__getattr__)
    from .filter import (
        Estimate,
        ExpertState,
        GFlowConfig,
        Proposals,
        concatenate_proposals,
        expert_rngs,
        init_state,
        propose,
        step,
        update,
    )
    from .geometry import COEF, N_RIGID, ROT, TRANS, box_minus, box_plus, make_pose, pose_names, pose_size, project
    from .head_model import (
        MODEL_FORMAT_VERSION,
        EllipsoidHead,
        MorphableModel,
        fit_head_model_to_box,
        fit_head_to_box,
        model_from_arrays,
        model_to_arrays,
        pose_for_box,
    )
    from .params import ELLIPSOID, PAPER, GFlowParams, paper_config
    from .tracker import GFlowObservation, GFlowState, GFlowTracker, ModelSetup, model_setup

#: exported name -> the module of this package that defines it
_EXPORTS = {
    "Estimate": "filter",
    "ExpertState": "filter",
    "GFlowConfig": "filter",
    "Proposals": "filter",
    "concatenate_proposals": "filter",
    "expert_rngs": "filter",
    "init_state": "filter",
    "propose": "filter",
    "step": "filter",
    "update": "filter",
    "COEF": "geometry",
    "N_RIGID": "geometry",
    "ROT": "geometry",
    "TRANS": "geometry",
    "box_minus": "geometry",
    "box_plus": "geometry",
    "make_pose": "geometry",
    "pose_names": "geometry",
    "pose_size": "geometry",
    "project": "geometry",
    "MODEL_FORMAT_VERSION": "head_model",
    "EllipsoidHead": "head_model",
    "MorphableModel": "head_model",
    "fit_head_model_to_box": "head_model",
    "fit_head_to_box": "head_model",
    "model_from_arrays": "head_model",
    "model_to_arrays": "head_model",
    "pose_for_box": "head_model",
    "ELLIPSOID": "params",
    "PAPER": "params",
    "GFlowParams": "params",
    "paper_config": "params",
    "GFlowObservation": "tracker",
    "GFlowState": "tracker",
    "GFlowTracker": "tracker",
    "ModelSetup": "tracker",
    "model_setup": "tracker",
}


def __getattr__(name: str) -> Any:
    mod = _EXPORTS.get(name)
    if mod is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{mod}", __name__), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_EXPORTS))


__all__ = [
    "COEF",
    "ELLIPSOID",
    "PAPER",
    "GFlowParams",
    "GFlowObservation",
    "GFlowState",
    "GFlowTracker",
    "ModelSetup",
    "model_setup",
    "paper_config",
    "N_RIGID",
    "ROT",
    "TRANS",
    "MODEL_FORMAT_VERSION",
    "EllipsoidHead",
    "Estimate",
    "ExpertState",
    "GFlowConfig",
    "MorphableModel",
    "Proposals",
    "box_minus",
    "box_plus",
    "concatenate_proposals",
    "expert_rngs",
    "fit_head_model_to_box",
    "fit_head_to_box",
    "init_state",
    "make_pose",
    "model_from_arrays",
    "model_to_arrays",
    "pose_names",
    "pose_for_box",
    "pose_size",
    "project",
    "propose",
    "step",
    "update",
]
