"""A request of the application layer and its plan: :class:`TrackRequest` (what ``gflow track``
takes, as one value), the stage parameters and source it names, and :func:`plan_track`, every
check made before anything starts.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from types import SimpleNamespace
from typing import TYPE_CHECKING, Any, Iterable, Mapping

from pipeline.app.errors import RequestError

if TYPE_CHECKING:  # imported where used: a request is made, and a missing source refused, without msgspec, the
    # stages, the graph loader or zenoh (every gflow track that stops at a mistake paid for them)
    from pipeline.runtime.graph import Plan
    from pipeline.runtime.transport import ZenohSettings

__all__ = ["RequestError", "TrackRequest", "TrackPlan", "plan_track", "source_params", "check_stage_values",
           "sets_as_given", "parse_sets", "Box"]

Box = tuple[float, float, float, float]


@dataclass(frozen=True)
class TrackRequest:
    """Everything ``gflow track`` takes, as one value.

    source : an image folder (or a dataset folder with ``frames/``), a video, an ``.mcap``
        recording, a stream URL or a camera device.
    init : the initial box ``(x, y, w, h)`` in frame ``start``.
    tracker, params : the tracker's name and its options as ``gflow track`` names them
        (``{"particles": 500, "model": "m.npz"}``; :meth:`options` is what its ``overrides`` reads).
    sets : stage parameters, each ``STAGE.PARAM=VALUE`` as ``--set`` takes it.
    record : the recording's path (None: ``recordings/track-TIME-RUNID.mcap``); ``no_record``:
        none at all; ``record_topics``: shell patterns of the topics to keep.
    network : the zenoh settings of a multi-process run (None: loopback, 7447 when free);
        ``listen_given``: its listen endpoints were the user's (never moved to a free port).
    """

    source: str
    init: Box
    tracker: str = "dcf"
    params: Mapping[str, Any] = field(default_factory=dict)
    sets: tuple[str, ...] = ()
    seed: int = 1
    record: str | None = None
    no_record: bool = False
    record_topics: tuple[str, ...] = ()
    inline: bool = False
    fps: float = 25.0
    realtime: bool = False
    start: int = 0
    stop: int | None = None
    reconnect: float | None = None
    open_timeout: float | None = None
    graph: str | None = None
    stream: str | None = None
    quiet: bool = False
    network: ZenohSettings | None = None
    listen_given: bool = False

    def options(self) -> SimpleNamespace:
        """The tracker's options with the initial box and the seed, as its ``overrides`` reads them."""
        return SimpleNamespace(**{**self.params, "tracker": self.tracker, "init": tuple(self.init), "seed": self.seed,
                                  "source": self.source})


# -- stage parameters given by name -----------------------------------------------------------


def parse_sets(items: Iterable[str] | None) -> dict[str, dict]:
    """``stage.param=value`` (value parsed as YAML: numbers, lists, true/false) -> overrides."""
    import yaml

    out: dict[str, dict] = {}
    for it in items or []:
        if "=" not in it or "." not in it.split("=", 1)[0]:
            raise RequestError(f"--set expects stage.param=value, got {it!r}")
        key, val = it.split("=", 1)
        stage, param = key.split(".", 1)
        out.setdefault(stage, {})[param] = yaml.safe_load(val)
    return out


def sets_as_given(items: Iterable[str] | None) -> dict[str, tuple[str, str, Any]]:
    """Each ``--set stage.param=value`` as :func:`check_stage_values` takes it: {``--set ITEM``: (stage, param, value)}."""
    return {f"--set {it}": (stage, param, value) for it in items or ()
            for stage, kv in parse_sets([it]).items() for param, value in kv.items()}


