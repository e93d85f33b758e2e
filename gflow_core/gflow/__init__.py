"""G-flow (Marks, Hershey, Roddey & Movellan, NIPS 2004): the mathematics.

Pure numpy / scipy / OpenCV; no I/O. Modules:

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
* :mod:`.special_cases` -- constrained optic flow (eq. 21), template matching (eq. 22).
* :mod:`.synthetic_head` -- synthetic textured-head sequences for tests and benchmarks.
"""

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
