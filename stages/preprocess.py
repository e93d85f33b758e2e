"""Preprocessing stage: grey levels, gradients, Canny edges, the chamfer image (M2 eq. 4-5) and colour bins.

The edges and the chamfer image are :func:`gflow_core.features.edges_and_chamfer`, with the Canny
thresholds of :func:`gflow_core.features.canny_calibrated` when ``calibrate_box`` is set, on the frame
resampled by ``model_scale`` with ``match_resolution`` (:class:`~gflow_core.contour.params.EdgeParams`):
the observation of the contour trackers' protocol (:mod:`gflow_core.contour.protocol`)."""

from __future__ import annotations

from typing import Mapping

import numpy as np

from gflow_core import colour, features
from gflow_core.contour.params import EdgeParams

from .base import Output, Stage, StageInputError
from gflow_msgs.messages import ColourFeatures, Features, Frame, Message, MessageError, NDArray
from gflow_msgs.snapshots import PreprocessSnapshot
from gflow_msgs.params import StageFields, stage_params, tracker_params

__all__ = ["PreprocessStage", "PreprocessParams", "PreprocessFields"]

SNAPSHOT_VERSION = 1


class PreprocessFields(StageFields, frozen=True):
    """The preprocess stage's own settings, beside the edge settings of
    :class:`~gflow_core.contour.params.EdgeParams` (``profile``, ``g0``, ``canny_low``, ``canny_high``,
    ``canny_percentile``, ``blur``: where their defaults and help live).

    calibrate_box: with ``canny_low`` / ``canny_high`` unset, the Canny thresholds are chosen from the
    gradient magnitude (``canny_percentile``) once, from the pixels of this box in the first frame
    (the tracked target; ``gflow track`` sets it to the initial box), or, with no box, afresh on
    every frame over the whole image.
    gradients: also send the grey image's gradients.
    edges: compute the Canny edges and the chamfer image (default). Off, ``edges`` and
    ``chamfer`` travel as empty arrays: for trackers that read only the grey image (G-flow),
    which saves the distance transform and 450 KB a frame at 320x240 on every hop.
    colour: also send the colour bins (:func:`gflow_core.colour.bins`, one byte a pixel) of a frame
    that has colour (none for a grey frame), for the contour trackers' lost guard.
    """

    calibrate_box: tuple[float, float, float, float] | None = None
    gradients: bool = False
    edges: bool = True
    colour: bool = False

    def box_needs(self) -> tuple[int, str]:
        """The pixels a side the thresholds are calibrated on (:data:`gflow_core.features.MIN_CALIBRATION_SIDE`)
        when they are calibrated on ``calibrate_box``, the initial box."""
        fixed = getattr(self, "canny_low", None) is not None and getattr(self, "canny_high", None) is not None
        if self.edges and self.calibrate_box is not None and not fixed:
            return features.MIN_CALIBRATION_SIDE, "its edges' thresholds are calibrated on the box's pixels"
        return 1, ""


#: the preprocess stage's settings: every field of EdgeParams and those of :class:`PreprocessFields`
#: (not a stage of a tracker: a graph's tracker block does not feed it, its tracker's
#: ``preprocess`` values do, :attr:`gflow_core.spec.TrackerSpec.preprocess`)
PreprocessParams = stage_params("PreprocessParams", EdgeParams, PreprocessFields, __name__, of_tracker=False)


class PreprocessStage(Stage[PreprocessFields]):
    kind = "preprocess"
    Params = PreprocessParams
    inputs = {"frames": Frame}
    outputs = {"features": Features}

    def __init__(self, params: PreprocessFields, ctx) -> None:
        super().__init__(params, ctx)
        self.edge: EdgeParams = tracker_params(params, EdgeParams)
        self.done = 0
        e = self.edge
        self.thresholds: tuple[float, float] | None = (
            (e.canny_low, e.canny_high) if e.canny_low is not None and e.canny_high is not None else None)

    def step(self, seq: int, inputs: Mapping[str, Message | None]) -> list[Output]:
        p, e = self.params, self.edge
        frame = inputs["frames"]
        assert isinstance(frame, Frame)
        try:
            img = frame.image.array()
            grey = features.to_grey(img)
        except (MessageError, ValueError) as err:
            raise StageInputError(f"frame {seq}: {err}") from None
        if not p.edges:  # grey only: edges and chamfer travel empty
            edges, cham = np.zeros(0, np.uint8), np.zeros(0, np.float32)
        else:
            if self.thresholds is None and p.calibrate_box is not None:
                try:
                    self.thresholds = features.canny_calibrated(grey, e.blur, e.canny_percentile, p.calibrate_box)
                except ValueError as err:
                    raise StageInputError(f"frame {seq}: {err}") from None
            # the contour trackers' observation (gflow_core.contour.protocol computes the same)
            edges, cham = features.edges_and_chamfer(grey, self.thresholds, e.blur, e.canny_percentile, e.profile,
                                                     e.g0, e.resample)
        gx = gy = None
        if p.gradients:
            gxa, gya = features.gradients(grey)
            gx, gy = NDArray.of(gxa), NDArray.of(gya)
        self.done += 1
        msg = self._features(header=frame.header, grey=NDArray.of(grey), edges=NDArray.of(edges),
                             chamfer=NDArray.of(cham.astype(np.float32)), profile=e.profile, g0=e.g0,
                             grad_x=gx, grad_y=gy, img=img)
        return [("features", msg)]

    def _features(self, img: np.ndarray, **fields) -> Features:
        """The message: :class:`ColourFeatures` with the frame's colour bins when asked for and the frame
        has colour, else :class:`Features` (a grey frame has no colour)."""
        if self.params.colour and not colour.is_grey(img):
            return ColourFeatures(**fields, bins=NDArray.of(colour.bins(img)))
        return Features(**fields)

    def summary(self) -> dict:
        return {"frames": self.done, "canny_thresholds": self.thresholds}

    snapshot_struct = PreprocessSnapshot
    snapshot_versions = (SNAPSHOT_VERSION,)

    def snapshot_fields(self) -> dict:
        """The thresholds calibrated on the first frame: a restarted stage must not calibrate
        them again on a later frame."""
        th = (float(self.thresholds[0]), float(self.thresholds[1])) if self.thresholds is not None else None
        return {"done": self.done, "thresholds": th}

    def restore_fields(self, snap: PreprocessSnapshot) -> None:
        self.done = snap.done
        self.thresholds = snap.thresholds