def check_stage_values(graph: str, given: dict[str, tuple[str, str, Any]], others: dict[str, dict] | None = None) -> None:
    """Refuse stage parameters given on the command line that the graph's stage would refuse, in the
    words of the options that gave them: ``given`` = {how it was given (``--particles 0``,
    ``--set filter.particles=0``): (stage, parameter, value)}, checked together per stage, on top of
    the graph's values and ``others`` ({stage: {parameter: value}} set otherwise). A stage the graph
    does not have is named by the option that gave it. The same line as ``gflow track --particles 0``,
    with no graph path. A parameter of the graph's tracker block is given as ``tracker.PARAM``
    (:func:`pipeline.runtime.tracker_checks.check_tracker_values`)."""
    from pipeline.runtime.graph import GraphError, load_graph, params_error
    from pipeline.runtime.tracker_checks import check_tracker_values

    if not given:
        return
    try:
        loaded = load_graph(graph)
    except GraphError:  # the graph's own fault: said by the load that follows, with the overrides
        return
    refused = check_tracker_values(loaded, given, others)
    if refused:
        raise RequestError(_unknown_tracker_param(loaded, given) or refused)
    _refuse_tracker_sets_without_block(loaded, given, others)
    stages = loaded.stages
    _refuse_unknown_stages(loaded, given)
    for stage in dict.fromkeys(st for st, _, _ in given.values()):
        if stage not in stages:
            continue
        mine = {how: (param, value) for how, (st, param, value) in given.items() if st == stage}
        base = {**loaded.stage_params(stage), **(others or {}).get(stage, {})}
        why = params_error(stages[stage].kind, {**base, **{param: value for param, value in mine.values()}})
        if why is not None:  # named by the values refused alone, else by all of them
            alone = [how for how, (param, value) in mine.items() if params_error(stages[stage].kind, {**base, param: value})]
            raise RequestError(f"{' '.join(alone or mine)}: {why}")


def _refuse_tracker_sets_without_block(plan: Plan, given: dict[str, tuple[str, str, Any]],
                                       others: dict[str, dict] | None) -> None:
    """``--set tracker.PARAM=VALUE`` of a graph with no tracker block (the built-in ``demo``, a graph file of one's
    own) goes to each of its stages of a tracker. One that such a stage refuses was reported as a bad parameter of
    that stage, quoting the graph file's line; it is refused in the words of the option: a name no such stage has,
    saying the graph has no tracker block and the stages whose ``--set STAGE.PARAM`` it takes; a value refused, as
    ``--set filter.PARAM`` would be."""
    from stages.registry import STAGES

    from pipeline.runtime.graph import params_error
    from pipeline.runtime.tracker_block import TRACKER_KEY, stage_tracker

    if plan.tracker is not None:
        return
    mine = {how: (param, value) for how, (stage, param, value) in given.items() if stage == TRACKER_KEY}
    takers = [n for n, s in plan.stages.items() if s.kind in STAGES and stage_tracker(STAGES[s.kind].Params)]
    for how, (param, value) in mine.items():
        for name in takers:
            base = {**plan.stages[name].params, **(others or {}).get(name, {})}
            why = params_error(plan.stages[name].kind, {**base, param: value})
            if why is not None and why.startswith("no parameter "):
                raise RequestError(f"{how}: the graph {plan.name} has no tracker block, and its stage {name} has no "
                                   f"parameter {param!r}; set a stage's parameter with --set STAGE.PARAM=VALUE (its "
                                   f"stages: {', '.join(plan.stages)})")
            if why is not None:
                raise RequestError(f"{how}: {why}")


def _refuse_unknown_stages(plan: Plan, given: dict[str, tuple[str, str, Any]]) -> None:
    """A stage of ``given`` that ``plan`` does not have, refused in the words of the option that named it: the
    graph's own error named the graph file (``/.../pipeline/graphs/dcf.yaml: override for stage 'nosuch'``), not
    the option."""
    from pipeline.runtime.tracker_block import TRACKER_KEY

    hint = f"; {TRACKER_KEY}.PARAM sets the tracker's parameters" if plan.tracker is not None else ""
    for how, (stage, _, _) in given.items():
        if stage not in plan.stages and stage != TRACKER_KEY:
            raise RequestError(f"{how}: the graph {plan.name} has no stage {stage!r} (its stages: "
                               f"{', '.join(plan.stages)}{hint})")


def _unknown_tracker_param(plan: Plan, given: dict[str, tuple[str, str, Any]]) -> str:
    """The first ``tracker.PARAM`` of ``given`` that ``plan``'s tracker block does not have, said with the
    closest names and where to find them all (``gflow info TRACKER``), or ''. The tracker's own words list
    every parameter (a hundred, for dcf) on the one line."""
    import difflib

    from pipeline.runtime.tracker_block import TRACKER_KEY, block_class, tracker_fields

    block = plan.tracker
    if block is None:
        return ""
    cls = block_class(block)
    known = tracker_fields(cls)
    for how, (stage, param, _) in given.items():
        if stage == TRACKER_KEY and param not in known:
            close = difflib.get_close_matches(param, known, n=3)
            hint = (f"did you mean {close[0]!r}? " + (f"also close: {', '.join(map(repr, close[1:]))}; "
                                                     if close[1:] else "")) if close else ""
            return (f"{how}: {cls.__name__} has no parameter {param!r} ({hint}`gflow info {block.name}` lists all "
                    f"{len(known)})")
    return ""


# -- the source ---------------------------------------------------------------------------------

