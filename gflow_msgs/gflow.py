"""Messages of the G-flow tracker (Marks, Hershey, Roddey & Movellan, NIPS 2004).

Size budget. The experts' background textures are (E, H, W) per mean and variance: with
20 experts at 320x240 that is 24.6 MB per frame in float64, which must not cross a topic
every frame. The filter never reads the background (only the proposals' likelihood,
eq. 13, does), and advancing it needs only the parents, the new poses and the frame
(``gflow_core.gflow.filter.advance_background``). So :class:`ExpertStates` carries poses,
object textures, credibilities and parents (about 20 x (6 + 2 x n) x 8 bytes); each
proposal process keeps a bit-identical replica of the backgrounds. ``bg_mean`` /
``bg_var`` are never filled by the G-flow stages (the proposal stage's own snapshot holds
its replica as distinct tiles, see ``stages/gflow_proposal.py``).
"""

from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

import msgspec
import numpy as np

from .base import ArrayTable, Box, Header, MessageError, NDArray, checked_arrays, packed_arrays

__all__ = ["ExpertStates", "PoseProposals", "PoseEstimate", "EXPERT_ARRAYS", "PROPOSAL_ARRAYS", "states_of",
           "read_states", "proposals_of", "read_proposals", "read_shards", "pose_estimate_of"]


class ExpertStates(msgspec.Struct, frozen=True, tag=True):
    """The G-flow experts after frame ``header.seq`` (sec. 3.3, 3.4).

    poses : (E, P) float64, u_t of each expert (layout: gflow_core.gflow.geometry).
    tex_mean, tex_var : (E, n) float64, object texel posteriors (eq. 7, 8).
    log_credibility : (E,) float64, normalised (eq. 17).
    parents : (E,) int64, the parent of each expert at this frame (identity at the first).
    image_shape : (H, W) of the frames.
    config_digest : digest of the G-flow configuration and model; proposal and filter must agree.
    first : True for the state made from the first frame (the backgrounds start from it).
    bg_mean, bg_var : never filled and never read (the proposal stages keep the backgrounds).
    tex_anchor : (n,) float64, the first frame's texels the texture reverts toward (``texture_decay < 1``).
    """

    header: Header
    poses: NDArray
    tex_mean: NDArray
    tex_var: NDArray
    log_credibility: NDArray
    parents: NDArray
    image_shape: tuple[int, int]
    config_digest: str
    first: bool = False
    bg_mean: NDArray | None = None
    bg_var: NDArray | None = None
    tex_anchor: NDArray | None = None


#: the arrays every :class:`ExpertStates` carries (E experts, pose size P, n vertices)
EXPERT_ARRAYS: ArrayTable = {"poses": (("E", "P"), "float64"), "tex_mean": (("E", "n"), "float64"),
                             "tex_var": (("E", "n"), "float64"), "log_credibility": (("E",), "float64"),
                             "parents": (("E",), "int64")}


class PoseProposals(msgspec.Struct, frozen=True, tag=True):
    """Pose opinions of a shard of experts for frame ``header.seq`` (sec. 3.2, eq. 14-19).

    expert_indices : (E',) int64; u_hat : (E', P); sigma_hat : (E', P, P); samples : (E', s, P);
    log_weights : (E', s) (eq. 16); log_evidence : (E',) (eq. 19); gn_objective : (E',).
    shard / shards : which shard of how many produced it.
    reset : (E',) bool, experts that took the frontal reset (texture restarted from the first look);
        None (an older message) = none did.
    dt : frame periods from the state's frame to this one, the step the proposals were made for
        (a live source skips frames); 1.0 in an older message.
    """

    header: Header
    expert_indices: NDArray
    u_hat: NDArray
    sigma_hat: NDArray
    samples: NDArray
    log_weights: NDArray
    log_evidence: NDArray
    gn_objective: NDArray
    shard: int = 0
    shards: int = 1
    config_digest: str = ""
    reset: NDArray | None = None
    dt: float = 1.0


#: the arrays every :class:`PoseProposals` carries (E' experts of the shard, s samples, pose size P)
PROPOSAL_ARRAYS: ArrayTable = {"expert_indices": (("E'",), "int64"), "u_hat": (("E'", "P"), "float64"),
                               "sigma_hat": (("E'", "P", "P"), "float64"), "samples": (("E'", "s", "P"), "float64"),
                               "log_weights": (("E'", "s"), "float64"), "log_evidence": (("E'",), "float64"),
                               "gn_objective": (("E'",), "float64")}


