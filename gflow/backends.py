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
from collections import deque
from typing import Any, Mapping

import numpy as np

from gflow_core.spec import get as get_spec
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
    (:func:`gflow_core.spec.get`) made from the API's keywords: the spec's setup, with model files
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
    m2 with a patch model (graph ``m2_patch``), the one tracker not on the protocol."""

    def __init__(self, name: str, seed: int, fps: float, params: Mapping[str, Any]) -> None:
        from pipeline.cli.trackers import TRACKERS

        self.name, self.seed, self.fps = name, int(seed), float(fps)
        kw = dict(params)
        self.sets: dict[str, dict[str, Any]] = {k: dict(v) for k, v in dict(kw.pop("set", None) or {}).items()}
        self.options = kw
        self.module = TRACKERS[name]
        self.hosts: dict[str, Any] = {}
        self.queue: deque[tuple[str, bytes, int, str]] = deque()
        self.done: dict[int, Estimate] = {}
        self.problems: list[tuple[int, str]] = []
        self._check_options()

    def _argv(self, box: Box) -> list[str]:
        argv = ["-", "--init", ",".join(repr(float(v)) for v in box), "--out", "-", "--tracker", self.name,
                "--seed", str(self.seed)]
        for key, value in self.options.items():
            opt = "--" + key.replace("_", "-")
            if value is True:
                argv.append(opt)
            elif value is not False and value is not None:
                argv += [opt, str(value)]
        for stage, kv in self.sets.items():
            argv += [a for k, v in kv.items() for a in ("--set", f"{stage}.{k}={_yaml(v)}")]
        return argv

    def _args(self, box: Box) -> argparse.Namespace:
        from pipeline.cli.commands.common import CliError
        from pipeline.cli.commands.track import check_tracker_options, track_args

        try:
            args = track_args(self._argv(box))
            check_tracker_options(args)
        except CliError as e:
            raise GflowError(str(e)) from None
        return args

    def _check_options(self) -> None:
        from pipeline.cli.commands.track import _OWN_OPTIONS, _ALSO_USED_BY, add_track_args

        if not _OWN_OPTIONS:
            add_track_args(argparse.ArgumentParser(add_help=False))
        own = {d for t, opts in _OWN_OPTIONS.items() for d in opts
               if t == self.name or self.name in _ALSO_USED_BY.get(d, ())}
        unknown = sorted(set(self.options) - own)
        if unknown:
            from gflow_core.params import UnknownParameter

            raise UnknownParameter(f"tracker {self.name} has no option {', '.join(unknown)} (options: "
                                   f"{', '.join(sorted(own)) or 'none'}; any stage parameter: set={{'STAGE': "
                                   f"{{'PARAM': VALUE}}}})")

    def init(self, image: np.ndarray, box: Box, t: int) -> list[Estimate]:
        from pipeline.cli.commands.common import CliError
        from pipeline.runtime.build import make_stage
        from pipeline.runtime.graph import GraphError, load_graph
        from pipeline.runtime.stage_host import StageHost
        from stages.source import SourceStage

        args = self._args(box)
        try:
            graph, over = self.module.overrides(args)
            for sname, kv in self.sets.items():
                over.setdefault(sname, {}).update(kv)
            # frames are pushed, never read: the source only validates and stamps them (media time)
            over.setdefault("source", {}).update(kind="synthetic", fps=self.fps, start=0, stop=None)
            make_plan = getattr(self.module, "make_plan", None)
            plan = make_plan(graph, over) if make_plan is not None else load_graph(graph, overrides=over)
        except (CliError, GraphError, ValueError) as e:
            raise GflowError(str(e)) from None
        for name, sp in plan.stages.items():
            if sp.kind == "recorder":
                continue
            try:
                stage = make_stage(plan, name)
            except (OSError, ValueError) as e:
                raise GflowError(f"stage {name}: {e}") from None
            self.hosts[name] = StageHost(stage, sp.inputs, sp.outputs, plan.error_topic, self._publish,
                                         ahead=False)
            if isinstance(stage, SourceStage):
                self.source = self.hosts[name]
        self.estimate_topics = {t for sp in plan.stages.values() for p, t in sp.outputs.items() if p == "estimate"}
        self.subscribers: dict[str, list[Any]] = {}
        for h in self.hosts.values():
            for topic in h.topics_in.values():
                self.subscribers.setdefault(topic, []).append(h)
        self.error_topic = plan.error_topic
        return self.update(image, t)

    def _publish(self, topic: str, payload: bytes, seq: int, type_name: str = "") -> None:
        self.queue.append((topic, payload, seq, type_name))

    def _drain(self) -> list[Estimate]:
        from stages.messages import decode

        out = []
        while self.queue:
            topic, payload, seq, type_name = self.queue.popleft()
            if topic in self.estimate_topics and type_name != "EndOfStream":
                out.append(_estimate_of(decode(payload)))
            elif topic == self.error_topic:
                report = decode(payload)
                self.problems.append((seq, f"{report.stage}: {report.kind}: {report.message}"))
            for h in self.subscribers.get(topic, ()):
                h.deliver(topic, payload)
        return out

    def update(self, image: np.ndarray | None, t: int, dt: float = 1.0) -> list[Estimate]:
        from stages.source import RawFrame

        if image is not None:
            src = self.source
            outs = src.stage.emit(RawFrame(t, image))
            src._flush_reports()
            src._emit(outs)
        return self._drain()

    def finish(self) -> list[Estimate]:
        for h in self.hosts.values():
            h.close("end")
        return self._drain()


def _yaml(v: Any) -> str:
    import yaml

    return yaml.safe_dump(v, default_flow_style=True).strip().removesuffix("\n...").strip()


def _estimate_of(msg: Any) -> Estimate:
    """The protocol's estimate of an estimate message (its other fields as extras, arrays decoded)."""
    import msgspec

    from stages.messages import NDArray

    extras = {}
    for f in msgspec.structs.fields(type(msg)):
        if f.name in ("header", "box", "state", "confidence", "target_state"):
            continue
        v = getattr(msg, f.name)
        extras[f.name] = v.array() if isinstance(v, NDArray) else v
    b = msg.box
    return Estimate(frame=msg.header.seq, box=(float(b[0]), float(b[1]), float(b[2]), float(b[3])),
                    confidence=float(msg.confidence), target_state=msg.target_state, phase=msg.state, extras=extras)
