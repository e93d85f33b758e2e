"""What the G-flow proposal and filter stages share: parameters, model, digest, message packing.

The two stages (``gflow.proposal``, ``gflow.filter``; Marks, Hershey, Roddey & Movellan,
NIPS 2004) must run the same G-flow configuration, model and seed, or the proposals of
one would be weighed against the textures of another. Both therefore take the same
:class:`GFlowParams` and compute the same :func:`config_digest`, which travels in every
:class:`ExpertStates` and :class:`PoseProposals` message and is checked on receipt.

The model is built the same way in both stages from the parameters and the size of
the first usable frame (:func:`prepare_model`): a user morphable model (the ``model``
resource, placed in the initial box by :func:`pose_for_box`) or the generic ellipsoid
head fitted into the initial box (:func:`fit_head_model_to_box`). An initial box that
sticks out of the frame is clipped to it (and reported); one that misses the frame is an
error.

Random streams (so that shards concatenate to exactly one process's result, and the
pipeline equals :func:`gflow_core.gflow.step` run in a loop):

* expert ``i`` at frame ``t``: ``default_rng([seed, stream_hash, t, i])``
  (:func:`gflow_core.gflow.expert_rngs`), used by the proposal stage;
* the filter's resampling at frame ``t``: ``default_rng([seed, stream_hash, t])``;
* the initial jitter of the experts (filter, first frame only):
  ``frame_rng(seed, stream, t, PURPOSE_INIT)``.
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
from dataclasses import asdict
from typing import Any, Literal, Mapping

import numpy as np

from gflow_core.gflow import COEF, GFlowConfig, MorphableModel, fit_head_model_to_box, pose_for_box
from gflow_core.gflow.image import local_contrast

from .base import Params, StageInputError
from .messages import ExpertStates, Features, Header, MessageError, NDArray, PoseProposals
from .rng import stream_hash

__all__ = [
    "GFlowParams",
    "ModelSetup",
    "PURPOSE_INIT",
    "config_of",
    "config_digest",
    "clip_box",
    "prepare_model",
    "frame_of",
    "states_msg",
    "unpack_states",
    "proposals_msg",
    "unpack_proposals",
    "update_rng",
    "shard_indices",
]

#: ``purpose`` of the filter's first-frame jitter draw (see :func:`stages.rng.frame_rng`).
PURPOSE_INIT = 0x6F10

#: GFlowConfig fields that are parameters of both stages, under the same names.
CONFIG_FIELDS = tuple(GFlowConfig.__dataclass_fields__)


class GFlowParams(Params):
    """G-flow settings shared by ``gflow.proposal`` and ``gflow.filter``; they must be equal
    in both stages (checked through :func:`config_digest`).

    Every field of :class:`gflow_core.gflow.GFlowConfig` is a parameter with the same
    name and default (``n_experts``, ``n_samples``, ``alpha``, ``gn_iterations``,
    ``sigma_w``, ``psi_v``, ``psi_b``, ``v_init_var``, ``b_init_var``, ``unknown_var``,
    ``background``, ``gn_background``, ``object_mask``, ``object_mask_margin``,
    ``prior_std_rotation``, ``prior_std_translation``, ``prior_std_coefficients``,
    ``resample_ess_fraction``, ``prior_rotation_decay``, ``pyramid_levels``, ``search_radius``,
    ``search_step``, ``photometric``, ``photometric_gain_max``, ``max_rotation_deg``, ``search_stride``,
    ``outlier_sigmas``, ``max_scale_change``, ``scale_reference``, ``morph_prior_std``, ``texture_decay``,
    ``reset_rate``, ``reset_std_deg``, ``reset_min_deg``;
    ``scale_reference`` left empty,
    :func:`prepare_model` sets it from the initial pose; ``morph_prior_std``, left empty, set from ``morph_prior``);
    see its docstring for their meaning. Grey levels are in ``[0, 1]``, so variances are in those units squared. Also:

    morph_prior : a learned model's expressions stay near what it was learned from: the stationary factor of the
        pose prior on ``c_2 .. c_k`` has std ``morph_prior * morph_std_j * c_1`` (``morph_std``: the model's training
        spread of ``c_j / c_1``; ``c_1``: the initial scale); ``inf`` = none. Ignored for a model without
        ``morph_std`` (the ellipsoid, k = 1).
    contrast_sigma : pixels; > 0: every frame is local-contrast normalised before G-flow sees it
        (``gflow_core.gflow.image.local_contrast``, a Gaussian neighbourhood of that std), so smooth
        changes of light do not change the texture; 0 = the grey levels themselves (the paper).

    seed : random seed (expert ``i`` of frame ``t`` draws from ``[seed, crc32(stream), t, i]``).
    init : (x, y, w, h) initial box of the face in the first usable frame, 0-based pixels.
    model : path of a morphable model file (``pipeline.io.modelfile``, kind ``morphable``);
        empty: the generic ellipsoid head fitted into ``init``.
    depth_ratio : generic head only, depth semi-axis over width semi-axis.
    head_grid : generic head only, (longitudes, latitudes) of its vertex grid; n = product.
    """

    n_experts: int = 20
    n_samples: int = 10
    alpha: float = 1.0
    gn_iterations: int = 5
    sigma_w: float = 1e-3
    psi_v: float = 1e-4
    psi_b: float = 1e-4
    v_init_var: float = 1e-3
    b_init_var: float = 1e-3
    unknown_var: float = 1.0
    background: bool = False
    gn_background: bool = False
    object_mask: Literal["hull", "vertices"] = "hull"
    object_mask_margin: float = 0.2
    prior_std_rotation: float | tuple[float, ...] = 0.1
    prior_std_translation: float | tuple[float, ...] = 10.0
    prior_std_coefficients: float | tuple[float, ...] = 2.0
    resample_ess_fraction: float = 1.0
    prior_rotation_decay: float = 1.0
    pyramid_levels: int = 1
    search_radius: float = 0.0
    search_step: float = 4.0
    photometric: bool = False
    photometric_gain_max: float = 2.0
    max_rotation_deg: float = math.inf
    search_stride: int = 1
    outlier_sigmas: float = math.inf
    max_scale_change: float = math.inf
    scale_reference: tuple[float, ...] = ()
    morph_prior_std: tuple[float, ...] = ()
    texture_decay: float = 1.0
    reset_rate: float = 0.0
    reset_std_deg: float = 20.0
    reset_min_deg: float = 10.0
    morph_prior: float = math.inf
    contrast_sigma: float = 0.0
    seed: int = 0
    init: tuple[float, float, float, float] | None = None
    model: str = ""
    depth_ratio: float = 1.0
    head_grid: tuple[int, int] = (15, 15)

    def __post_init__(self) -> None:
        config_of(self)  # every GFlowConfig check, at graph validation time
        if self.seed < 0:
            raise ValueError(f"seed must be >= 0, got {self.seed}")
        if self.init is not None:
            if not all(math.isfinite(v) for v in self.init):
                raise ValueError(f"init box has NaN or infinite values: {self.init}")
            if not (self.init[2] > 0 and self.init[3] > 0):
                raise ValueError(f"init box must have positive width and height, got w={self.init[2]}, "
                                 f"h={self.init[3]} in {self.init}")
        if not (math.isfinite(self.depth_ratio) and self.depth_ratio > 0):
            raise ValueError(f"depth_ratio must be positive, got {self.depth_ratio}")
        if not (math.isfinite(self.contrast_sigma) and self.contrast_sigma >= 0):
            raise ValueError(f"contrast_sigma must be finite and >= 0 (0 = off), got {self.contrast_sigma}")
        if math.isnan(self.morph_prior) or self.morph_prior <= 0:
            raise ValueError(f"morph_prior must be > 0 (inf = none), got {self.morph_prior}")
        if min(self.head_grid) < 2:
            raise ValueError(f"head_grid must be at least (2, 2), got {self.head_grid}")


def config_of(p: GFlowParams) -> GFlowConfig:
    """The :class:`GFlowConfig` named by the parameters (raises ValueError if invalid)."""
    return GFlowConfig(**{f: getattr(p, f) for f in CONFIG_FIELDS})


def config_digest(cfg: GFlowConfig, model: MorphableModel, seed: int, contrast_sigma: float = 0.0) -> str:
    """A short digest of everything that must agree between the proposal and the filter:
    the configuration, the model's bases (shape and bytes), the seed and how frames are normalised."""
    h = hashlib.sha256()
    h.update(repr(sorted(asdict(cfg).items())).encode())
    h.update(repr((model.bases.shape, int(seed))).encode())
    if contrast_sigma:
        h.update(repr(("contrast_sigma", float(contrast_sigma))).encode())
    h.update(np.ascontiguousarray(model.bases, dtype="<f8").tobytes())
    return h.hexdigest()[:16]


