"""How :class:`gflow.Tracker` runs a tracker: on the protocol.

:class:`ProtocolBackend` calls a :class:`gflow_core.tracker.TrackingFilter` directly (``observe``,
``init``, ``propose``, ``update``, ``coast``): the same functions, draws and parameters the stages
call, so the boxes are those of ``gflow track --inline`` bit for bit. Every tracker is on it:
appearance, dcf, gflow, chamfer, m2 (a contour or a patch model: its registration's setup picks the
filter, :mod:`gflow_core.m2.protocol`) and the trackers other packages register.
"""

from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from gflow_core.registry import get as get_spec
from gflow_core.tracker import Box, Estimate, FrameRng, TrackingFilter, UnusableFrame
from gflow_core.tracker import stream_hash, unseen

from .errors import GflowError, UnusableFrameError

__all__ = ["ProtocolBackend", "load_model_file", "protocol_tracker"]


def load_model_file(name: str) -> tuple[Any, Mapping[str, Any], str]:
    """A model file (or a built-in model's name, ``face``) read for a tracker's setup
    (:data:`gflow_core.spec.Loader`): (the model, its file's meta, the built-in name or the file's
    absolute path). A missing or bad file is a :class:`GflowError` saying so."""
    from pipeline.io.modelfile import BUILTIN_MODELS, load_meta, load_model, model_path

    try:
        path = model_path(name)
        obj, meta = load_model(path), load_meta(path)
    except (OSError, ValueError) as e:
        raise GflowError(str(e)) from None
    return obj, meta, name if name in BUILTIN_MODELS else str(path.resolve())


def protocol_tracker(name: str, params: Mapping[str, Any]) -> tuple[TrackingFilter[Any, Any, Any, Any], Any,
                                                                    dict[str, Any]]:
    """(the protocol object, its parameters, its resources) of registered tracker ``name``
    (:func:`gflow_core.registry.get`) made from the API's keywords: the spec's setup, with model files
    read by :func:`load_model_file`."""
    spec = get_spec(name)
    p, resources = spec.make(params, load_model_file)
    return spec.tracker(), p, resources


class ProtocolBackend:
    """A tracker of :mod:`gflow_core.tracker` driven frame by frame.

    Frame ``t`` draws from ``FrameRng(seed, crc32(stream), t)``, as the stages of a graph whose
    stream is ``stream`` do (``cam0``: the shipped graphs)."""

    def __init__(self, impl: TrackingFilter[Any, Any, Any, Any], params: Any, resources: Mapping[str, Any],
                 seed: int, stream: str) -> None:
        self.impl, self.params, self.resources = impl, params, dict(resources)
        self.seed, self.hash = int(seed), stream_hash(stream)
        self.state: Any = None
        self.problems: list[tuple[int, str]] = []

    def rng(self, t: int) -> FrameRng:
        return FrameRng(self.seed, self.hash, t)

    def init(self, image: np.ndarray, box: Box, t: int) -> list[Estimate]:
        try:
            obs = self.impl.observe(self.params, image)
        except UnusableFrame as e:
            raise UnusableFrameError(f"frame {t}: {e}") from None
        try:
            self.state, est = self.impl.init(self.params, obs, box, self.rng(t), self.resources)
        except ValueError as e:
            raise GflowError(f"frame {t}: {e}") from None
        return [est]

    def update(self, image: np.ndarray | None, t: int, dt: float = 1.0) -> list[Estimate]:
        obs = None
        if image is not None:
            try:
                obs = self.impl.observe(self.params, image)
            except UnusableFrame as e:
                self.problems.append((t, f"frame {t}: {e}; coasting"))
        if obs is not None:
            try:
                proposal = self.impl.propose(self.params, self.state, obs, self.rng(t), dt)
                self.state, est = self.impl.update(self.params, self.state, proposal, obs, self.rng(t))
                return [est]
            except (ValueError, np.linalg.LinAlgError) as e:
                self.problems.append((t, f"frame {t}: {type(e).__name__}: {e}; coasting"))
        self.state, est = self.impl.coast(self.params, self.state, self.rng(t), obs)
        return [unseen(est)]  # no image used: the target was not seen, as the filter stages say
