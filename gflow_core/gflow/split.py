"""G-flow split across processes: what the pipeline's proposal and filter stages share and keep.

The pipeline runs G-flow's two steps (:class:`.tracker.GFlowTracker`'s ``propose`` and ``update``)
in separate processes, with the experts split into shards across proposal processes. This module
holds what that split needs beyond the protocol, so that the stages only turn messages into the
arguments of these calls and results into messages:

* :func:`config_digest` -- a digest of everything the proposal and the filter must agree on;
* :func:`placed`, :func:`restored_setup` -- the model placed in the user's box and its digest,
  identically in every process, and again for a snapshot, which must have the same digest;
* :func:`check_shard`, :func:`shard_indices` -- which shards a run may have, and the experts of one;
* :class:`BackgroundReplica` -- the background textures (E, H, W) a proposal process keeps and
  advances itself (eq. 7-10), since they never travel, and its snapshot fields;
* :class:`ProposalShard` -- what a proposal process keeps between frames (the model placed on the
  first usable frame, the replica) and its step: the replica brought to the experts' frame, then
  the pose opinions of its shard of experts;
* :func:`frame_observation`, :func:`filter_observation`, :func:`proposal_observation` -- what each
  process reads of a frame's grey image as it travels, so that every process sees the same bits;
* :func:`message_dims` -- the dimensions of the arrays that travel (E, P, n, s);
* :func:`expert_state` -- the experts rebuilt from the arrays that travel (a message, a snapshot);
* :func:`check_experts` -- what travelling experts must satisfy beyond their arrays' shapes;
* :func:`joined_proposals` -- the pose opinions of every shard for one frame, as one proposal;
* :func:`start_filter`, :func:`restored_state` -- the filter process's posterior at the first frame
  (without backgrounds, which the proposal processes keep) with its digest, and again from the
  arrays and fields of a snapshot.

Nothing here is new mathematics: the replica calls :func:`.filter.initial_background`,
:func:`.filter.advance_background` and :func:`.filter.predict_background`, exactly as the
one-process tracker advances its backgrounds.
"""

from __future__ import annotations

import dataclasses
import hashlib
from dataclasses import asdict, dataclass
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from .background import TileLayout, TiledBackground
from .filter import (ExpertState, Proposals, advance_background, concatenate_proposals, initial_background,
                     predict_background)
from .params import GFlowParams
from .state_fields import state_of_fields
from .tracker import TRACKER, GFlowObservation, GFlowState, ModelSetup, model_setup, online_params
from ..tracker import Estimate, FrameRng, UnusableFrame

__all__ = ["LATER_FIELDS", "config_digest", "placed", "restored_setup", "check_shard", "shard_indices", "message_dims",
           "BackgroundReplica", "ProposalShard", "frame_observation", "filter_observation", "proposal_observation", "expert_state", "check_experts", "joined_proposals", "start_filter",
           "restored_state"]


#: configuration fields added after recordings carried the digest, with the default each had until
#: then: at that default a field is left out of the digest, so every message of a recording made
#: before it (all carry the digest) re-runs bit for bit; set away from it, it enters the digest
LATER_FIELDS: dict[str, Any] = {"texel_noise_adapt": False, "local_background": 0.0, "self_occlusion": 0.0}


def config_digest(setup: ModelSetup, seed: int) -> str:
    """A short digest of everything that must agree between the proposal and the filter: the
    configuration (but :data:`LATER_FIELDS` at their defaults), the model's bases (shape and bytes),
    the seed and how frames are normalised."""
    h = hashlib.sha256()
    cfg = {k: v for k, v in asdict(setup.cfg).items() if k not in LATER_FIELDS or v != LATER_FIELDS[k]}
    h.update(repr(sorted(cfg.items())).encode())
    h.update(repr((setup.model.bases.shape, int(seed))).encode())
    if setup.contrast_sigma:
        h.update(repr(("contrast_sigma", float(setup.contrast_sigma))).encode())
    h.update(np.ascontiguousarray(setup.model.bases, dtype="<f8").tobytes())
    return h.hexdigest()[:16]