class PoseEstimate(msgspec.Struct, frozen=True, tag=True):
    """G-flow's answer for one frame.

    box : (x, y, w, h): for a learned face (a model with a reference box), the initial box moved and
        scaled with the face (``gflow_core.gflow.face_pose.following_box``); otherwise the bounding box
        of the projected vertices of the posterior mean pose.
    pose / pose_std : (P,) posterior mean and standard deviation (tangent space).
    rotation : (3, 3) float64 rotation of the mean pose, row-major.
    spread_px : RMS distance of the experts' projected vertices from the mean's.
    ess : effective sample size of the credibilities before resampling.
    expert_points : (E, n, 2) float32, every expert's projected vertices (the paper's fig. 2).
    mean_points : (n, 2) float32.
    log_credibility : (E,) float64; parents : (E,) int64.
    state : "init", "track" or "coast".
    confidence, target_state : as in :class:`gflow_msgs.messages.Estimate`.
    landmarks : (n,) int32, for a learned face the reference landmark index of each vertex (the order of
        ``mean_points``); None for other models.
    yaw_pitch_roll : degrees, of the posterior mean pose (``gflow_core.gflow.face_pose``: yaw > 0 nose toward
        the image's right, pitch > 0 nose up, roll > 0 clockwise in the image).
    expression : (k - 1,) morph coefficients c_2..c_k over c_1, in the model's training standard deviations
        (empty for a rigid model); the raw coefficients are ``pose[5:]``.
    """

    header: Header
    box: Box
    pose: tuple[float, ...]
    pose_std: tuple[float, ...]
    rotation: tuple[float, ...]
    spread_px: float
    ess: float
    expert_points: NDArray
    mean_points: NDArray
    log_credibility: NDArray
    parents: NDArray
    resampled: bool = True
    state: str = "track"
    confidence: float = 1.0
    target_state: str = "tracked"
    landmarks: NDArray | None = None
    yaw_pitch_roll: tuple[float, float, float] = (0.0, 0.0, 0.0)
    expression: tuple[float, ...] = ()


# -- packing and reading: what travels, checked on receipt (a MessageError says what is wrong) ------------------


def states_of(header: Header, experts: Any, parents: np.ndarray, image_shape: tuple[int, int], digest: str,
              first: bool = False) -> ExpertStates:
    """The experts after frame ``header.seq``: ``experts`` has the arrays of :data:`EXPERT_ARRAYS`
    but ``parents`` (given apart, (E,)) as attributes and ``tex_anchor`` (n,) or None
    (``gflow_core.gflow.filter.ExpertState``); never their backgrounds (the proposal stages keep them)."""
    arrays = packed_arrays({k: getattr(experts, k) for k in EXPERT_ARRAYS if k != "parents"} | {"parents": parents},
                           EXPERT_ARRAYS)
    anchor = experts.tex_anchor
    return ExpertStates(header=header, **arrays, image_shape=(int(image_shape[0]), int(image_shape[1])),
                        config_digest=digest, first=bool(first),
                        tex_anchor=None if anchor is None else NDArray.of(np.asarray(anchor, np.float64)))


def read_states(msg: ExpertStates, dims: Mapping[str, int], digest: str | None) -> dict[str, Any]:
    """The arrays of an :class:`ExpertStates` made with the configuration digest ``digest`` (None: not
    checked), with ``dims`` E (experts), P (pose size) and n (vertices): poses (E, P), tex_mean (E, n),
    tex_var (E, n), log_credibility (E,), parents (E,), tex_anchor (n,) or None (``bg_mean`` /
    ``bg_var`` are never read).

    Raises MessageError for another digest or an array of the wrong shape, dtype or with non-finite values."""
    if digest is not None and msg.config_digest != digest:
        raise MessageError(f"the expert states were made with another G-flow configuration, model or seed (digest "
                           f"{msg.config_digest}, this stage has {digest}); give the proposal and filter stages the "
                           f"same parameters")
    out: dict[str, Any] = checked_arrays(msg, EXPERT_ARRAYS, dims)
    out["tex_anchor"] = None if msg.tex_anchor is None else msg.tex_anchor.checked("tex_anchor", (dims["n"],),
                                                                                    "float64")
    return out


def proposals_of(header: Header, props: Any, shard: int, shards: int, digest: str) -> PoseProposals:
    """Pack a shard's proposals (``props`` has the arrays of :data:`PROPOSAL_ARRAYS`, ``reset`` (E',)
    bool and ``dt`` as attributes: ``gflow_core.gflow.Proposals``), or an empty shard when ``props``
    is None (every array without experts)."""
    if props is None:
        empty: dict[str, Any] = packed_arrays({f: np.zeros((0,) * len(shape)) for f, (shape, _) in
                                               PROPOSAL_ARRAYS.items()}, PROPOSAL_ARRAYS)
        return PoseProposals(header=header, **empty, shard=shard, shards=shards, config_digest=digest)
    return PoseProposals(header=header, **packed_arrays({f: getattr(props, f) for f in PROPOSAL_ARRAYS},
                                                        PROPOSAL_ARRAYS),
                         shard=shard, shards=shards, config_digest=digest,
                         reset=NDArray.of(np.asarray(props.reset, dtype=bool)) if props.reset.any() else None,
                         dt=float(props.dt))


