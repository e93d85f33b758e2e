"""M2 with a patch model (the mouth tracker, Toyama & Blake 2002, sec. 5.2) on the tracker protocol
of :mod:`gflow_core.tracker`: what the ``patch.filter`` stage drives.

The images are "largely registered", so tracking runs "with no alpha transformations": the state
is the exemplar index k of each particle (:class:`PatchState`); the proposal samples
k_t ~ M[k_{t-1}] (:func:`.patch_tracking.propose_k`; the pipeline's is the proposal stage's,
``stages/particle_proposal.py``) and ``update`` weighs each particle by eq. 7 with the model's metric
(shuffle or L2),

    log p(y_t | k) = -rho(x~_k, z_t) / (2 sigma_k^2) - d_k log sigma_k,

computing the K distances once per frame (:mod:`.patch_tracking`), then resamples.

The observation is the frame's grey image; the patch z_t is cut from it the way the model's
training patches were (``crop``, :func:`crop_patch`): ``frame``, the whole frame resized to the
model's patch shape with area averaging (pre-cropped video such as AVLetters), or ``box``, the
initial box resampled to the patch shape. A frame with (almost) no contrast (grey-level standard
deviation below ``blank_std``), or none, carries no evidence: the posterior is the prior.

Random draws of frame ``t``: k_0 ~ pi from ``stream(PURPOSE_INIT_K)``, the proposal from
``stream(PURPOSE_PROPOSAL)`` (the proposal stage's), the resampling from ``stream(PURPOSE_RESAMPLE)``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping

import cv2
import msgspec
import numpy as np

from .. import similarity
from ..contour.dynamics import PURPOSE_PROPOSAL
from ..features import to_grey
from ..params import make
from ..tracker import Box, Estimate, FrameRng
from .model import M2Model
from .patch_params import PatchParams, crop_of
from .patch_tracking import PatchExemplars, init_k, patch_posterior, propose_k, weigh_patches
from .snapshot_arrays import snapshot_codec

__all__ = ["PatchParams", "PatchState", "PatchTracker", "PATCH", "crop_patch", "crop_of", "patch_setup", "patch_model", "PatchSnapshot",
           "snapshot_of", "state_of", "encode", "decode", "PURPOSE_INIT_K", "PURPOSE_RESAMPLE", "SNAPSHOT_VERSION"]

PURPOSE_INIT_K = 0x1418
PURPOSE_RESAMPLE = 0x2E5B
SNAPSHOT_VERSION = 1


def patch_model(model: Any) -> PatchExemplars:
    """The patch exemplars of a learned model; ``ValueError`` saying what it is instead (no M2 model, or one
    with contour exemplars)."""
    if not isinstance(model, M2Model) or model.kind != "patch":
        what = f"an M2 model with {model.metric} contour exemplars" if isinstance(model, M2Model) else type(model).__name__
        raise ValueError(f"is {what}; the patch filter needs patch exemplars (shuffle or l2)")
    return model.to_patch_exemplars()


def patch_setup(model: M2Model, meta: Mapping[str, Any],
                keywords: Mapping[str, Any]) -> tuple[PatchParams, dict[str, Any]]:
    """The parameters and resources of M2 with the patch model ``model`` (its file's ``meta``): the
    keywords as :class:`PatchParams`, ``crop`` the model's unless given (:func:`crop_of`), and the
    model's :class:`PatchExemplars` as resource ``model``."""
    return make(PatchParams, {"crop": crop_of(meta), **keywords}), {"model": model.to_patch_exemplars()}


@dataclass(frozen=True)
class PatchState:
    """The posterior after a frame: model, the patch exemplars; k : (N,) int64 the resampled
    particles; alpha0 : (4,) the crop transform (cx, cy, 0, s) of the first frame; box : the
    estimate's box (the crop box, or the whole first frame)."""

    model: PatchExemplars
    k: np.ndarray
    alpha0: np.ndarray
    box: Box


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


def _shape(model: PatchExemplars) -> tuple[int, int]:
    return int(model.patches.shape[1]), int(model.patches.shape[2])


class PatchTracker:
    """M2 with a patch model as a :class:`gflow_core.tracker.TrackingFilter` (stateless: everything is
    in :class:`PatchState`); observations are (H, W) grey images, proposals (N,) exemplar indices."""

    name = "m2"
    Params = PatchParams

    def observe(self, params: PatchParams, image: np.ndarray) -> np.ndarray:
        """The grey levels of a ``(H, W, 3)`` BGR or ``(H, W)`` grey frame (``ValueError`` for one
        that is not an image)."""
        return to_grey(image)

    def init(self, params: PatchParams, obs: np.ndarray, box: Box | None, rng: FrameRng,
             resources: Mapping[str, Any]) -> tuple[PatchState, Estimate]:
        """k_0 ~ pi (resource ``model``, the :class:`PatchExemplars`) weighed by the first frame; the
        crop box is ``box`` (required by ``crop: box``; None: the whole frame)."""
        model = resources["model"]
        if not isinstance(model, PatchExemplars):
            raise ValueError(f"the model is a {type(model).__name__}, not patch exemplars")
        _, alpha0 = crop_patch(obs, _shape(model), params.crop, box)
        H, W = obs.shape
        b = box if box is not None else (0.0, 0.0, W, H)
        st = PatchState(model, np.zeros(0, np.int64), alpha0, (float(b[0]), float(b[1]), float(b[2]), float(b[3])))
        # k_0 ~ pi
        k0 = init_k(params.particles, model, rng.stream(PURPOSE_INIT_K))
        return self._weigh(params, st, k0, obs, rng, "init")

    def propose(self, params: PatchParams, state: PatchState, obs: np.ndarray | None, rng: FrameRng,
                dt: float = 1.0) -> np.ndarray:
        """k_t ~ M[k_{t-1}] (:func:`.patch_tracking.propose_k`), from ``rng.stream(PURPOSE_PROPOSAL)``: the
        draws of the pipeline's proposal stage (:func:`gflow_core.contour.dynamics.propose_cloud` with
        alpha fixed), so a step here and one through the stages give the same bits."""
        return propose_k(state.k, state.model, rng.stream(PURPOSE_PROPOSAL))

    def update(self, params: PatchParams, state: PatchState, proposal: np.ndarray, obs: np.ndarray | None,
               rng: FrameRng) -> tuple[PatchState, Estimate]:
        """The proposal weighed by the frame (no evidence when ``obs`` is None or blank) and resampled;
        phase ``track`` or ``coast``."""
        return self._weigh(params, state, proposal, obs, rng, "track")

    def coast(self, params: PatchParams, state: PatchState, rng: FrameRng,
              obs: np.ndarray | None = None) -> tuple[PatchState, Estimate]:
        """Frame ``rng.t`` could not be used: the proposal k_t ~ M[k_{t-1}] weighed by no evidence (phase
        ``coast``), as the filter stage weighs the proposals of a frame whose features never came."""
        return self.update(params, state, self.propose(params, state, None, rng), None, rng)

    def _weigh(self, params: PatchParams, st: PatchState, k: np.ndarray, obs: np.ndarray | None, rng: FrameRng,
               phase: str) -> tuple[PatchState, Estimate]:
        z = None if obs is None else crop_patch(obs, _shape(st.model), params.crop, st.box)[0]
        if z is None or float(z.std()) < params.blank_std:
            # no evidence (a missing, unusable or blank frame): the posterior is the prior
            log_lik = np.zeros(k.size)
            phase = "init" if phase == "init" else "coast"
        else:
            # log p(y | k) = -rho(x~_k, z) / (2 sigma_k^2) - d_k log sigma_k         (eq. 7)
            log_lik, _ = weigh_patches(k, st.model, z)
        post = patch_posterior(k, log_lik, st.model.K, rng.stream(PURPOSE_RESAMPLE), params.particles)
        # X^_t = argmax_k p_t(k)                                                    (sec. 5.1.2)
        map_k = int(np.argmax(post.k_hist))
        a = tuple(float(v) for v in st.alpha0)
        extras = {"alpha": a, "k": map_k, "mean": a, "std": (0.0, 0.0, 0.0, 0.0), "ess": float(post.ess),
                  "n": params.particles, "log_evidence": float(post.log_evidence),
                  "contour": np.zeros((0, 2), dtype=np.float32)}
        st = PatchState(st.model, post.resampled, st.alpha0, st.box)
        return st, Estimate(frame=rng.t, box=st.box, confidence=1.0, target_state="tracked", phase=phase,
                            extras=extras)


#: the one instance (it keeps no state)
PATCH = PatchTracker()


class PatchSnapshot(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """A :class:`PatchState` (None: not initialised) and the filter stage's counters, as one Struct
    (:func:`encode`, :func:`decode`; version 1)."""

    version: int
    alpha0: list[float] | None
    box: list[float] | None
    k: np.ndarray | None  # (N,) int64 resampled posterior
    steps: int
    last_k: int
    last_seq: int


encode, decode = snapshot_codec(PatchSnapshot)


def snapshot_of(st: PatchState | None, steps: int, last_k: int, last_seq: int) -> PatchSnapshot:
    """The snapshot of a state and the stage's counters (the last MAP exemplar and its frame)."""
    return PatchSnapshot(version=SNAPSHOT_VERSION, alpha0=None if st is None else [float(v) for v in st.alpha0],
                         box=None if st is None else list(st.box), k=None if st is None else st.k, steps=steps,
                         last_k=last_k, last_seq=last_seq)


def state_of(snap: PatchSnapshot, model: PatchExemplars) -> PatchState | None:
    """The state of a snapshot (None: not initialised); ``ValueError`` naming what does not fit ``model``."""
    if snap.version != SNAPSHOT_VERSION:
        raise ValueError(f"patch filter snapshot version {snap.version}, expected {SNAPSHOT_VERSION}")
    k = None if snap.k is None else np.asarray(snap.k, dtype=np.int64)
    if k is not None and k.size and (k.min() < 0 or k.max() >= model.K):
        raise ValueError(f"snapshot particles use exemplars outside [0, {model.K})")
    if (k is None) != (snap.alpha0 is None) or (snap.alpha0 is not None and len(snap.alpha0) != 4) \
            or (k is not None and (snap.box is None or len(snap.box) != 4)):
        raise ValueError("inconsistent patch filter snapshot")
    if k is None or snap.alpha0 is None or snap.box is None:
        return None
    b = snap.box
    return PatchState(model, k, np.array(snap.alpha0, dtype=np.float64), (b[0], b[1], b[2], b[3]))