def clip_box(box: tuple[float, float, float, float], shape: tuple[int, int]) -> tuple[np.ndarray, bool]:
    """The initial box clipped to the image ``[-0.5, W - 0.5] x [-0.5, H - 0.5]``.

    Returns
    -------
    box : (4,) float64, (x, y, w, h)
    clipped : bool, True if the box had to be cut.

    Raises
    ------
    StageInputError
        When less than 1 x 1 pixel of the box lies in the image.
    """
    H, W = shape
    x, y, w, h = (float(v) for v in box)
    x0, y0 = max(x, -0.5), max(y, -0.5)
    x1, y1 = min(x + w, W - 0.5), min(y + h, H - 0.5)
    if x1 - x0 < 1.0 or y1 - y0 < 1.0:
        raise StageInputError(f"initial box (x={x:g}, y={y:g}, w={w:g}, h={h:g}) lies outside the {W}x{H} frame "
                              f"(x must overlap [-0.5, {W - 0.5}] and y [-0.5, {H - 0.5}] by at least a pixel)")
    out = np.array([x0, y0, x1 - x0, y1 - y0])
    return out, bool(not np.allclose(out, [x, y, w, h]))


class ModelSetup:
    """The model, initial pose, configuration and digest of one run, for one frame size.

    Attributes
    ----------
    model : MorphableModel
    pose0 : (P,) float64, initial pose (projected bounding box = the clipped initial box).
    cfg : GFlowConfig
    digest : str
    box : (4,) float64, the initial box actually used (clipped to the frame).
    clipped : bool
    image_shape : (H, W)
    contrast_sigma : float, the frames' local contrast normalisation (0: none).
    """

    def __init__(self, model: MorphableModel, pose0: np.ndarray, cfg: GFlowConfig, digest: str, box: np.ndarray,
                 clipped: bool, image_shape: tuple[int, int], contrast_sigma: float = 0.0) -> None:
        self.model, self.pose0, self.cfg, self.digest = model, pose0, cfg, digest
        self.box, self.clipped, self.image_shape = box, clipped, image_shape
        self.contrast_sigma = contrast_sigma

    def observation(self, grey: np.ndarray) -> np.ndarray:
        """``y_t`` of a grey uint8 frame (:func:`observation`, with this run's ``contrast_sigma``)."""
        return observation(grey, self.contrast_sigma)


