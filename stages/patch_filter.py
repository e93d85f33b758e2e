"""Filter stage for M2 patch exemplars: the mouth tracker (Toyama & Blake 2002, sec. 5.2).

The images are "largely registered", so tracking runs "with no alpha transformations":
the state is the exemplar index k, the proposal stage samples k_t ~ M[k_{t-1}] and passes
alpha through unchanged, and this stage weighs each particle by eq. 7 with the model's
metric (shuffle or L2),

    log p(y_t | k) = -rho(x~_k, z_t) / (2 sigma_k^2) - d_k log sigma_k,

computing the K distances once per frame (:mod:`gflow_core.m2.patch_tracking`).

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
"""

from __future__ import annotations

from typing import Literal, Mapping

import cv2
import msgspec
import numpy as np

from gflow_core import similarity
from gflow_core.m2.model import M2Model
from gflow_core.m2.patch_tracking import PatchExemplars, init_k, patch_posterior, weigh_patches
from gflow_core.m2.tracking import ParticleCloud

from .base import Output, Params, Stage, StageInputError
from .messages import Estimate, Features, Message, MessageError, NDArray, Particles
from .box_tracker import cloud_of, particles_msg
from .rng import frame_rng

__all__ = ["PatchFilterStage", "PatchFilterParams", "crop_patch"]

PURPOSE_INIT_K = 0x1418
PURPOSE_RESAMPLE = 0x2E5B
SNAPSHOT_VERSION = 1


class PatchFilterParams(Params, frozen=True):
    """Patch filter settings.

    model : path of a learned M2 model with patch exemplars (required).
    init : (x, y, w, h) crop box (``crop: box``); with ``crop: frame`` it is only reported.
    crop : how the observed patch is cut from the frame (see the module docstring).
    particles : number of particles N.
    blank_std : frames whose grey levels have a smaller standard deviation coast.
    """

    model: str = ""
    init: tuple[float, float, float, float] | None = None
    crop: Literal["frame", "box"] = "frame"
    particles: int = 500
    seed: int = 0
    blank_std: float = 1.0

    def __post_init__(self) -> None:
        if self.particles < 1:
            raise ValueError(f"particles must be >= 1, got {self.particles}")
        if self.crop == "box" and self.init is None:
            raise ValueError("crop: box needs the crop box: set init: [x, y, w, h]")
        if self.init is not None and not (self.init[2] > 0 and self.init[3] > 0):
            raise ValueError(f"init box must have positive width and height, got {self.init}")
        if self.blank_std < 0:
            raise ValueError(f"blank_std must be >= 0, got {self.blank_std}")


