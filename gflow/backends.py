"""How :class:`gflow.Tracker` runs each tracker: on the protocol, or (m2 with a patch model) through
its stages in process.

* :class:`ProtocolBackend` calls a :class:`gflow_core.tracker.TrackingFilter` directly
  (``observe``, ``init``, ``propose``, ``update``, ``coast``): the same functions, draws and
  parameters the stages call, so the boxes are those of ``gflow track --inline`` bit for bit.
  Every tracker is on it: appearance, dcf, gflow, chamfer and m2 (a contour model).
* :class:`GraphBackend` runs a tracker's built-in graph in this process, exactly as ``--inline``
  does (frames pushed into its source stage, every message encoded and decoded): only for m2 with
  a patch model (the ``m2_patch`` graph, whose filter is not on the protocol). Its parameters are
  given as ``gflow track`` takes them: its tracker options (``particles=500``) and
  ``set={"filter.lam": 0.3}``.
"""

from __future__ import annotations

import argparse
from typing import Any, Mapping

import numpy as np

from gflow_core.registry import get as get_spec
from gflow_core.tracker import Box, Estimate, FrameRng, TrackingFilter, UnusableFrame
from stages.rng import stream_hash

from .errors import GflowError, UnusableFrameError

__all__ = ["ProtocolBackend", "GraphBackend", "load_model_file", "patch_model", "protocol_tracker"]


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


def patch_model(name: str, params: Mapping[str, Any]) -> tuple[bool, dict[str, Any]]:
    """Whether tracker ``name`` with ``params`` is m2 with a patch model (run through its stages),
    and the parameters with an m2 model file read once (model, meta) for its setup."""
    if name != "m2":
        return False, dict(params)
    from gflow_core.builtin_trackers import m2_model

    try:
        model, meta = m2_model(params.get("model"), load_model_file)
    except ValueError as e:
        raise GflowError(str(e)) from None
    if model.kind == "patch":
        return True, dict(params)
    return False, {**params, "model": (model, meta)}


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
        return [est]

    def finish(self) -> list[Estimate]:
        return []


class GraphBackend:
    """A tracker's built-in graph run in this process, fed one frame at a time (as ``--inline``):
    m2 with a patch model (graph ``m2_patch``), the one tracker not on the protocol. The graph
    comes from the application layer (:class:`pipeline.app.TrackRequest`, run by
    :class:`pipeline.app.PushedRun`), as ``gflow track`` makes it."""

    def __init__(self, name: str, seed: int, fps: float, params: Mapping[str, Any]) -> None:
        from pipeline.cli.trackers import TRACKERS

        self.name, self.seed, self.fps = name, int(seed), float(fps)
        kw = dict(params)
        self.sets: dict[str, dict[str, Any]] = {k: dict(v) for k, v in dict(kw.pop("set", None) or {}).items()}
        self.options = kw
        self.module = TRACKERS[name]
        self.run: Any = None
        self.problems: list[tuple[int, str]] = []
        self._check_options()

    def _request(self, box: Box) -> Any:
        """The :class:`pipeline.app.TrackRequest` of this tracker's options, checked as ``gflow track``
        checks them."""
        from pipeline.app import RequestError, TrackRequest
        from pipeline.cli.commands.track import check_tracker_options, tracker_params

        given = _as_typed({k: v for k, v in self.options.items() if v is not None})
        options = argparse.Namespace(**{**_track_defaults(), **given, "tracker": self.name})
        try:
            check_tracker_options(options)
        except RequestError as e:
            raise GflowError(str(e)) from None
        sets = tuple(f"{stage}.{k}={_yaml(v)}" for stage, kv in self.sets.items() for k, v in kv.items())
        return TrackRequest(source="(frames given one at a time)", init=(float(box[0]), float(box[1]), float(box[2]),
                                                                         float(box[3])),
                            tracker=self.name, params=tracker_params(options), sets=sets, seed=self.seed,
                            fps=self.fps, inline=True, quiet=True)

    def _check_options(self) -> None:
        from pipeline.cli.commands.track import tracker_options

        own = set(tracker_options(self.name))
        unknown = sorted(set(self.options) - own)
        if unknown:
            from gflow_core.params import UnknownParameter

            raise UnknownParameter(f"tracker {self.name} has no option {', '.join(unknown)} (options: "
                                   f"{', '.join(sorted(own)) or 'none'}; any stage parameter: set={{'STAGE': "
                                   f"{{'PARAM': VALUE}}}})")

    def init(self, image: np.ndarray, box: Box, t: int) -> list[Estimate]:
        from pipeline.app import PushedRun, RequestError
        from pipeline.runtime.graph import GraphError

        request = self._request(box)
        try:
            self.run = PushedRun(request, self.module)
        except (RequestError, GraphError, ValueError) as e:
            raise GflowError(str(e)) from None
        self.problems = self.run.problems
        return self.update(image, t)

    def update(self, image: np.ndarray | None, t: int, dt: float = 1.0) -> list[Estimate]:
        return [_estimate_of(m) for m in self.run.push(image, t)]

    def finish(self) -> list[Estimate]:
        return [_estimate_of(m) for m in self.run.finish()]


