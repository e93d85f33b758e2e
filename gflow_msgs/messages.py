"""Every message that crosses a topic, as msgspec Structs.

Messages are the contract of every stage's ``step()``, so they live at the stage layer;
``pipeline/`` encodes them for zenoh and MCAP, ``gflow_core/`` never sees them.

Rules
-----
* Each message has a :class:`Header`: stream id, sequence number (the frame index) and
  capture time in ns. Inputs are joined by ``seq``, never by arrival time.
* ndarrays travel as :class:`NDArray` (dtype string + shape + raw bytes, C order) and come
  back with ``np.frombuffer``. No pickle anywhere.
* The wire format is MessagePack with a ``type`` tag, so any payload can be decoded
  without knowing its topic (``decode``). Schema evolution follows msgspec's rules: new
  fields get defaults and go at the end; fields are never renamed or retyped.
"""

from __future__ import annotations

import typing
from typing import Any, Union

import msgspec
import numpy as np

__all__ = [
    "Header", "NDArray", "Frame", "Features", "ColourFeatures", "Particles", "Estimate", "ErrorReport", "EndOfStream",
    "StageStatus", "Control", "Snapshot", "Capture", "FOXGLOVE_TYPES", "ExpertStates", "PoseProposals", "PoseEstimate",
    "Message", "MESSAGE_TYPES", "encode", "decode", "decode_as", "json_schema", "MessageError", "estimate_of",
    "particles_msg", "bins_of",
]

from .base import Box, Header, MessageError, NDArray  # noqa: E402  (re-exported)

class Frame(msgspec.Struct, frozen=True, tag=True):
    """One video frame. ``image`` is (H, W, 3) uint8 BGR or (H, W) uint8 grey.

    ``truth`` is the known box (x, y, w, h) of a synthetic scene, else None.
    """

    header: Header
    image: NDArray
    source: str = ""
    truth: Box | None = None


class Features(msgspec.Struct, frozen=True, tag=True):
    """Preprocessed frame: grey (H, W) uint8, Canny edges (H, W) uint8, chamfer image (H, W) float32.

    ``grad_x`` / ``grad_y`` are Sobel gradients (H, W) float32 when the stage is asked for them.
    ``profile`` and ``g0`` say how the chamfer image was made (M2 eq. 4-5).
    """

    header: Header
    grey: NDArray
    edges: NDArray
    chamfer: NDArray
    profile: str
    g0: float
    grad_x: NDArray | None = None
    grad_y: NDArray | None = None


class ColourFeatures(Features, frozen=True, tag=True):
    """:class:`Features` of a colour frame with its colour bins (H, W) uint8
    (:func:`gflow_core.colour.bins`), for the contour trackers' lost guard. A type of its own, not a
    field of :class:`Features`, so features without bins encode as they always did (recordings made
    before re-run bit for bit)."""

    bins: NDArray | None = None

    def bins_array(self, shape: tuple[int, ...]) -> np.ndarray | None:
        """The bins as an (H, W) uint8 array of the grey image's ``shape``; None when not sent.
        Raises :class:`MessageError` naming what is wrong with them."""
        if self.bins is None:
            return None
        try:
            b = self.bins.array()
        except MessageError as e:
            raise MessageError(f"colour bins: {e}") from None
        if b.shape != tuple(shape) or b.dtype != np.uint8:
            raise MessageError(f"colour bins of {b.dtype} {b.shape}, not uint8 {tuple(shape)}")
        return b


def bins_of(feat: Features, shape: tuple[int, ...]) -> tuple[np.ndarray | None, str]:
    """The colour bins a features message carries for a grey image of ``shape`` (:meth:`ColourFeatures.bins_array`;
    None when it carries none: a grey frame, or a recording made before them) and what is wrong with them
    ("" when nothing is; None then)."""
    if not isinstance(feat, ColourFeatures):
        return None, ""
    try:
        return feat.bins_array(shape), ""
    except MessageError as e:
        return None, str(e)


class Particles(msgspec.Struct, frozen=True, tag=True):
    """A particle cloud over X = (alpha, k): alpha (N, 4) float64, k (N,) int64, log_w (N,) float64.

    ``kind`` is ``"proposal"`` (drawn from the dynamics for frame ``seq``) or
    ``"posterior"`` (resampled after weighing frame ``seq``).
    """

    header: Header
    kind: str
    alpha: NDArray
    k: NDArray
    log_w: NDArray


