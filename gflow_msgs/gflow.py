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

import msgspec

from .base import ArrayTable, Box, Header, NDArray

__all__ = ["ExpertStates", "PoseProposals", "PoseEstimate", "EXPERT_ARRAYS", "PROPOSAL_ARRAYS"]


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