def _track_actions() -> dict[str, argparse.Action]:
    """``gflow track``'s options by dest (and every tracker's options registered)."""
    from pipeline.cli.commands.track import add_track_args

    p = argparse.ArgumentParser(add_help=False)
    add_track_args(p)
    return {a.dest: a for a in p._actions}


def _track_defaults() -> dict[str, Any]:
    """{dest: default} of every tracker option of ``gflow track``."""
    from pipeline.cli.commands.track import registered_options

    return {d: default for opts in registered_options().values() for d, (_, default) in opts.items()}


def _as_typed(options: Mapping[str, Any]) -> dict[str, Any]:
    """Tracker options given as keywords, converted as ``gflow track`` converts its options
    (``particles=500`` as ``--particles 500``): a flag takes True / False, a value the option's type."""
    actions = _track_actions()
    out = {}
    for dest, value in options.items():
        action = actions[dest]
        if action.nargs == 0:  # a flag (--track-scale)
            if not isinstance(value, bool):
                raise GflowError(f"{action.option_strings[0]} is a flag: give True or False, not {value!r}")
        elif callable(action.type):
            try:
                value = action.type(str(value))
            except argparse.ArgumentTypeError as e:  # argparse's own words
                raise GflowError(f"argument {action.option_strings[0]}: {e}") from None
            except (TypeError, ValueError):
                kind = getattr(action.type, "__name__", "")
                raise GflowError(f"argument {action.option_strings[0]}: invalid {kind} value: {str(value)!r}") from None
        else:  # a string option (--model FILE)
            value = str(value)
        if action.choices is not None and value not in action.choices:
            raise GflowError(f"{action.option_strings[0]}: {value!r} is not one of "
                             f"{', '.join(map(str, action.choices))}")
        out[dest] = value
    return out


def _yaml(v: Any) -> str:
    import yaml

    return yaml.safe_dump(v, default_flow_style=True).strip().removesuffix("\n...").strip()


def _estimate_of(msg: Any) -> Estimate:
    """The protocol's estimate of an estimate message (its other fields as extras, arrays decoded)."""
    import msgspec

    from gflow_msgs.messages import NDArray

    extras = {}
    for f in msgspec.structs.fields(type(msg)):
        if f.name in ("header", "box", "state", "confidence", "target_state"):
            continue
        v = getattr(msg, f.name)
        extras[f.name] = v.array() if isinstance(v, NDArray) else v
    b = msg.box
    return Estimate(frame=msg.header.seq, box=(float(b[0]), float(b[1]), float(b[2]), float(b[3])),
                    confidence=float(msg.confidence), target_state=msg.target_state, phase=msg.state, extras=extras)