def placed(params: GFlowParams, box: Sequence[float], seed: int, shape: tuple[int, int],
           model: Any = None) -> tuple[ModelSetup, str]:
    """The model placed in ``box`` (x, y, w, h) on frames of ``shape`` (H, W)
    (:func:`.tracker.model_setup`; ``model``: a learned morphable model, None: the generic head) and
    its digest (:func:`config_digest` with ``seed``): every process of a run calls this on the same
    first frame and gets the same setup and digest.

    Raises ValueError (:func:`.tracker.model_setup`) when the model cannot be placed in the box."""
    setup = model_setup(params, box, shape, model)
    return setup, config_digest(setup, seed)


def restored_setup(params: GFlowParams, box: Sequence[float], seed: int, shape: tuple[int, int], model: Any,
                   digest: str) -> tuple[ModelSetup, str]:
    """:func:`placed` for a snapshot made on frames of ``shape`` with digest ``digest``.

    Raises ValueError when the model cannot be placed or the digest is another configuration's."""
    setup, mine = placed(params, box, seed, shape, model)
    if mine != digest:
        raise ValueError(f"the snapshot was made with another G-flow configuration, model or seed (digest "
                         f"{digest}, this stage has {mine})")
    return setup, mine


def check_shard(n_experts: int, shard: int, shards: int) -> None:
    """ValueError unless ``1 <= shards <= n_experts`` (no shard without an expert) and
    ``0 <= shard < shards``."""
    if not 1 <= shards <= n_experts:
        raise ValueError(f"shards must be in [1, n_experts={n_experts}], got {shards}")
    if not 0 <= shard < shards:
        raise ValueError(f"shard must be in [0, shards={shards}), got {shard}")


def shard_indices(n_experts: int, shard: int, shards: int) -> np.ndarray:
    """The experts of one shard: contiguous blocks of ``range(n_experts)`` (``numpy.array_split``)."""
    return np.array_split(np.arange(n_experts, dtype=np.int64), shards)[shard]


def frame_observation(params: GFlowParams, grey: Callable[[], np.ndarray]) -> GFlowObservation:
    """What G-flow reads of a frame whose grey image ``grey()`` gives (the preprocess stage's features):
    :meth:`.tracker.GFlowTracker.observe_grey`. Every process reads frames with it, so they see
    bit-identical frames.

    Raises ValueError saying what is wrong: a grey image ``grey()`` cannot read (its ValueError), one
    that is not a 2-D uint8 image of at least 2 x 2 pixels, or a uniform one (all black, saturated or
    any single grey level: the frame is skipped)."""
    try:
        g = grey()
    except ValueError as e:
        raise ValueError(f"grey image: {e}") from None
    try:
        return TRACKER.observe_grey(params, g)
    except UnusableFrame as e:
        raise ValueError(f"{e}; frame skipped") from None


def filter_observation(params: GFlowParams, grey: Callable[[], np.ndarray],
                       bins: Callable[[tuple[int, ...]], tuple[np.ndarray | None, str]]) -> tuple[GFlowObservation, str]:
    """The filter process's observation of a frame (:func:`frame_observation`) with the colour bins
    ``bins((H, W))`` gives (bins or None, what is wrong with them or ""), asked only when the tracker reads
    colour (:meth:`.tracker.GFlowTracker.with_bins`), and the lost guard's orientation channels
    (:meth:`~.tracker.GFlowTracker.with_channels`); and what was wrong with the bins ("": nothing)."""
    obs = frame_observation(params, grey)
    b, problem = bins(obs.grey.shape) if TRACKER.reads_colour(params) else (None, "")
    return TRACKER.with_channels(params, TRACKER.with_bins(params, obs, b)), problem


def proposal_observation(params: GFlowParams, grey: Callable[[], np.ndarray]) -> GFlowObservation:
    """A proposal process's observation of a frame (:func:`frame_observation`) with the pyramid its
    Gauss-Newton reads (:meth:`.tracker.GFlowTracker.with_pyramid`)."""
    return TRACKER.with_pyramid(params, frame_observation(params, grey))


def message_dims(setup: ModelSetup) -> dict[str, int]:
    """The dimensions of the arrays that travel between the processes for ``setup``: ``E`` experts,
    pose size ``P``, ``n`` vertices and ``s`` samples of each expert's pose opinion."""
    return {"E": setup.cfg.n_experts, "P": setup.model.pose_size, "n": setup.model.n_vertices,
            "s": setup.cfg.n_samples}