def read_proposals(msg: PoseProposals, digest: str, shard: int, shards: int, expected: np.ndarray,
                   dims: Mapping[str, int], max_dt: float) -> dict[str, Any]:
    """The arrays of shard ``shard`` of ``shards``'s proposals, whose experts are ``expected`` (E',), made
    with the digest ``digest``, for pose size P and s samples (``dims``): the arrays of
    :data:`PROPOSAL_ARRAYS`, ``reset`` (E',) bool and ``dt`` in [1, ``max_dt``] frame periods.

    Raises MessageError for another digest or shard, an empty shard (its proposal stage had no usable
    frame or state), a bad ``dt``, other experts, or an array of the wrong shape, dtype or values."""
    if msg.config_digest != digest:
        raise MessageError(f"proposals made with another G-flow configuration, model or seed (digest "
                           f"{msg.config_digest}, the filter has {digest}); give every proposal stage and the "
                           f"filter the same parameters")
    if (msg.shard, msg.shards) != (shard, shards):
        raise MessageError(f"expected shard {shard} of {shards}, got shard {msg.shard} of {msg.shards}; check the "
                           f"proposal stages' shard / shards parameters and the filter's wiring")
    Ep = expected.size
    if Ep and msg.expert_indices.shape == (0,):
        raise MessageError("the proposal stage had no usable frame or expert state for this frame")
    if not (math.isfinite(msg.dt) and 1.0 <= msg.dt <= max_dt):
        raise MessageError(f"dt must be in [1, {max_dt:g}] frame periods, got {msg.dt!r}")
    idx = msg.expert_indices.checked("expert_indices", (Ep,), "int64")
    if not np.array_equal(idx, expected):
        raise MessageError(f"expert indices {idx.tolist()} are not this shard's {expected.tolist()}")
    arrays = checked_arrays(msg, {k: v for k, v in PROPOSAL_ARRAYS.items() if k != "expert_indices"},
                            {"E'": Ep, **dims})
    reset = np.zeros(Ep, dtype=bool) if msg.reset is None else msg.reset.checked("reset", (Ep,), "bool")
    return {"expert_indices": idx, "reset": reset, "dt": float(msg.dt), **arrays}


def read_shards(msgs: Sequence[Any], digest: str, expected: Sequence[np.ndarray], dims: Mapping[str, int],
                max_dt: float) -> tuple[list[dict[str, Any]] | None, tuple[str, str] | None]:
    """The proposals of every shard of a frame, ``msgs[k]`` shard ``k``'s message (None: it did not come),
    each read with :func:`read_proposals` (its experts ``expected[k]``).

    Returns (one :func:`read_proposals` dict a shard, None) or, at the first shard that did not come or
    does not read, (None, (kind, why)): ``missing_proposals`` or ``bad_proposals``."""
    shards, parts = len(msgs), []
    for k, msg in enumerate(msgs):
        if not isinstance(msg, PoseProposals):
            return None, ("missing_proposals", f"no proposals from shard {k} of {shards}")
        try:
            parts.append(read_proposals(msg, digest, k, shards, expected[k], dims, max_dt))
        except MessageError as e:
            return None, ("bad_proposals", f"proposals of shard {k}: {e}")
    return parts, None


def pose_estimate_of(header: Header, est: Any) -> PoseEstimate:
    """The message of G-flow's estimate of a frame (``gflow_core.tracker.Estimate``: ``box``, ``phase``,
    ``confidence``, ``target_state`` and the ``extras`` its tracker documents; points as float32)."""
    x = est.extras
    landmarks = x["landmarks"]
    return PoseEstimate(
        header=header, box=est.box, pose=tuple(float(v) for v in x["pose"]),
        pose_std=tuple(float(v) for v in x["pose_std"]), rotation=tuple(float(v) for v in np.ravel(x["rotation"])),
        spread_px=float(x["spread_px"]), ess=float(x["ess"]),
        expert_points=NDArray.of(np.asarray(x["expert_points"], dtype=np.float32)),
        mean_points=NDArray.of(np.asarray(x["mean_points"], dtype=np.float32)),
        log_credibility=NDArray.of(np.asarray(x["log_credibility"], dtype=np.float64)),
        parents=NDArray.of(np.asarray(x["parents"], dtype=np.int64)), resampled=bool(x["resampled"]),
        state=est.phase, confidence=float(est.confidence), target_state=est.target_state,
        landmarks=None if landmarks is None else NDArray.of(np.asarray(landmarks, dtype=np.int32)),
        yaw_pitch_roll=(float(x["yaw_pitch_roll"][0]), float(x["yaw_pitch_roll"][1]), float(x["yaw_pitch_roll"][2])),
        expression=tuple(float(v) for v in x["expression"]))
