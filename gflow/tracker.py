"""``gflow.Tracker``: one target through frames you hand it, as OpenCV's trackers take them."""

from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np

from gflow_core.tracker import Box, Estimate

from gflow_core import registry
from gflow_core.spec import SpecError

from .backends import ProtocolBackend, protocol_tracker
from .errors import GflowError

__all__ = ["Tracker", "TRACKERS", "trackers"]


def trackers() -> tuple[str, ...]:
    """The trackers' names, as ``gflow track --tracker NAME`` names them: the built-in ones and those
    other packages register (entry-point group ``gflow.trackers``, :mod:`gflow_core.registry`)."""
    return tuple(registry.names())


def __getattr__(name: str) -> Any:
    """``TRACKERS``: :func:`trackers`, read from the registry each time it is asked for (a tracker
    another package registers is in it)."""
    if name == "TRACKERS":
        return trackers()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def check_box(box: Sequence[float]) -> Box:
    """``(x, y, w, h)``: four finite numbers with ``w, h > 0`` (``gflow track --init``'s rules)."""
    try:
        vals = tuple(float(v) for v in box)
    except (TypeError, ValueError):
        raise GflowError(f"expected X,Y,W,H numbers, got {box!r}") from None
    if len(vals) != 4:
        raise GflowError(f"expected 4 numbers X,Y,W,H, got {len(vals)}")
    if not all(math.isfinite(v) for v in vals):
        raise GflowError("box has NaN or inf")
    if vals[2] <= 0 or vals[3] <= 0:
        raise GflowError(f"box width and height must be positive, got W={vals[2]}, H={vals[3]}")
    return vals[0], vals[1], vals[2], vals[3]


