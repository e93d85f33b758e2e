"""Preprocessing stage: grey levels, gradients, Canny edges and the chamfer image (M2 eq. 4-5)."""

from __future__ import annotations

from typing import Literal, Mapping

import numpy as np

from gflow_core import features

from .base import Output, Params, Stage, StageInputError
from .messages import Features, Frame, Message, MessageError, NDArray

__all__ = ["PreprocessStage", "PreprocessParams"]


class PreprocessParams(Params):
    """Edge and chamfer settings. ``profile``: quadratic g(u)=u^2 or truncated min(u^2, g0)."""

    canny_low: float = 50.0
    canny_high: float = 150.0
    blur: float = 1.0
    profile: Literal["quadratic", "truncated", "linear"] = "truncated"
    g0: float = 100.0
    gradients: bool = False


class PreprocessStage(Stage):
    kind = "preprocess"
    Params = PreprocessParams
    inputs = {"frames": Frame}
    outputs = {"features": Features}

    def __init__(self, params: PreprocessParams, ctx) -> None:
        super().__init__(params, ctx)
        self.done = 0

    def step(self, seq: int, inputs: Mapping[str, Message | None]) -> list[Output]:
        p: PreprocessParams = self.params  # type: ignore[assignment]
        frame = inputs["frames"]
        assert isinstance(frame, Frame)
        try:
            img = frame.image.array()
            grey = features.to_grey(img)
        except (MessageError, ValueError) as e:
            raise StageInputError(f"frame {seq}: {e}") from None
        edges = features.edge_map(grey, p.canny_low, p.canny_high, p.blur)
        cham = features.chamfer_image(edges, p.profile, p.g0)
        gx = gy = None
        if p.gradients:
            gxa, gya = features.gradients(grey)
            gx, gy = NDArray.of(gxa), NDArray.of(gya)
        self.done += 1
        msg = Features(header=frame.header, grey=NDArray.of(grey), edges=NDArray.of(edges),
                       chamfer=NDArray.of(cham.astype(np.float32)), profile=p.profile, g0=p.g0,
                       grad_x=gx, grad_y=gy)
        return [("features", msg)]

    def summary(self) -> dict:
        return {"frames": self.done}
