"""The edge settings of M2's contour exemplars, named once.

Contour exemplars are Canny edges (:func:`gflow_core.features.edge_map`) scored by the chamfer
distance with profile g(u) (eq. 4-5). A model is learned with settings (``gflow learn m2 --canny LOW,HIGH
--blur B --profile P --g0 G``) that its file keeps (the profile and g0 in the model, the Canny
thresholds and blur in its meta), and it is tracked with the same ones
(:func:`gflow_core.contour.protocol.m2_edge_params`). These are the defaults of both: what
``gflow learn m2`` and :mod:`.training` use unless told otherwise, and what a model file that names
no thresholds is tracked with. The m2 tracker's registration names them as its preprocess stage's
(:attr:`gflow_core.spec.TrackerSpec.preprocess`), so the ``m2`` graph (``gflow run m2``) reads edges
with them without repeating them; ``gflow track`` sets the stage from the model file.
"""

from __future__ import annotations

from typing import Literal

from ..contour.params import EdgeParams

__all__ = ["CANNY_LOW", "CANNY_HIGH", "BLUR", "PROFILE", "G0", "LEARN_EDGES"]

#: Canny's hysteresis thresholds on the gradient magnitude of the blurred grey image
CANNY_LOW, CANNY_HIGH = 50.0, 150.0
#: std of the Gaussian pre-blur, px
BLUR = 1.0
#: the chamfer profile g(u) = u^2 (eq. 4) and the truncation level of min(u^2, g0), squared px
PROFILE: Literal["quadratic", "truncated"] = "quadratic"
G0 = 100.0

#: the settings above as the contour trackers' :class:`~gflow_core.contour.params.EdgeParams`
LEARN_EDGES = EdgeParams(profile=PROFILE, g0=G0, canny_low=CANNY_LOW, canny_high=CANNY_HIGH, blur=BLUR)
