"""Filter stage for M2 patch exemplars: the mouth tracker (Toyama & Blake 2002, sec. 5.2).

A registration of :class:`stages.box_tracker.BoxFilterStage` driving
:data:`gflow_core.m2.patch_protocol.PATCH` (where the mathematics is) on the ``features``' grey image.
The images are "largely registered", so tracking runs "with no alpha transformations":
the state is the exemplar index k, the proposal stage samples k_t ~ M[k_{t-1}] and passes
alpha through unchanged, and the tracker weighs each particle by eq. 7 with the model's
metric (shuffle or L2), computing the K distances once per frame.

The observation z_t is cut from the frame's grey image the way the model's training
patches were (``crop``):

* ``frame``: the whole frame, resized to the model's patch shape with area averaging
  (:func:`gflow_core.m2.training.patches_from_frames`; pre-cropped video such as AVLetters);
* ``box``: the ``init`` box resampled to the patch shape (:func:`training.patches_from_boxes`).

Inputs: ``features`` (its ``grey`` image) and ``proposals``. Outputs: ``particles`` (the
resampled posterior; alpha is the fixed crop transform) and ``estimate``: k is the MAP
exemplar argmax_k p_t(k) (sec. 5.1.2), the box is the crop box, ``contour`` is empty.

A frame with (almost) no contrast (grey-level standard deviation below ``blank_std``,
e.g. a blanked frame) carries no evidence: the particles coast on the Markov dynamics.

State for ``snapshot()`` / ``restore()``: one msgpack encode of
:class:`gflow_core.m2.patch_protocol.PatchSnapshot` (the particles' exemplars, the crop transform
and box, and the counters; version 1).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from gflow_core.m2.model import M2Model
from gflow_core.m2 import patch_protocol as patch
from gflow_core.m2.patch_protocol import PATCH, PatchParams
from gflow_core.m2.patch_tracking import PatchExemplars
from gflow_core.m2.tracking import ParticleCloud
from gflow_core.tracker import Estimate as TrackerEstimate

from .base import StageContext, StageInputError
from .box_tracker import FeaturesFilterStage
from gflow_msgs.messages import Features, Header, Message, MessageError
from gflow_msgs.params import SeedBoxFields, stage_params

__all__ = ["PatchFilterStage", "PatchFilterParams", "PatchFields"]

SNAPSHOT_VERSION = patch.SNAPSHOT_VERSION


class PatchFields(SeedBoxFields, frozen=True):
    """The patch filter's own fields, beside :class:`~gflow_core.m2.patch_params.PatchParams`' (the
    tracker's, named once in the graph's tracker block): the ``seed``, the ``init`` box (the crop box
    with ``crop: box``; with ``crop: frame`` it is only reported), and ``model``, the path of a learned
    M2 model with patch exemplars (required)."""

    model: str = ""

    def check(self, tracker: PatchParams) -> None:
        super().check(tracker)
        if tracker.crop == "box" and self.init is None:
            raise ValueError("crop: box needs the crop box: set init: [x, y, w, h]")


#: the patch filter's settings: every field of PatchParams and those of :class:`PatchFields`
PatchFilterParams = stage_params("PatchFilterParams", PatchParams, PatchFields, __name__)


class PatchFilterStage(FeaturesFilterStage):
    kind = "patch.filter"
    Params = PatchFilterParams
    tracker = PATCH
    needs_init = False

    def __init__(self, params: Any, ctx: StageContext) -> None:
        super().__init__(params, ctx)
        m = self.learned_model()
        try:
            self.model: PatchExemplars = patch.patch_model(m)
        except ValueError as e:
            raise ValueError(f"stage {ctx.name!r}: model {params.model!r} {e}") from None
        self.m2: M2Model = m
        self.resources = {"model": self.model}

    def _features(self, feat: Features, seq: int) -> np.ndarray | None:
        """The frame's grey image, (H, W) with both sides at least 2 pixels, or None (reported): coasting."""
        try:
            g = feat.grey.array()
            problem = "" if g.ndim == 2 and min(g.shape) >= 2 else f"grey image has shape {g.shape}"
        except MessageError as e:
            problem = str(e)
        if problem:
            self.report("bad_features", f"frame {seq}: {problem}; coasting", seq)
            return None
        return g

    def _proposed(self, seq: int, prop: Message | None) -> np.ndarray:
        k: np.ndarray = super()._proposed(seq, prop).k
        if k.size and (k.min() < 0 or k.max() >= self.model.K):
            raise StageInputError(f"proposals {seq}: exemplar index outside [0, {self.model.K})")
        return k

    def _last(self, header: Header, est: TrackerEstimate) -> dict:
        return {"seq": header.seq, "k": int(est.extras["k"])}

    def _posterior(self) -> ParticleCloud:
        st = self.state
        return ParticleCloud(alpha=np.tile(st.alpha0, (st.k.size, 1)), k=st.k, log_w=np.zeros(st.k.size))

    def summary(self) -> dict:
        k, frames = int(self.last.get("k", -1)), self.m2.exemplar_frame
        return {"steps": self.steps, "seq": int(self.last.get("seq", -1)), "k": k,
                "training_frame": int(frames[k]) if k >= 0 and frames is not None else -1}

    def snapshot(self) -> bytes:
        last = self.last
        return patch.encode(patch.snapshot_of(self.state, self.steps, int(last.get("k", -1)), int(last.get("seq", -1))))

    def restore(self, data: bytes) -> None:
        snap = self._restored(data, patch.decode, lambda snap: patch.state_of(snap, self.model))
        self.steps = snap.steps
        self.last = {} if snap.last_seq < 0 and snap.last_k < 0 else {"seq": snap.last_seq, "k": snap.last_k}
