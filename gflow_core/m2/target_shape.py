"""Fit a learned contour model to the shape of the user's box (departure from Toyama & Blake 2002).

The paper learns exemplars, the reference box and the dynamics from one kind of target
and tracks that kind. A model learned on caviar1's pedestrians (reference box 28 x 73,
aspect 0.38) and placed on a face (46 x 60, aspect 0.77) keeps a pedestrian's shape:
the estimate is a tall box around the face and its overlap with the truth is below 0.5
on almost every frame even when the centre is right, and the appearance regions (the
region of the reference box under alpha, :mod:`.appearance_metric`) are mostly background.

The model is therefore put in a canonical frame and stretched to the user's box: every
item coordinate is scaled by (a_x, a_y) with a_x a_y = 1, chosen so that the reference box
takes the initial box's aspect ratio,

    a_x = sqrt(q_box / q_ref),  a_y = 1 / a_x,   q = w / h.

The area is unchanged, so the scale s of a state alpha (eq. of the similarity transform,
s = sqrt of the box area over the reference area) means what it did: the learned AR(1)
process on log s, the kernels and the Markov matrix are untouched. Exemplar contours x~_k
and the appearance sampling grid go through the same diagonal map, so T_alpha places them
on a box of the user's shape. On the sequence the model was learned on the initial box has
the reference box's shape and the map is close to the identity (caviar1: a_x = 1.02).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .curves import Curves
from .model import M2Model

__all__ = ["aspect_factors", "fit_to_box"]


def aspect_factors(ref_size: np.ndarray, box: tuple[float, float, float, float]) -> np.ndarray:
    """(a_x, a_y), a_x a_y = 1, that give ``ref_size`` (w, h) the aspect ratio of ``box`` (x, y, w, h)."""
    rw, rh = (float(v) for v in ref_size)
    w, h = float(box[2]), float(box[3])
    if not (rw > 0 and rh > 0 and w > 0 and h > 0):
        raise ValueError(f"sizes must be positive, got reference {ref_size} and box {box}")
    ax = float(np.sqrt((w / h) / (rw / rh)))
    return np.array([ax, 1.0 / ax])


def fit_to_box(model: M2Model, box: tuple[float, float, float, float]) -> M2Model:
    """The contour model with its item frame stretched to ``box``'s aspect ratio (module docstring).

    Returns a new M2Model whose exemplar points and ``ref_size`` are scaled by (a_x, a_y);
    the appearance exemplars keep their grid (the grid spans the stretched reference box).
    Patch models (no item frame) are returned unchanged.
    """
    if model.kind != "curve":
        return model
    a = aspect_factors(model.ref_size, box)
    ex = model.exemplars
    assert isinstance(ex, Curves)
    return replace(model, exemplars=Curves(ex.points * a, ex.n_points), ref_size=model.ref_size * a)
