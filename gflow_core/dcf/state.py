"""What the correlation-filter tracker reads of a frame, proposes, and carries from frame to frame.

All frozen: the tracker's functions return new values and never change their arguments.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..visibility import ChiSquare
from .model import Geometry, TargetModel

__all__ = ["DCFObservation", "DCFProposal", "DCFState"]


@dataclass(frozen=True)
class DCFObservation:
    """A frame as the tracker reads it.

    image : (H, W, 3) BGR uint8 of a colour frame, or (H, W) uint8 of a grey one (single channel, or
    three equal channels: :func:`gflow_core.dcf.features.is_grey`); grey : (H, W) float32 grey levels;
    is_grey : whether the frame holds grey levels only.
    """

    image: np.ndarray
    grey: np.ndarray
    is_grey: bool


@dataclass(frozen=True)
class DCFProposal:
    """The proposal for frame t: particles (N, 3) (x, y, log s) from the proposal's random walk about
    the posterior of the frame before, and ``dt``, the frame periods since that posterior."""

    particles: np.ndarray
    dt: float = 1.0


@dataclass(frozen=True)
class DCFState:
    """The posterior after a frame.

    geom : the filter's window (:class:`.model.Geometry`, a function of the first box's size and the
        parameters); model : the filters, the colour model and the scale filter.
    particles : (N, 3) float64 resampled posterior over (x, y, log s).
    centre : (2,) float64 and log_s : the last estimate (the box is exp(log_s) times the first size).
    velocity : (2,) float64 px / frame.
    target : distribution of the estimate's distance rho = 1 - y (y the response) on frames the target
        was present; clutter : of the best distance away from the estimate (:mod:`gflow_core.visibility`).
    hidden_run : frames in a row that clutter explained the estimate (0: present).
    back : while the target is judged hidden, the filtered probability it was present on the last frame.
    target_state : how the target was judged on the last frame with evidence (what a coasted frame
        reports).
    """

    geom: Geometry
    model: TargetModel
    particles: np.ndarray
    centre: np.ndarray
    log_s: float
    velocity: np.ndarray
    target: ChiSquare
    clutter: ChiSquare
    hidden_run: int = 0
    back: float = 0.0
    target_state: str = "tracked"