class Tracker:
    """A tracker you hand frames to: ``init(frame, box)`` on the first, then ``update(frame)`` on
    each next one, each returning an :class:`~gflow_core.tracker.Estimate`.

    Parameters
    ----------
    name : {"appearance", "chamfer", "dcf", "gflow", "m2"} or a registered tracker
        The tracker (``docs/trackers.md``); ``dcf`` is ``gflow track``'s default. Another package's
        tracker registered under the entry-point group ``gflow.trackers`` is named the same way
        (``docs/own_tracker.md``); its keywords are its parameter dataclass's.
    seed : int >= 0
        Frame ``t`` draws from ``default_rng([seed, crc32("cam0"), t, ...])``, as every stage of the
        shipped graphs does: the same seed gives the boxes of ``gflow track --seed SEED`` bit for bit.
    **params
        For ``appearance``, any parameter of :class:`gflow_core.appearance.params.AppearanceParams`
        (``gflow info appearance``; its presets: ``Tracker("appearance", **TRACK_SCALE)``). For ``dcf``,
        any parameter of :class:`gflow_core.dcf.params.DCFParams` (``gflow info dcf``). For
        ``gflow``, any parameter of :class:`gflow_core.gflow.GFlowParams` (``gflow info gflow``)
        and ``model`` (``face``, ``ellipsoid``, a model file or a ``MorphableModel``). For
        ``chamfer``, any parameter of :class:`gflow_core.contour.params.ChamferParams` (``gflow info
        chamfer``); for ``m2``, any of :class:`gflow_core.contour.params.M2Params` and ``model`` (a
        file of ``gflow learn m2`` or an ``M2Model``); with a patch model (shuffle or L2 exemplars),
        any of :class:`gflow_core.m2.patch_protocol.PatchParams` and ``model``.

    Frames are numpy arrays as OpenCV gives them: ``(H, W, 3)`` BGR or ``(H, W)`` grey, uint8; every
    frame the size of the first. Frame indices count from ``init``'s ``frame_index`` (0).

    Raises
    ------
    GflowError (a ValueError)
        A bad value, box or frame, with the one-line message ``gflow track`` prints.
    UnknownParameter (a TypeError)
        A parameter the tracker does not have.
    """

    def __init__(self, name: str = "dcf", seed: int = 1, **params: Any) -> None:
        try:
            registry.get(name)
        except SpecError as e:
            raise GflowError(str(e)) from None
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
            raise GflowError(f"seed must be an integer >= 0, got {seed!r}")
        self.name, self.seed = name, int(seed)
        try:
            impl, p, resources = protocol_tracker(name, params)
        except ValueError as e:
            raise GflowError(str(e)) from None
        self._backend = ProtocolBackend(impl, p, resources, self.seed, "cam0")
        self._shape: tuple[int, ...] | None = None
        self._t = -1

    @property
    def params(self) -> Any:
        """The tracker's parameter dataclass (m2: ``M2Params`` or, with a patch model, ``PatchParams``)."""
        return self._backend.params

    @property
    def state(self) -> Any:
        """The posterior after the last frame (None before ``init``)."""
        return self._backend.state

    @property
    def frame_index(self) -> int:
        """The index of the last frame tracked (-1 before ``init``)."""
        return self._t

    @property
    def problems(self) -> list[tuple[int, str]]:
        """``(frame, message)`` of every frame the tracker could not use (it coasted), as the
        pipeline reports them on its errors topic."""
        return self._backend.problems

    def _check_frame(self, frame: Any, t: int) -> np.ndarray:
        img = np.asarray(frame)
        if img.dtype != np.uint8 or img.ndim not in (2, 3) or img.size == 0 or (img.ndim == 3 and img.shape[2] != 3):
            raise GflowError(f"frame {t}: expected (H, W) or (H, W, 3) uint8, got {img.dtype} {img.shape}")
        if self._shape is not None and img.shape != self._shape:
            raise GflowError(f"frame {t}: size changed from {self._shape} to {img.shape}")
        return img

    def init(self, frame: np.ndarray, box: Sequence[float], *, frame_index: int = 0) -> Estimate:
        """Start on ``frame`` from ``box`` ``(x, y, w, h)`` (pixels, top-left corner and size).

        Raises ``UnusableFrameError`` for a frame with no information (a uniform one) and
        ``GflowError`` for a box that misses the frame."""
        from pipeline.runtime.preflight import PreflightError, check_box_in_image

        if self._t >= 0:
            raise GflowError("the tracker has started already; make a new Tracker for a new target")
        if frame_index < 0:
            raise GflowError(f"frame_index must be >= 0, got {frame_index}")
        img = self._check_frame(frame, frame_index)
        b = check_box(box)
        try:
            check_box_in_image(b, img.shape[1], img.shape[0], what="init")
        except PreflightError as e:
            raise GflowError(str(e)) from None
        est = self._one(self._backend.init(img, b, frame_index), frame_index)
        self._shape, self._t = img.shape, frame_index
        return est

    def update(self, frame: np.ndarray, *, dt: float = 1.0) -> Estimate:
        """Track into the next frame. ``dt``: the time since the previous frame in frame periods
        (1: the next frame of a file; a live source that skipped frames gives more).

        A frame that carries no information (uniform) is coasted over: the estimate says
        ``phase == "coast"`` and :attr:`problems` says why."""
        if not (math.isfinite(dt) and dt >= 1.0):
            raise GflowError(f"dt must be >= 1 frame period, got {dt}")
        t = self._t + 1
        return self._one(self.step(frame, t, dt), t)

    def coast(self) -> Estimate:
        """No frame for the next index (a frame lost by the source): the posterior carried over it."""
        t = self._t + 1
        return self._one(self.step(None, t), t)

    def step(self, frame: np.ndarray | None, t: int, dt: float = 1.0) -> list[Estimate]:
        """Frame ``t`` (``None``: lost), after every index before it was stepped (indices skipped are
        lost frames, coasted over): the estimates of those indices and of ``t``, in frame order."""
        if self._t < 0:
            raise GflowError("call init(frame, box) first")
        if t <= self._t:
            raise GflowError(f"frame {t} comes after frame {self._t}")
        out: list[Estimate] = []
        for lost in range(self._t + 1, t):  # indices never given: lost frames
            out += self._backend.update(None, lost)
            self._t = lost
        out += self._backend.update(None if frame is None else self._check_frame(frame, t), t, dt)
        self._t = t
        return out

    def _one(self, ests: list[Estimate], t: int) -> Estimate:
        for e in ests:
            if e.frame == t:
                return e
        why = "; ".join(m for s, m in self.problems if s == t) or "no estimate was made"
        from .errors import UnusableFrameError

        raise UnusableFrameError(f"frame {t}: {why}")