def prepare_model(p: GFlowParams, resources: Mapping[str, Any], shape: tuple[int, int]) -> ModelSetup:
    """Build the model and the initial pose for frames of ``shape`` (identically in both stages).

    Raises
    ------
    StageInputError
        No initial box, a box outside the frame, or a model that cannot be placed in it.
    ValueError
        A ``model`` resource that is not a morphable model, or one that does not fit the
        configuration (e.g. ``prior_std_coefficients`` of the wrong length).
    """
    if p.init is None:
        raise StageInputError("G-flow needs an initial box: set init: [x, y, w, h] on the proposal and filter stages")
    box, clipped = clip_box(p.init, shape)
    cfg = config_of(p)
    user = resources.get("model")
    try:
        if user is not None:
            if not isinstance(user, MorphableModel):
                raise ValueError(f"the model file {p.model!r} holds a {type(user).__name__}; G-flow needs a morphable "
                                 f"model (model file kind 'morphable')")
            model = user
            pose0 = pose_for_box(model, box, shape)
        else:
            model, pose0 = fit_head_model_to_box(box, shape, n_lon=p.head_grid[0], n_lat=p.head_grid[1],
                                                 depth_ratio=p.depth_ratio)
        cfg.prior_std(model.n_bases)  # the coefficient stds must match k
        if math.isfinite(cfg.max_scale_change) and not cfg.scale_reference:
            # the scale wall is relative to the initial box's scale
            cfg = dataclasses.replace(cfg, scale_reference=tuple(float(v) for v in pose0[COEF]))
        if (math.isfinite(p.morph_prior) and not cfg.morph_prior_std and model.morph_std is not None
                and model.n_bases > 1):
            # m_j = morph_prior * (training spread of c_j / c_1) * c_1 at the initial box
            m = p.morph_prior * np.maximum(model.morph_std[1:], 1e-9) * abs(float(pose0[COEF][0]))
            cfg = dataclasses.replace(cfg, morph_prior_std=tuple(float(v) for v in m))
        cfg.prior_std(model.n_bases)  # the morph prior's length must match k too
    except ValueError as e:
        raise StageInputError(f"cannot place the G-flow model in the initial box {tuple(box.round(2))}: {e}") from None
    return ModelSetup(model, pose0, cfg, config_digest(cfg, model, p.seed, p.contrast_sigma), box, clipped, shape,
                      p.contrast_sigma)