#: options that only a live source takes: {field: option}
_LIVE_OPTIONS = {"reconnect": "--reconnect", "open_timeout": "--open-timeout"}


def _live_params(request: TrackRequest) -> dict:
    """Source parameters for a stream URL or a camera device."""
    from urllib.parse import urlsplit

    try:  # a port that is no number (udp://host:notaport) was waited on for --open-timeout, then "nothing received"
        urlsplit(request.source).port
    except ValueError as e:
        raise RequestError(f"{request.source}: not a stream URL gflow can open: {e}") from None
    for opt, given in (("--start", request.start), ("--realtime", request.realtime)):
        if given:
            raise RequestError(f"{opt} applies to files; a live source starts at its first frame and runs at its own "
                               f"pace")
    params: dict = {"kind": "live", "path": request.source, "fps": request.fps}
    for name in _LIVE_OPTIONS:
        if getattr(request, name) is not None:
            params[name] = getattr(request, name)
    if request.stop is not None:
        params["stop"] = request.stop
    return params


def source_params(request: TrackRequest) -> dict:
    """Source stage parameters for a path: image folder (or dataset folder with frames/), video, .mcap,
    or a live source (stream URL, camera device)."""
    from pipeline.io.live_capture import is_live_source

    source = request.source
    if is_live_source(source):
        return _live_params(request)
    for name, opt in _LIVE_OPTIONS.items():
        if getattr(request, name) is not None:
            raise RequestError(f"{opt} is an option of live sources (stream URLs, cameras), not of {source}")
    p = Path(source)
    params: dict = {"fps": request.fps, "realtime": request.realtime, "start": request.start}
    if request.stop is not None:
        params["stop"] = request.stop
    if p.is_dir():
        if (p / "frames").is_dir() and not any(q.suffix.lower() in (".jpg", ".png", ".jpeg", ".bmp") for q in p.iterdir()):
            p = p / "frames"  # a dataset folder like ../shared/data/caviar1
        params.update(kind="folder", path=str(p.resolve()))
    elif p.is_file():
        params.update(kind="mcap" if p.suffix == ".mcap" else "video", path=str(p.resolve()))
    else:
        raise RequestError(f"source not found: {source} (give an image folder, a video file or an .mcap recording)")
    return params


@dataclass
class TrackPlan:
    """A checked request: its graph with every override, and the source's frame count (None: unknown)."""

    request: TrackRequest
    plan: Plan
    total: int | None
    first_image_shape: tuple[int, ...] | None = None  # of frame ``start`` (None: a live source, not opened yet)


def _graph_plan(request: TrackRequest, tracker: Any, source: dict) -> Plan:
    """The tracker's graph for ``request`` with every override, its source stage given ``source``."""
    from pipeline.runtime.graph import load_graph

    graph, overrides = tracker.overrides(request.options())
    overrides.setdefault("source", {}).update(source)
    check_stage_values(request.graph or graph, sets_as_given(request.sets), overrides)
    for stage, kv in parse_sets(request.sets).items():
        overrides.setdefault(stage, {}).update(kv)
    make_plan = getattr(tracker, "make_plan", None)
    if make_plan is not None:  # a tracker that generates its graph (gflow: K proposal shards)
        return make_plan(request.graph or graph, overrides)
    return load_graph(request.graph or graph, overrides=overrides)


def plan_track(request: TrackRequest, tracker: Any) -> TrackPlan:
    """The plan of ``request`` for ``tracker`` (its module: ``overrides(options)``, maybe
    ``make_plan``). Bad options, stage values, sources or initial boxes raise
    :class:`RequestError` here, before anything starts."""
    source = source_params(request)  # a source that is not there: said before the imports below (OpenCV, the stages)
    import msgspec

    from stages.source import SourceParams
    from pipeline.io.frame_readers import count_frames
    from pipeline.runtime.preflight import box_needs, check_source
    from pipeline.runtime.zygote import preload

    plan = _graph_plan(request, tracker, source)
    if not request.inline:  # the stage processes' zygote imports their modules meanwhile
        preload(s.kind for s in plan.stages.values())
    sp = msgspec.convert(plan.stages["source"].params, SourceParams)
    if sp.kind == "live":  # opened once, by the source stage (a camera or a listen=1 server serves one client)
        return TrackPlan(request, plan, None)
    # readable, start inside it, init on the image and as large as the stages need: before anything starts
    first = check_source(sp, request.init, needs=box_needs(plan))
    shape = first.image.shape if first.image is not None else None
    return TrackPlan(request, plan, count_frames(sp), shape)