class Estimate(msgspec.Struct, frozen=True, tag=True):
    """The tracker's answer for one frame.

    box : (x, y, w, h) 0-based pixels, top-left corner and size.
    alpha : MAP transform (ux, uy, theta, s); k : MAP exemplar.
    mean / std : posterior mean and standard deviation of alpha.
    ess : effective sample size before resampling; n : number of particles.
    contour : (P, 2) float32 MAP contour in image (x, y) pixels, for drawing.
    state : "init", "track", or "coast" (no hypothesis explained the frame): the filter's
        data path.
    confidence : in [0, 1], how sure the tracker is that ``box`` holds the target.
    target_state : the target as the tracker judges it: ``"tracked"`` (seen in the box),
        ``"occluded"`` (hidden, the box is where it is expected) or ``"lost"`` (being
        searched for).
    """

    header: Header
    box: Box
    alpha: tuple[float, float, float, float]
    k: int
    mean: tuple[float, float, float, float]
    std: tuple[float, float, float, float]
    ess: float
    n: int
    log_evidence: float
    contour: NDArray
    state: str = "track"
    confidence: float = 1.0
    target_state: str = "tracked"


def particles_msg(header: Header, kind: str, cloud: Any) -> Particles:
    """The Particles message of a cloud (``gflow_core.m2.tracking.ParticleCloud``: ``alpha``, ``k``, ``log_w``)."""
    return Particles(header=header, kind=kind, alpha=NDArray.of(cloud.alpha), k=NDArray.of(cloud.k),
                     log_w=NDArray.of(cloud.log_w))


def estimate_of(header: Header, est: Any) -> Estimate:
    """The message of a particle-filter tracker's estimate of a frame (``gflow_core.tracker.Estimate``:
    ``box``, ``phase``, ``confidence``, ``target_state`` and the ``extras`` ``alpha``, ``mean``, ``std``,
    ``ess``, ``n``, ``log_evidence``, and ``k`` and the (P, 2) ``contour`` where the tracker has them;
    without a contour, the box's outline is drawn)."""
    e = est.extras
    if "contour" in e:
        outline = e["contour"]
    else:
        x, y, w, h = est.box
        outline = np.array([[x, y], [x + w, y], [x + w, y + h], [x, y + h]], dtype=np.float32)
    return Estimate(header=header, box=est.box, alpha=e["alpha"], k=e.get("k", 0), mean=e["mean"], std=e["std"],
                    ess=e["ess"], n=e["n"], log_evidence=e["log_evidence"], contour=NDArray.of(outline),
                    state=est.phase, confidence=est.confidence, target_state=est.target_state)


class ErrorReport(msgspec.Struct, frozen=True, tag=True):
    """A stage could not use an input (or failed on it). The stage keeps running."""

    header: Header
    stage: str
    kind: str
    message: str
    topic: str = ""


#: report kinds that are news about a live stream, not errors: its reconnects and its end (a
#: stream ends; counted as errors, a run would never end without one)
NOTICE_KINDS = ("reconnected", "stream_ended", "frames_missed", "damaged_input")


class EndOfStream(msgspec.Struct, frozen=True, tag=True):
    """No message with ``seq >= header.seq`` will follow on this topic."""

    header: Header
    reason: str = "end"


class StageStatus(msgspec.Struct, frozen=True, tag=True):
    """Heartbeat of a stage process: progress, rate, drops, last error, memory, the last frame
    done (``last_seq``; for a source, the frame it announces before sending it), the input
    queue length, the mean compute time of a step, the rejected input messages by kind,
    the frames lost to faults, what it waits for, a source's frame size, and the topics whose
    end of stream the recorder has written."""

    header: Header
    stage: str
    pid: int
    state: str
    steps: int
    fps: float
    dropped: dict[str, int] = {}
    errors: int = 0
    last_error: str = ""
    rss_mb: float = 0.0
    last_seq: int = -1
    queued: int = 0
    busy_ms: float = 0.0
    rejected: dict[str, int] = {}  # input messages not joined, by kind (future_seq, old_seq, bad_array...)
    lost: int = 0  # frames stepped with no input or given up after a fault
    waiting: str = ""  # what the stage waits for, when it waits (for stall reports)
    frame_shape: tuple[int, ...] = ()  # sources: (H, W) of the frames they send
    ended: tuple[str, ...] = ()  # the recorder: topics whose end of stream it has recorded
    captured: int = 0  # a live source: frames decoded since it opened
    skipped: int = 0  # a live source: frames decoded and not sent (the newest frame wins)
    reconnects: int = 0  # a live source: times the stream was lost and reopened
    missed: int = 0  # a live source: frames that never arrived (gaps in the stream's timestamps, reconnects)
    damaged: int = 0  # a live source: frames decoded from damaged data (FFmpeg reported errors)