class _PatchSnapshot(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    version: int
    alpha0: list[float] | None
    box: list[float] | None
    k: NDArray | None  # (N,) int64 resampled posterior
    steps: int
    last_k: int
    last_seq: int


def crop_patch(grey: np.ndarray, shape: tuple[int, int], crop: str,
               box: tuple[float, float, float, float] | None) -> tuple[np.ndarray, np.ndarray]:
    """The observed patch z_t and its crop transform.

    Parameters
    ----------
    grey : (H, W) uint8 grey image.
    shape : (rows, cols) of the model's patches.
    crop : "frame" (whole frame, area-resized) or "box" (``box`` resampled bilinearly).
    box : (x, y, w, h), for ``crop="box"``.

    Returns
    -------
    patch : (rows, cols) float64
    alpha : (4,) float64, (cx, cy, 0, s): patch pixel r maps to image point T_alpha r.
    """
    rows, cols = shape
    H, W = grey.shape
    if crop == "frame":
        g: np.ndarray = grey.astype(np.float32)
        if (rows, cols) != (H, W):
            g = cv2.resize(g, (cols, rows), interpolation=cv2.INTER_AREA)
        s = np.sqrt(H * W / (rows * cols))
        return g.astype(np.float64), np.array([(W - 1) / 2.0, (H - 1) / 2.0, 0.0, s])
    assert box is not None
    x, y, w, h = (float(v) for v in box)
    # s = sqrt(w h / (cols rows)), as in training.patches_from_boxes
    alpha = np.array([x + (w - 1) / 2.0, y + (h - 1) / 2.0, 0.0, np.sqrt(w * h / (cols * rows))])
    return similarity.warp_patch(grey, alpha, (rows, cols)).astype(np.float64), alpha


class PatchFilterStage(Stage[PatchFilterParams]):
    kind = "patch.filter"
    Params = PatchFilterParams
    inputs = {"features": Features, "proposals": Particles}
    outputs = {"particles": Particles, "estimate": Estimate}
    drivers = frozenset({"features"})

    def __init__(self, params: PatchFilterParams, ctx) -> None:
        super().__init__(params, ctx)
        m = ctx.resources.get("model")
        if m is None:
            raise ValueError(f"stage {ctx.name!r}: the patch filter needs a learned model: set model: MODEL.npz")
        if not isinstance(m, M2Model) or m.kind != "patch":
            what = f"an M2 model with {m.metric} contour exemplars" if isinstance(m, M2Model) else type(m).__name__
            raise ValueError(f"stage {ctx.name!r}: model {params.model!r} is {what}; the patch filter needs patch "
                             "exemplars (shuffle or l2)")
        self.m2 = m
        self.model: PatchExemplars = m.to_patch_exemplars()
        self.shape = (int(self.model.patches.shape[1]), int(self.model.patches.shape[2]))
        self.alpha0: np.ndarray | None = None
        self.box: tuple[float, float, float, float] | None = None
        self.k: np.ndarray | None = None
        self.steps = 0
        self.last_k = -1
        self.last_seq = -1

    def required(self, seq: int) -> frozenset[str]:
        return frozenset({"features"}) if self.k is None else frozenset(self.inputs)

    def _observe(self, feat: Features | None, seq: int) -> np.ndarray | None:
        """The observed patch, or None (reported) if the features are unusable."""
        p = self.params
        if feat is None:
            self.report("missing_features", f"frame {seq}: no features arrived; coasting on the dynamics", seq)
            return None
        try:
            grey = feat.grey.array()
        except MessageError as e:
            self.report("bad_features", f"frame {seq}: {e}; coasting", seq)
            return None
        if grey.ndim != 2 or min(grey.shape) < 2:
            self.report("bad_features", f"frame {seq}: grey image has shape {grey.shape}; coasting", seq)
            return None
        z, alpha = crop_patch(grey, self.shape, p.crop, p.init)
        if self.alpha0 is None:
            self.alpha0 = alpha
            H, W = grey.shape
            b = p.init if p.init is not None else (0.0, 0.0, W, H)
            self.box = (float(b[0]), float(b[1]), float(b[2]), float(b[3]))
        return z

    def step(self, seq: int, inputs: Mapping[str, Message | None]) -> list[Output]:
        p = self.params
        feat = inputs.get("features")
        feat = feat if isinstance(feat, Features) else None
        first = self.k is None
        if first:
            if feat is None:
                raise StageInputError(f"frame {seq}: cannot initialise without features")
            z = self._observe(feat, seq)
            if z is None:
                raise StageInputError(f"frame {seq}: cannot initialise on unusable features")
            # k_0 ~ pi
            k = init_k(p.particles, self.model, frame_rng(p.seed, self.ctx.stream, seq, PURPOSE_INIT_K))
        else:
            prop = inputs.get("proposals")
            if isinstance(prop, Particles):
                k = cloud_of(prop).k
            else:
                self.report("missing_proposals", f"frame {seq}: no proposals arrived; reusing the last posterior", seq)
                assert self.k is not None  # not the first frame
                k = self.k
            if k.size and (k.min() < 0 or k.max() >= self.model.K):
                raise StageInputError(f"proposals {seq}: exemplar index outside [0, {self.model.K})")
            z = self._observe(feat, seq)
        if z is None or float(z.std()) < p.blank_std:
            # no evidence (a missing, unusable or blank frame): the posterior is the prior
            log_lik = np.zeros(k.size)
            state = "coast"
        else:
            # log p(y | k) = -rho(x~_k, z) / (2 sigma_k^2) - d_k log sigma_k         (eq. 7)
            log_lik, _ = weigh_patches(k, self.model, z)
            state = "track"
        if first:
            state = "init"
        rng = frame_rng(p.seed, self.ctx.stream, seq, PURPOSE_RESAMPLE)
        post = patch_posterior(k, log_lik, self.model.K, rng, p.particles)
        self.k = post.resampled
        # X^_t = argmax_k p_t(k)                                                    (sec. 5.1.2)
        map_k = int(np.argmax(post.k_hist))
        self.steps += 1
        self.last_k, self.last_seq = map_k, seq
        header = feat.header if feat is not None else self.header(seq, 0)
        assert self.alpha0 is not None and self.box is not None
        alpha = np.tile(self.alpha0, (self.k.size, 1))
        cloud = ParticleCloud(alpha=alpha, k=self.k, log_w=np.zeros(self.k.size))
        a = (float(self.alpha0[0]), float(self.alpha0[1]), float(self.alpha0[2]), float(self.alpha0[3]))
        est = Estimate(header=header, box=self.box, alpha=a, k=map_k, mean=a, std=(0.0, 0.0, 0.0, 0.0),
                       ess=float(post.ess), n=p.particles, log_evidence=float(post.log_evidence),
                       contour=NDArray.of(np.zeros((0, 2), dtype=np.float32)), state=state)
        return [("particles", particles_msg(header, "posterior", cloud)), ("estimate", est)]

    def summary(self) -> dict:
        return {"steps": self.steps, "seq": self.last_seq, "k": self.last_k,
                "training_frame": int(frames[self.last_k]) if self.last_k >= 0 and (frames := self.m2.exemplar_frame)
                is not None else -1}

    def snapshot(self) -> bytes:
        snap = _PatchSnapshot(version=SNAPSHOT_VERSION,
                              alpha0=None if self.alpha0 is None else [float(v) for v in self.alpha0],
                              box=None if self.box is None else list(self.box),
                              k=None if self.k is None else NDArray.of(self.k), steps=self.steps,
                              last_k=self.last_k, last_seq=self.last_seq)
        return msgspec.msgpack.encode(snap)

    def restore(self, data: bytes) -> None:
        name = self.ctx.name
        try:
            snap = msgspec.msgpack.decode(data, type=_PatchSnapshot)
        except msgspec.DecodeError as e:
            raise ValueError(f"stage {name!r}: not a patch.filter snapshot: {e}") from None
        if snap.version != SNAPSHOT_VERSION:
            raise ValueError(f"stage {name!r}: patch filter snapshot version {snap.version}, expected "
                             f"{SNAPSHOT_VERSION}")
        try:
            k = None if snap.k is None else np.asarray(snap.k.array(), dtype=np.int64).copy()
        except MessageError as e:
            raise ValueError(f"stage {name!r}: bad patch filter snapshot: {e}") from None
        if k is not None and k.size and (k.min() < 0 or k.max() >= self.model.K):
            raise ValueError(f"stage {name!r}: snapshot particles use exemplars outside [0, {self.model.K})")
        if (k is None) != (snap.alpha0 is None) or (snap.alpha0 is not None and len(snap.alpha0) != 4):
            raise ValueError(f"stage {name!r}: inconsistent patch filter snapshot")
        self.k = k
        self.alpha0 = None if snap.alpha0 is None else np.array(snap.alpha0, dtype=np.float64)
        self.box = None if snap.box is None else (snap.box[0], snap.box[1], snap.box[2], snap.box[3])
        self.steps, self.last_k, self.last_seq = snap.steps, snap.last_k, snap.last_seq
