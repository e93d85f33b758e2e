"""Render stage: the frame and the tracker's state as Foxglove well-known messages.

Outputs, for every frame that has an estimate:

* ``image``: ``foxglove.CompressedImage`` (JPEG of the frame);
* ``annotations``: ``foxglove.ImageAnnotations``, the estimate's overlays
  (:func:`gflow_msgs.annotations.annotations_for`: the box coloured by the target's state, the
  ground truth, the particles or G-flow's experts, the contour or mesh, a status line).

The same annotations are drawn into videos by ``gflow render``.
"""

from __future__ import annotations

from typing import Literal, Mapping

import cv2

from .base import Output, Params, Stage, StageInputError
from gflow_msgs.annotations import annotations_for
from gflow_msgs.messages import Estimate, Frame, Message, MessageError, Particles, PoseEstimate
from gflow_msgs.foxglove import CompressedImage, ImageAnnotations, time_of

__all__ = ["RenderStage", "RenderParams"]


class RenderParams(Params, frozen=True):
    """estimate: which estimate type the tracker publishes (``particle`` for chamfer / M2,
    ``gflow`` for G-flow). particles: also draw the posterior particles (chamfer / M2).
    max_points: at most this many particles or expert points drawn per frame.
    jpeg_quality: 1-100."""

    estimate: Literal["particle", "gflow"] = "particle"
    particles: bool = False
    max_points: int = 400
    jpeg_quality: int = 85

    def __post_init__(self) -> None:
        if not 1 <= self.jpeg_quality <= 100:
            raise ValueError(f"jpeg_quality must be in 1..100, got {self.jpeg_quality}")
        if self.max_points < 0:
            raise ValueError("max_points must be >= 0")


class RenderStage(Stage[RenderParams]):
    kind = "render"
    Params = RenderParams
    inputs = {"frames": Frame, "estimate": Estimate}
    outputs = {"image": CompressedImage, "annotations": ImageAnnotations}

    @classmethod
    def ports(cls, params: RenderParams) -> tuple[Mapping[str, type], Mapping[str, type]]:
        ins: dict[str, type] = {"frames": Frame, "estimate": PoseEstimate if params.estimate == "gflow" else Estimate}
        if params.particles:
            ins["particles"] = Particles
        return ins, cls.outputs

    def __init__(self, params: RenderParams, ctx) -> None:
        super().__init__(params, ctx)
        self.drawn = 0

    def step(self, seq: int, inputs: Mapping[str, Message | None]) -> list[Output]:
        p = self.params
        frame, est = inputs.get("frames"), inputs.get("estimate")
        if not isinstance(frame, Frame) or not isinstance(est, (Estimate, PoseEstimate)):
            return []  # nothing to draw for this frame (the frame or the estimate was lost)
        try:
            img = frame.image.array()
        except MessageError as e:
            raise StageInputError(f"frame {seq}: {e}") from None
        ok, jpg = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, p.jpeg_quality])
        if not ok:
            raise StageInputError(f"frame {seq}: OpenCV could not encode a {img.shape} image as JPEG")
        part = inputs.get("particles") if p.particles else None
        ann = annotations_for(frame, est, part if isinstance(part, Particles) else None, p.max_points)
        self.drawn += 1
        image = CompressedImage(time_of(frame.header.stamp_ns), "camera", jpg.tobytes(), "jpeg")
        return [("image", image), ("annotations", ann)]

    def summary(self) -> dict:
        return {"drawn": self.drawn}