def expert_state(setup: ModelSetup, arrays: Mapping[str, Any], bg: tuple[Any, Any] | None = None) -> ExpertState:
    """The experts of ``arrays`` (``poses`` (E, P), ``tex_mean`` / ``tex_var`` (E, n), ``log_credibility``
    (E,), ``tex_anchor`` (n,) or None), already checked for shape, as read-only copies, with the
    backgrounds ``bg`` (mean, var) or none."""
    arrs = {k: np.array(arrays[k]) for k in ("poses", "tex_mean", "tex_var", "log_credibility")}
    for v in arrs.values():
        v.setflags(write=False)
    bg_mean, bg_var = (None, None) if bg is None else bg
    return ExpertState(bg_mean=bg_mean, bg_var=bg_var, image_shape=setup.image_shape,
                       tex_anchor=arrays.get("tex_anchor"), **arrs)


def check_experts(setup: ModelSetup, image_shape: tuple[int, int], parents: np.ndarray, has_anchor: bool) -> None:
    """What experts received from another process must satisfy, beyond their arrays' shapes and
    dtypes, to be ``setup``'s: made on frames of ``image_shape`` (H, W) equal to the model's,
    ``parents`` (E,) in ``[0, E)``, and a texture anchor exactly when the texels revert toward it
    (``texture_decay != 1``).

    Raises ValueError saying which does not hold."""
    if tuple(image_shape) != tuple(setup.image_shape):
        raise ValueError(f"expert states are for {image_shape} frames, this stage tracks {setup.image_shape}")
    E = setup.cfg.n_experts
    if parents.min() < 0 or parents.max() >= E:
        raise ValueError(f"parents must lie in [0, {E})")
    if has_anchor != (setup.cfg.texture_decay != 1.0):
        raise ValueError("the texture anchor is " + ("unexpected" if has_anchor else "missing") +
                         f" for texture_decay {setup.cfg.texture_decay}")


def joined_proposals(parts: Sequence[Mapping[str, Any]]) -> Proposals:
    """The proposals of one frame of every shard, each the fields of :class:`.filter.Proposals` (the arrays
    read from a shard's message, its ``dt``), joined in expert order (:func:`.filter.concatenate_proposals`)."""
    return concatenate_proposals([Proposals(**p) for p in parts])


def start_filter(params: GFlowParams, obs: GFlowObservation, box: Sequence[float], seed: int, rng: FrameRng,
                 model: Any = None) -> tuple[GFlowState, Estimate, str]:
    """The filter process's posterior at the first frame (:meth:`.tracker.GFlowTracker.init` keeping no
    backgrounds: the proposal processes start them from this frame), its estimate and the digest
    (:func:`config_digest` with ``seed``) its messages carry.

    Raises ValueError when the model cannot be placed in ``box``."""
    state, est = TRACKER.init(params, obs, (box[0], box[1], box[2], box[3]), rng, {"model": model},
                              backgrounds=False)
    return state, est, config_digest(state.setup, seed)


def restored_state(params: GFlowParams, box: Sequence[float], seed: int, shape: tuple[int, int], model: Any,
                   digest: str, read: Any, fields: Mapping[str, Any]) -> GFlowState:
    """The filter process's posterior of a snapshot made on frames of ``shape`` (H, W) with ``digest``: the
    model placed again (:func:`restored_setup`), the experts of the arrays ``read(setup)`` gives (the
    snapshot's experts read for ``setup``'s dimensions, :func:`message_dims`) and the rest of the state of
    ``fields`` (:func:`.state_fields.state_of_fields`).

    Raises ValueError when the model cannot be placed, the digest is another configuration's or the
    arrays or fields do not fit."""
    setup, _ = restored_setup(params, box, seed, shape, model, digest)
    return state_of_fields(setup, expert_state(setup, read(setup)), fields, online_params(params))