def frame_of(feat: Features, seq: int, shape: tuple[int, int] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The grey frame of a Features message as ``(uint8 (H, W), float64 (H, W) in [0, 1])``.

    Both stages convert with this function, so they see bit-identical frames.

    Raises
    ------
    StageInputError
        An undecodable array, not a 2-D uint8 image of at least 2 x 2 pixels, a uniform
        image (all black, saturated or any single grey level), or another size than
        ``shape`` (the frames the tracker was initialised on).
    """
    try:
        grey = feat.grey.array()
    except MessageError as e:
        raise StageInputError(f"frame {seq}: grey image: {e}") from None
    if grey.ndim != 2 or grey.dtype != np.uint8 or min(grey.shape) < 2:
        raise StageInputError(f"frame {seq}: grey image must be (H, W) uint8 of at least 2x2 pixels, "
                              f"got {grey.dtype} {grey.shape}")
    lo, hi = int(grey.min()), int(grey.max())
    if lo == hi:
        raise StageInputError(f"frame {seq}: every pixel is {lo} (a blank or saturated frame carries no "
                              f"information about the pose, and would overwrite the textures); frame skipped")
    if shape is not None and grey.shape != tuple(shape):
        raise StageInputError(f"frame {seq}: size {grey.shape[1]}x{grey.shape[0]} differs from the "
                              f"{shape[1]}x{shape[0]} frames the tracker started on; frame skipped")
    # y_t in [0, 1] (grey levels / 255)
    return grey, grey.astype(np.float64) / 255.0


def observation(grey: np.ndarray, contrast_sigma: float = 0.0) -> np.ndarray:
    """What G-flow observes of a grey uint8 frame: grey levels / 255, local-contrast normalised when
    ``contrast_sigma > 0`` (:func:`gflow_core.gflow.image.local_contrast`). Both stages use it."""
    y = grey.astype(np.float64) / 255.0
    return local_contrast(y, contrast_sigma) if contrast_sigma > 0 else y


def update_rng(seed: int, stream: str, t: int) -> np.random.Generator:
    """The filter's generator for frame ``t``: ``default_rng([seed, crc32(stream), t])``
    (the same as :func:`gflow_core.gflow.step`)."""
    return np.random.default_rng([int(seed), stream_hash(stream), int(t)])


# -- messages <-> gflow_core --------------------------------------------------------------


def states_msg(header: Header, poses: np.ndarray, tex_mean: np.ndarray, tex_var: np.ndarray,
               log_credibility: np.ndarray, parents: np.ndarray, image_shape: tuple[int, int], digest: str,
               first: bool, bg_mean: np.ndarray | None = None, bg_var: np.ndarray | None = None,
               tex_anchor: np.ndarray | None = None) -> ExpertStates:
    """Pack the experts after frame ``header.seq`` (backgrounds only for snapshots)."""
    return ExpertStates(
        header=header, poses=NDArray.of(np.asarray(poses, np.float64)),
        tex_mean=NDArray.of(np.asarray(tex_mean, np.float64)), tex_var=NDArray.of(np.asarray(tex_var, np.float64)),
        log_credibility=NDArray.of(np.asarray(log_credibility, np.float64)),
        parents=NDArray.of(np.asarray(parents, np.int64)), image_shape=(int(image_shape[0]), int(image_shape[1])),
        config_digest=digest, first=bool(first),
        bg_mean=None if bg_mean is None else NDArray.of(bg_mean), bg_var=None if bg_var is None else NDArray.of(bg_var),
        tex_anchor=None if tex_anchor is None else NDArray.of(np.asarray(tex_anchor, np.float64)))


def _arr(nd: NDArray, name: str, shape: tuple[int, ...], dtype: str, where: str) -> np.ndarray:
    try:
        a = nd.array()
    except MessageError as e:
        raise StageInputError(f"{where}: {name}: {e}") from None
    if a.shape != shape or a.dtype != np.dtype(dtype):
        raise StageInputError(f"{where}: {name} must be {dtype} {shape}, got {a.dtype} {a.shape}")
    if a.dtype.kind == "f" and not np.isfinite(a).all():
        raise StageInputError(f"{where}: {name} has NaN or infinite values")
    return a


def unpack_states(msg: ExpertStates, setup: ModelSetup, where: str) -> dict[str, np.ndarray]:
    """Validate and unpack an ExpertStates message made for ``setup``.

    Returns
    -------
    dict with poses (E, P), tex_mean (E, n), tex_var (E, n), log_credibility (E,), parents (E,), tex_anchor
    (n,) or None, and bg_mean / bg_var (E, H, W) when the message carries them.

    Raises
    ------
    StageInputError
        Another configuration or model (digest), another frame size, or arrays of the wrong
        shape, dtype or with non-finite values.
    """
    if msg.config_digest != setup.digest:
        raise StageInputError(f"{where}: the expert states were made with another G-flow configuration, model or "
                              f"seed (digest {msg.config_digest}, this stage has {setup.digest}); give the proposal "
                              f"and filter stages the same parameters")
    if tuple(msg.image_shape) != tuple(setup.image_shape):
        raise StageInputError(f"{where}: expert states are for {msg.image_shape} frames, this stage tracks "
                              f"{setup.image_shape}")
    E, P, n = setup.cfg.n_experts, setup.model.pose_size, setup.model.n_vertices
    out = {
        "poses": _arr(msg.poses, "poses", (E, P), "float64", where),
        "tex_mean": _arr(msg.tex_mean, "tex_mean", (E, n), "float64", where),
        "tex_var": _arr(msg.tex_var, "tex_var", (E, n), "float64", where),
        "log_credibility": _arr(msg.log_credibility, "log_credibility", (E,), "float64", where),
        "parents": _arr(msg.parents, "parents", (E,), "int64", where),
    }
    if out["parents"].min() < 0 or out["parents"].max() >= E:
        raise StageInputError(f"{where}: parents must lie in [0, {E})")
    if (msg.tex_anchor is not None) != (setup.cfg.texture_decay != 1.0):
        raise StageInputError(f"{where}: the texture anchor is " + ("missing" if msg.tex_anchor is None else
                              "unexpected") + f" for texture_decay {setup.cfg.texture_decay}")
    out["tex_anchor"] = None if msg.tex_anchor is None else _arr(msg.tex_anchor, "tex_anchor", (n,), "float64", where)
    if msg.bg_mean is not None and msg.bg_var is not None:
        H, W = setup.image_shape
        out["bg_mean"] = _arr(msg.bg_mean, "bg_mean", (E, H, W), "float64", where)
        out["bg_var"] = _arr(msg.bg_var, "bg_var", (E, H, W), "float64", where)
    return out


_PROPOSAL_FIELDS = ("expert_indices", "u_hat", "sigma_hat", "samples", "log_weights", "log_evidence", "gn_objective")


def proposals_msg(header: Header, props, shard: int, shards: int, digest: str) -> PoseProposals:
    """Pack :class:`gflow_core.gflow.Proposals` (or an empty shard when ``props`` is None)."""
    if props is None:
        return PoseProposals(header=header, expert_indices=NDArray.of(np.zeros(0, np.int64)),
                             u_hat=NDArray.of(np.zeros((0, 0))), sigma_hat=NDArray.of(np.zeros((0, 0, 0))),
                             samples=NDArray.of(np.zeros((0, 0, 0))), log_weights=NDArray.of(np.zeros((0, 0))),
                             log_evidence=NDArray.of(np.zeros(0)), gn_objective=NDArray.of(np.zeros(0)),
                             shard=shard, shards=shards, config_digest=digest)
    return PoseProposals(header=header, **{f: NDArray.of(np.asarray(getattr(props, f))) for f in _PROPOSAL_FIELDS},
                         shard=shard, shards=shards, config_digest=digest,
                         reset=NDArray.of(np.asarray(props.reset, dtype=bool)) if props.reset.any() else None)


def unpack_proposals(msg: PoseProposals, setup: ModelSetup, shard: int, shards: int, expected: np.ndarray,
                     where: str):
    """Validate a shard's PoseProposals and return :class:`gflow_core.gflow.Proposals`.

    An empty shard (the proposal stage had no usable frame or state) raises
    StageInputError saying so.
    """
    from gflow_core.gflow import Proposals

    if msg.config_digest != setup.digest:
        raise StageInputError(f"{where}: proposals made with another G-flow configuration, model or seed (digest "
                              f"{msg.config_digest}, the filter has {setup.digest}); give every proposal stage and "
                              f"the filter the same parameters")
    if (msg.shard, msg.shards) != (shard, shards):
        raise StageInputError(f"{where}: expected shard {shard} of {shards}, got shard {msg.shard} of {msg.shards}; "
                              f"check the proposal stages' shard / shards parameters and the filter's wiring")
    Ep = expected.size
    if Ep and msg.expert_indices.shape == (0,):
        raise StageInputError(f"{where}: the proposal stage had no usable frame or expert state for this frame")
    P, s = setup.model.pose_size, setup.cfg.n_samples
    idx = _arr(msg.expert_indices, "expert_indices", (Ep,), "int64", where)
    if not np.array_equal(idx, expected):
        raise StageInputError(f"{where}: expert indices {idx.tolist()} are not this shard's {expected.tolist()}")
    return Proposals(
        expert_indices=idx,
        u_hat=_arr(msg.u_hat, "u_hat", (Ep, P), "float64", where),
        sigma_hat=_arr(msg.sigma_hat, "sigma_hat", (Ep, P, P), "float64", where),
        samples=_arr(msg.samples, "samples", (Ep, s, P), "float64", where),
        log_weights=_arr(msg.log_weights, "log_weights", (Ep, s), "float64", where),
        log_evidence=_arr(msg.log_evidence, "log_evidence", (Ep,), "float64", where),
        gn_objective=_arr(msg.gn_objective, "gn_objective", (Ep,), "float64", where),
        reset=np.zeros(Ep, dtype=bool) if msg.reset is None else _arr(msg.reset, "reset", (Ep,), "bool", where),
    )


def shard_indices(n_experts: int, shard: int, shards: int) -> np.ndarray:
    """The experts of one shard: contiguous blocks of ``range(n_experts)`` (``numpy.array_split``)."""
    return np.array_split(np.arange(n_experts, dtype=np.int64), shards)[shard]