class Capture(msgspec.Struct, frozen=True, tag=True):
    """A live source's account of one frame it sent, on ``gflow/<stream>/captures``.

    ``header`` is the frame's: ``seq`` its number in the stream (0, 1, 2, ... for the frames
    sent), ``stamp_ns`` the host clock when it was read. ``frame`` is the camera's frame number
    (every frame decoded since the source opened, sent or not); ``skipped`` the frames decoded
    since the previous frame sent and not sent (the newest frame wins); ``gap_s`` the seconds
    without frames when the stream was lost and reopened before this frame (0: no gap);
    ``missed`` the frames that never arrived since the previous frame sent (the camera's frame
    numbers skip them); ``damaged`` whether this frame was decoded from damaged data (FFmpeg
    reported corrupt or undecodable data on it, or on a frame it was predicted from).
    """

    header: Header
    frame: int
    skipped: int = 0
    gap_s: float = 0.0
    missed: int = 0
    damaged: bool = False


class Snapshot(msgspec.Struct, frozen=True, tag=True):
    """A stage's whole internal state after frame ``header.seq`` (``Stage.snapshot()``).

    Restoring it and feeding the inputs of the frames after ``header.seq`` gives the same
    outputs as running from the start; ``gflow rerun --from SEQ`` relies on it.
    """

    header: Header
    stage: str
    kind: str
    data: bytes


class Control(msgspec.Struct, frozen=True, tag=True):
    """Launcher -> stages: ``start`` (all peers are ready) or ``stop``."""

    header: Header
    command: str


from .gflow import ExpertStates, PoseEstimate, PoseProposals  # noqa: E402

Message = Union[Frame, Features, ColourFeatures, Particles, Estimate, ErrorReport, EndOfStream, StageStatus, Control, Snapshot,
                ExpertStates, PoseProposals, PoseEstimate, Capture]
MESSAGE_TYPES: dict[str, type] = {t.__name__: t for t in typing.get_args(Message)}

from .foxglove import FOXGLOVE_SCHEMAS, CompressedImage, ImageAnnotations  # noqa: E402

_encoder = msgspec.msgpack.Encoder()
_json_encoder = msgspec.json.Encoder()
_decoder = msgspec.msgpack.Decoder(Message)
_typed_decoders: dict[type, msgspec.msgpack.Decoder] = {}
FOXGLOVE_TYPES: dict[str, type] = {t.__name__: t for t in FOXGLOVE_SCHEMAS}


def encode(msg: Any) -> bytes:
    """Encode a message: MessagePack (deterministic for equal messages), or JSON for the
    Foxglove well-known schemas, which a viewer decodes without gflow."""
    if type(msg) in FOXGLOVE_SCHEMAS:
        return _json_encoder.encode(msg)
    return _encoder.encode(msg)


def decode(buf: bytes | memoryview) -> Any:
    """Decode any gflow message (or Foxglove JSON message). Raises :class:`MessageError`
    naming what was wrong. gflow's own messages are MessagePack maps, so a payload that
    starts with ``{`` is JSON."""
    if bytes(buf[:1]) == b"{":
        try:
            obj = msgspec.json.decode(buf)
            typ = CompressedImage if isinstance(obj, dict) and "format" in obj else ImageAnnotations
            return msgspec.convert(obj, typ)
        except (msgspec.DecodeError, msgspec.ValidationError) as e:
            raise MessageError(f"malformed JSON message ({len(buf)} bytes): {e}") from None
    try:
        return _decoder.decode(buf)
    except msgspec.DecodeError as e:
        raise MessageError(f"malformed message ({len(buf)} bytes): {e}") from None


def decode_as(buf: bytes | memoryview, typ: type) -> Any:
    """Decode a payload that must be of one message type."""
    dec = _typed_decoders.get(typ)
    if dec is None:
        dec = _typed_decoders[typ] = msgspec.msgpack.Decoder(typ)
    try:
        return dec.decode(buf)
    except msgspec.DecodeError as e:
        raise MessageError(f"malformed {typ.__name__} ({len(buf)} bytes): {e}") from None


def json_schema(typ: type) -> dict[str, Any]:
    """JSON schema of one message type, with its definitions inlined under ``$defs``."""
    schema = msgspec.json.schema(typ)
    ref = schema.get("$ref")
    if ref:  # inline the top-level $ref (Foxglove and other readers want the object itself)
        name = ref.rsplit("/", 1)[-1]
        defs = dict(schema.get("$defs", {}))
        body = dict(defs.pop(name))
        if defs:
            body["$defs"] = defs
        return body
    return schema