@dataclass(frozen=True)
class BackgroundReplica:
    """A proposal process's copy of every expert's background textures (sec. 3.1, eq. 7-10).

    The likelihood (eq. 13) needs each expert's background texels, (E, H, W) means and variances,
    which never travel: every proposal process keeps all E of them (any expert can be a parent)
    and advances them from the state message (new poses and parents) and the previous frame it
    saw, as the filter would.

    Attributes
    ----------
    bg : (mean, var) of (E, H, W) texels stored once per distinct tile
        (:class:`.background.TiledTexels`), or None (none yet, or lost).
    seq : the frame ``bg`` describes; -1 for none.
    prev_seq : the last usable frame seen; -1 for none.
    prev_grey : (H, W) uint8 of that frame, or None.
    """

    bg: tuple[Any, Any] | None = None
    seq: int = -1
    prev_seq: int = -1
    prev_grey: np.ndarray | None = None

    def seen(self, seq: int, grey: np.ndarray) -> BackgroundReplica:
        """The replica after frame ``seq`` (grey ``(H, W)`` uint8) was seen."""
        return dataclasses.replace(self, prev_seq=seq, prev_grey=grey)

    def advance(self, setup: ModelSetup, seq: int, poses: np.ndarray, parents: np.ndarray,
                first: bool) -> tuple[BackgroundReplica, tuple[str, str] | None]:
        """Bring the backgrounds from frame ``seq - 2`` to ``seq - 1``, the frame of the experts'
        ``poses`` (E, P) and ``parents`` (E,) (``first``: the experts of the first frame).

        Returns the new replica (``bg`` None when it cannot be had: it cannot start without frame
        ``seq - 1``) and a problem to report, ``(kind, text)``, or None. Without ``background`` (the
        likelihood without the background terms) there is nothing to keep: the replica is returned
        as it is.
        """
        if not setup.cfg.background:
            return self, None
        t1 = seq - 1
        prev = setup.observation(self.prev_grey) if self.prev_grey is not None and self.prev_seq == t1 else None
        problem = None
        if first or self.bg is None or self.seq != t1 - 1:
            if prev is None:
                return dataclasses.replace(self, bg=None, seq=-1), (
                    "no_background", f"frame {seq}: the background model cannot start without frame {t1}; "
                                     f"no proposals for this frame")
            if not first:
                problem = ("background_reset", f"frame {seq}: the background replica was at frame {self.seq}, "
                                               f"not {t1 - 1}; restarted from frame {t1}")
            # B_1 = the frame, unknown under each expert's object
            bg = initial_background(setup.model, poses, prev, setup.cfg)
        elif prev is not None:
            # each child: its parent's background predicted (eq. 9, 10) and updated with y_{t-1} (eq. 7, 8)
            bg = advance_background(self.bg[0], self.bg[1], poses, parents, prev, setup.model, setup.cfg)
        else:
            # frame t - 1 was not seen here: prediction only, mu unchanged (eq. 9), sigma + Psi_b (eq. 10)
            bg = predict_background(self.bg[0], self.bg[1], parents, setup.cfg)
        return dataclasses.replace(self, bg=bg, seq=t1), problem

    def ready(self, setup: ModelSetup) -> bool:
        """Whether proposals can be made for ``setup``: it keeps no backgrounds, or they are here."""
        return not setup.cfg.background or self.bg is not None

    def fields(self) -> dict[str, Any]:
        """The replica as flat snapshot fields: ``prev_seq`` and ``prev_grey`` (H, W) uint8 (-1 and None
        before a frame), ``bg_seq``, ``bg_tile`` (the tile side), ``bg_table`` (E, K) int32 tile ids and
        ``bg_mean`` / ``bg_var`` (U, T*T) float64 distinct tiles (-1, 0 and None without backgrounds)."""
        bank = None if self.bg is None else self.bg[0].bank
        return dict(prev_seq=-1 if self.prev_grey is None else self.prev_seq, prev_grey=self.prev_grey,
                    bg_seq=-1 if bank is None else self.seq, bg_tile=0 if bank is None else bank.layout.tile,
                    bg_table=None if bank is None else bank.table, bg_mean=None if bank is None else bank.pool_mean,
                    bg_var=None if bank is None else bank.pool_var)

    @classmethod
    def of_fields(cls, setup: ModelSetup | None, prev_seq: int, prev_grey: np.ndarray | None, bg_seq: int,
                  bg_tile: int, bg_table: np.ndarray | None, bg_mean: np.ndarray | None,
                  bg_var: np.ndarray | None) -> BackgroundReplica:
        """The replica of :meth:`fields` (arrays copied). Raises ValueError when they do not fit ``setup``
        (None: the model was never placed)."""
        bg = None
        if bg_table is not None and bg_mean is not None and bg_var is not None:
            if setup is None:
                raise ValueError("a background replica without a frame size")
            bank = TiledBackground(TileLayout(setup.image_shape, bg_tile), bg_table.astype(np.int32), bg_mean.copy(),
                                   bg_var.copy())
            if bank.n_experts != setup.cfg.n_experts:
                raise ValueError(f"a background replica of {bank.n_experts} experts, this stage has "
                                 f"{setup.cfg.n_experts}")
            bg = (bank.mean, bank.var)
        return cls(bg, bg_seq, prev_seq, None if prev_grey is None else prev_grey.copy())


@dataclass(frozen=True)
class ProposalShard:
    """What a proposal process of G-flow split across processes keeps between frames (sec. 3.2): the
    model placed on the first usable frame (``setup``, its ``digest``, that frame ``init_seq``; None
    before) and the :class:`BackgroundReplica` with the last usable frame it saw. Its methods return a
    new value."""

    setup: ModelSetup | None = None
    digest: str = ""
    init_seq: int | None = None
    replica: BackgroundReplica = BackgroundReplica()

    def started(self, params: GFlowParams, box: Sequence[float], seed: int, seq: int, grey: np.ndarray,
                model: Any = None) -> ProposalShard:
        """The model placed on frame ``seq`` (grey ``(H, W)`` uint8) as the filter places it there
        (:func:`placed`); raises ValueError when it cannot be."""
        setup, digest = placed(params, box, seed, grey.shape, model)
        return ProposalShard(setup, digest, seq, self.replica.seen(seq, grey))

    def seen(self, seq: int, grey: np.ndarray) -> ProposalShard:
        """The shard after frame ``seq`` (grey ``(H, W)`` uint8) was seen (:meth:`BackgroundReplica.seen`)."""
        return dataclasses.replace(self, replica=self.replica.seen(seq, grey))

    def propose(self, params: GFlowParams, seq: int, experts: Mapping[str, Any], first: bool,
                obs: GFlowObservation | None, rng: Any, dt: float,
                indices: np.ndarray) -> tuple[ProposalShard, Proposals | None, list[tuple[str, str]]]:
        """Frame ``seq``'s step: the replica brought to frame ``seq - 1`` with the ``experts`` of that frame
        (the arrays of an expert-state message, checked: ``poses``, ``parents`` ...; ``first``: the first
        frame's), then the pose opinions of the experts ``indices`` (E',) for frame ``seq``
        (:meth:`.tracker.GFlowTracker.propose` with ``rng`` over ``dt`` frame periods), none without the
        frame ``obs`` or the backgrounds the likelihood needs.

        Returns the new shard, the proposals (None: none) and the problems to report, ``(kind, text)``:
        the replica's, and ``propose_failed`` when the proposals could not be made."""
        s = self.setup
        assert s is not None
        replica, problem = self.replica.advance(s, seq, experts["poses"], experts["parents"], first)
        problems = [] if problem is None else [problem]
        out = None
        if obs is not None and replica.ready(s):
            try:
                out = TRACKER.propose(params, GFlowState(s, expert_state(s, experts, replica.bg)), obs, rng, dt, indices)
            except (ValueError, np.linalg.LinAlgError) as e:
                problems.append(("propose_failed", f"frame {seq}: {type(e).__name__}: {e}; no proposals"))
        return dataclasses.replace(self, replica=replica), out, problems

    def fields(self) -> dict[str, Any]:
        """The shard as flat snapshot fields: ``image_shape`` (H, W) (None before the model was placed),
        ``digest``, ``init_seq`` (-1: not placed) and the replica's (:meth:`BackgroundReplica.fields`)."""
        return dict(image_shape=None if self.setup is None else self.setup.image_shape, digest=self.digest,
                    init_seq=-1 if self.init_seq is None else self.init_seq, **self.replica.fields())

    @classmethod
    def of_fields(cls, setup: ModelSetup | None, init_seq: int, digest: str, replica: Mapping[str, Any]
                  ) -> ProposalShard:
        """The shard of :meth:`fields` with the model placed again (``setup``, :func:`restored_setup` of the
        fields' ``image_shape`` and ``digest``; None when it was not placed). Raises ValueError when the
        replica's fields do not fit it."""
        return cls(setup, digest if setup is not None else "", None if init_seq < 0 else init_seq,
                   BackgroundReplica.of_fields(setup, **replica))
