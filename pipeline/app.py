"""The application layer: what ``gflow track`` does, below any command line.

A :class:`TrackRequest` (a frozen value: source, initial box, tracker and its options, seed,
where to record, ...) becomes a :class:`TrackPlan` (:func:`plan_track`: every check that can
be made before anything starts, then the graph with its overrides, the source checked and its
frames counted), and :func:`run` runs it, inline or as processes, yielding each estimate as an
:class:`EstimateSink` takes it from the run's own messages, while the run goes on (closing the
generator stops the run); what the run came to (:class:`TrackResult`: the estimates, time,
report lines, the recording kept) is the generator's return value, and :func:`track` runs a plan
to its end and returns it.

The estimates come from the run, not from reading its recording back: with ``no_record`` no
recorder runs and no MCAP file is written (a live source, whose camera frame numbers and
figures are read from the recording, still records to a temporary file, removed at the end).
A recording, when kept, still fills in an estimate the sink missed.

Commands are shells over this module (``gflow track``, ``gflow benchmark``, ``gflow run``,
``gflow demo``); the tracker registry lives above it, so :func:`plan_track` is handed the
tracker (anything with ``overrides(options) -> (graph, {stage: {param: value}})`` and,
optionally, ``make_plan(graph, overrides)``).
"""

from __future__ import annotations

import dataclasses
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from types import SimpleNamespace
from typing import Any, Callable, Generator, Iterable, Mapping

import msgspec

from stages.messages import ErrorReport, Estimate, MessageError, PoseEstimate, decode
from stages.source import SourceParams

from pipeline.runtime.graph import Plan, load_graph
from pipeline.runtime.transport import SessionError, ZenohSettings, free_port
from pipeline.recording.live_record import LiveSummary
from pipeline.recording.results import RunOutcome, estimate_columns, renumber, run_outcome, write_boxes

__all__ = ["RequestError", "TrackRequest", "TrackPlan", "TrackResult", "EstimateSink", "RunStop", "plan_track", "run",
           "track",
           "run_graph", "PushedRun", "RecordingTarget", "place", "source_params", "check_stage_values", "sets_as_given",
           "parse_sets", "default_listen", "default_zenoh", "DEFAULT_ENDPOINT"]

Box = tuple[float, float, float, float]
DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"


class RequestError(Exception):
    """A request that cannot run, said in one line naming what is wrong (``gflow``: exit status 2)."""


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
    does not have is left to the graph's own error. The same line as ``gflow track --particles 0``,
    with no graph path. A parameter of the graph's tracker block is given as ``tracker.PARAM``
    (:func:`pipeline.runtime.tracker_checks.check_tracker_values`)."""
    from pipeline.runtime.graph import GraphError, params_error
    from pipeline.runtime.tracker_checks import check_tracker_values

    if not given:
        return
    try:
        loaded = load_graph(graph)
    except GraphError:  # the graph's own fault: said by the load that follows, with the overrides
        return
    refused = check_tracker_values(loaded, given, others)
    if refused:
        raise RequestError(refused)
    stages = loaded.stages
    for stage in dict.fromkeys(st for st, _, _ in given.values()):
        if stage not in stages:
            continue
        mine = {how: (param, value) for how, (st, param, value) in given.items() if st == stage}
        base = {**loaded.stage_params(stage), **(others or {}).get(stage, {})}
        why = params_error(stages[stage].kind, {**base, **{param: value for param, value in mine.values()}})
        if why is not None:  # named by the values refused alone, else by all of them
            alone = [how for how, (param, value) in mine.items() if params_error(stages[stage].kind, {**base, param: value})]
            raise RequestError(f"{' '.join(alone or mine)}: {why}")


# -- the source ---------------------------------------------------------------------------------

#: options that only a live source takes: {field: option}
_LIVE_OPTIONS = {"reconnect": "--reconnect", "open_timeout": "--open-timeout"}


def _live_params(request: TrackRequest) -> dict:
    """Source parameters for a stream URL or a camera device."""
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


# -- where a run records --------------------------------------------------------------------------


class RecordingTarget:
    """Where a run records: ``record`` (a path; None: ``default``, or the graph's own name made when
    the run starts), ``no_record`` and ``record_topics`` (shell patterns).

    ``needed`` are topics read back after the run: they are always recorded, and with
    ``no_record`` they go to a temporary file that :meth:`cleanup` deletes; with nothing needed,
    ``no_record`` removes the recorder stage. ``path`` is what to pass to the launcher (None: no
    recorder).
    """

    def __init__(self, plan: Plan, record: str | None, no_record: bool, record_topics: Iterable[str],
                 default: str | None, needed: tuple[str, ...] = ()) -> None:
        import tempfile

        self.tmpdir: str | None = None
        self.temporary = False
        self.given = bool(record)
        rec = plan.recorder()
        pats = [p.strip() for item in record_topics for p in item.split(",") if p.strip()]
        if rec is None:
            if pats or needed:
                raise RequestError(f"the graph {plan.name!r} has no recorder stage, so there is nothing to "
                                   + ("select topics of" if pats else "read the results from"))
            self.path = None
            return
        if no_record:
            if not needed:
                del plan.stages[rec.name]
                self.path = None
                return
            self.tmpdir = tempfile.mkdtemp(prefix="gflow-norecord-")
            self.temporary = True
            self.path = str(Path(self.tmpdir) / "run.mcap")
            rec.params["topics"] = list(needed)
            return
        if pats:
            rec.params["topics"] = pats + [t for t in needed if t not in pats]
        self.path = record or default
        from pipeline.io.recording_files import refuse_existing
        from pipeline.runtime.preflight import check_writable

        if self.path:  # a recording never overwrites a file (the recorder also creates it exclusively)
            refuse_existing(self.path, "--record" if record else "the recording")
        path = self.path or plan.recording_path()  # None: named when the run starts, with its run id
        assert path is not None  # the plan has its recorder
        # the default recordings/ folder is made; a typed one must exist
        check_writable(path, "--record" if record else "the recording", make_folder=not record)  # before any work

    @property
    def kept(self) -> str:
        """How to name the recording to the user."""
        return "none (--no-record)" if self.temporary or self.path is None else str(self.path)

    def written(self, path: str | None) -> None:
        """The path the run recorded to (a default one is named when the run starts); a note when
        its folder holds more than ``GFLOW_RECORDINGS_WARN_MB`` of recordings."""
        if not self.temporary and path:
            self.path = path
            from pipeline.io.recording_files import size_warning

            note = size_warning(Path(path).parent)
            if note:
                print(note, file=sys.stderr)

    def cleanup(self) -> None:
        if self.tmpdir:
            import shutil

            shutil.rmtree(self.tmpdir, ignore_errors=True)
            self.tmpdir = None


def temporary_recording(path: str | None) -> bool:
    """A recording :class:`RecordingTarget` made for ``no_record`` (read back, then removed)."""
    return bool(path) and Path(str(path)).parent.name.startswith("gflow-norecord-")


# -- running a graph --------------------------------------------------------------------------------


def place(plan: Plan, hosts: tuple[str, ...], inline: bool, stream: str | None) -> tuple[str, ...]:
    """Check ``hosts`` against the whole graph and choose the run's stream (see
    :mod:`pipeline.runtime.runid`); return the host labels this process runs."""
    from pipeline.runtime.placement import local_stages
    from pipeline.runtime.runid import choose_stream

    local_stages(plan, hosts)  # an unknown label: one line naming the graph's labels
    if hosts and inline:
        raise RequestError("--host runs the stages placed on this host as processes; it cannot be combined with "
                           "--inline")
    if inline and not stream:
        return hosts  # one process, no network: nothing to mix with
    choose_stream(plan, stream, placed=bool(hosts))
    return hosts


def _startup_failure(plan: Plan, launcher, message: str) -> str:
    """What to tell the user when a run could not start. A live source that cannot be opened says
    so itself, in one line naming it and what FFmpeg said; the recording, which holds nothing but
    the start-up's heartbeats, is removed."""
    from pipeline.runtime.node_plan import EXIT_BAD_SOURCE

    src = next((n for n, s in plan.stages.items() if s.is_source()), None)
    exit_ = launcher.exits.get(src)
    if exit_ is None or exit_.returncode != EXIT_BAD_SOURCE or not exit_.last_error:
        return message
    if launcher.recording and plan.recorder() is not None:
        Path(launcher.recording).unlink(missing_ok=True)
    return f"cannot track {exit_.last_error}"


Tap = Callable[[str, bytes, int, str], None]


def run_graph(plan: Plan, *, inline: bool, zenoh: Callable[[], ZenohSettings], listen_given: bool,
              recording: str | None, total: int | None, hosts: tuple[str, ...] = (), quiet: bool = False,
              strict: bool = True, sink: EstimateSink | None = None, no_record: bool = False,
              stop: RunStop | None = None):
    """Run a placed plan inline or as processes; return (recording path, seconds, frames, per-stage info).

    ``zenoh()`` gives the settings of a multi-process run (asked only for one); ``sink`` is fed
    the run's estimates as they are published (inline) or heard (processes), and its error
    reports; ``stop`` ends the run early when set from another thread; ``no_record``: the run
    keeps no recording (so ``gflow ps`` says). With ``strict=False`` a run that did not finish
    cleanly returns (``info["ok"]`` False) instead of raising, so the caller can keep what was
    tracked."""
    if inline:
        from pipeline.runtime.inline import run_inline

        last = [0.0]

        def progress(n: int) -> None:
            now = time.monotonic()
            if not quiet and now - last[0] > 1.0:
                last[0] = now
                print(f"  {n}" + (f"/{total}" if total else "") + " frames", file=sys.stderr)

        md = {"gflow.graph": {"name": plan.name, "stream": plan.stream, "yaml": plan.source_text},
              "gflow.config": plan.config_metadata()}
        r = run_inline(plan, progress=progress, recording=recording, metadata=md, tap=sink,
                       stop=stop.event if stop is not None else None)
        bad = {n: e for n, e in r.errors.items() if e}
        return r.recording, r.seconds, r.frames, {"mode": "inline", "steps": r.steps, "errors": bad}
    from pipeline.runtime.launcher import Launcher
    from pipeline.runtime.running import announce
    from pipeline.runtime.zygote import preload

    preload(s.kind for s in plan.stages.values())  # the stage processes' zygote imports their modules (once)

    settings = zenoh()
    while True:
        launcher = Launcher(plan, zenoh=settings, recording=recording, progress=not quiet,
                            total_frames=total, hosts=hosts, say_recording=not temporary_recording(recording))
        if sink is not None:  # each estimate as the launcher hears it
            launcher.monitor.on_estimate = sink.take
        if stop is not None:
            stop.attach(launcher)
        endpoints = [e for e in launcher.zenoh.listen if not e.endswith(":0")]
        if not quiet:
            here = ", ".join(n for n in plan.stages if n in launcher.local)
            where = f"host {', '.join(hosts)} ({here}); " if hosts else ""
            reach = (f"a client of {', '.join(launcher.zenoh.connect)}" if launcher.zenoh.mode == "client"
                     else f"listening on {', '.join(endpoints)}")
            print(f"{plan.name}: {where}{reach} (stream {plan.stream}; gflow ps, topics, echo and hz find it)",
                  file=sys.stderr)
        rec = plan.recorder()
        with announce(plan.stream, endpoints, name=plan.name, stages=sorted(launcher.local, key=list(plan.stages).index),
                      camera=plan.seed_stream, no_record=no_record or temporary_recording(recording),
                      recording=(launcher.recording if rec and rec.name in launcher.local
                                 and not temporary_recording(recording) else None)):
            try:
                res = launcher.run()
            except SessionError as e:  # 7447, free a moment ago, taken by a run started at the same time
                if listen_given or settings.listen != (DEFAULT_ENDPOINT,) or "in use" not in str(e):
                    raise RequestError(str(e)) from None
                settings = dataclasses.replace(settings, listen=(f"tcp/127.0.0.1:{free_port()}",))
                continue  # nothing had started: the session is the launcher's first step
            except RuntimeError as e:  # start-up: a stage died, a host did not come, the stream is taken
                raise RequestError(_startup_failure(plan, launcher, str(e))) from None
        break
    if res.interrupted:
        print("interrupted: stages stopped, recording closed", file=sys.stderr)
    for n, ex in res.exits.items():
        if ex.returncode != 0:
            print(f"stage {n} exited with status {ex.returncode}: {ex.last_error}", file=sys.stderr)
    src = next((n for n, s in plan.stages.items() if s.is_source()), None)  # a graph fed from outside has none
    frames = res.status[src].steps if src in res.status else 0
    from pipeline.recording.live_record import LIVE_REPORTS  # a live source's reconnects and end: not errors

    info = {"mode": "processes", "ok": res.ok, "pids": res.pids, "peak_rss_mb": res.peak_rss_mb,
            "errors": sum(e.kind not in LIVE_REPORTS for e in res.errors), "fps": {n: s.fps for n, s in res.status.items()},
            "interrupted": res.interrupted, "stall": res.stall,
            "restarts": {n: e.restarts for n, e in res.exits.items() if e.restarts}, "estimates": res.estimates}
    if sink is not None:  # what the launcher heard of the run: its estimates and its error reports
        for seq, payload in sorted(res.estimates.items()):
            sink.take(payload)
        for report in res.errors:
            sink.reported.add(report.header.seq)
    if res.stall:
        print(res.stall, file=sys.stderr)
    unsigned = {n: st.rejected["unsigned"] for n, st in res.status.items() if st.rejected.get("unsigned")}
    if unsigned:  # --run-key: what came from outside the run was dropped; say so
        info["unsigned"] = unsigned
        print("ignored messages not signed with the run key (from outside the run), by stage: "
              + ", ".join(f"{n} {c}" for n, c in sorted(unsigned.items())), file=sys.stderr)
    if strict and not res.ok and not res.interrupted:
        raise RequestError("the pipeline did not finish cleanly (see the messages above)")
    return res.recording, res.seconds, frames, info


# -- gflow track ---------------------------------------------------------------------------------


class EstimateSink:
    """The estimates and error reports of a run, taken from its messages as they are published
    (inline: every message of the run; processes: what the launcher heard on the run's topics).

    estimates : {frame: Estimate | PoseEstimate} of the run's estimate topics.
    reported : the frames a stage reported a problem with (an ``ErrorReport``).
    on_estimate : called with each estimate the first time its frame's is taken (from the thread
        that runs the graph, or the launcher's zenoh thread).
    """

    def __init__(self, estimate_topics: Iterable[str] = (), error_topic: str = "",
                 on_estimate: Callable[[Estimate | PoseEstimate], None] | None = None) -> None:
        self.topics = set(estimate_topics)
        self.error_topic = error_topic
        self.on_estimate = on_estimate
        self.estimates: dict[int, Estimate | PoseEstimate] = {}
        self.reported: set[int] = set()

    def __call__(self, topic: str, payload: bytes, seq: int, type_name: str = "") -> None:
        """One message of an inline run (the tap of :func:`pipeline.runtime.inline.run_inline`)."""
        if topic in self.topics:
            self.take(payload)
        elif topic == self.error_topic:
            try:
                report = decode(payload)
            except MessageError:
                return
            if isinstance(report, ErrorReport):
                self.reported.add(report.header.seq)

    def take(self, payload: bytes) -> None:
        """An estimate message (anything else on an estimate topic, such as its end of stream, is left)."""
        try:
            m = decode(payload)
        except MessageError:
            return
        if isinstance(m, (Estimate, PoseEstimate)):
            new = m.header.seq not in self.estimates
            self.estimates[m.header.seq] = m
            if new and self.on_estimate is not None:
                self.on_estimate(m)


class RunStop:
    """Ends a run early, asked from another thread (:func:`run`'s consumer stopping): inline, the
    source ends before its next frame and every stage closes as at its end; as processes, the
    launcher stops the stages as on Ctrl-C. Either way the recording is closed properly."""

    def __init__(self) -> None:
        import threading

        self.event = threading.Event()
        self._lock = threading.Lock()
        self._launchers: list[Any] = []

    def attach(self, launcher: Any) -> None:
        """The launcher of a multi-process run (stopped at once when the stop came first)."""
        with self._lock:
            self._launchers.append(launcher)
            if self.event.is_set():
                launcher.request_stop()

    def set(self) -> None:
        with self._lock:
            self.event.set()
            for launcher in self._launchers:
                launcher.request_stop()


@dataclass
class TrackPlan:
    """A checked request: its graph with every override, and the source's frame count (None: unknown)."""

    request: TrackRequest
    plan: Plan
    total: int | None
    first_image_shape: tuple[int, ...] | None = None  # of frame ``start`` (None: a live source, not opened yet)


def _graph_plan(request: TrackRequest, tracker: Any, source: dict) -> Plan:
    """The tracker's graph for ``request`` with every override, its source stage given ``source``."""
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
    from pipeline.io.frame_readers import count_frames
    from pipeline.runtime.preflight import check_source
    from pipeline.runtime.zygote import preload

    plan = _graph_plan(request, tracker, source_params(request))
    if not request.inline:  # the stage processes' zygote imports their modules meanwhile
        preload(s.kind for s in plan.stages.values())
    sp = msgspec.convert(plan.stages["source"].params, SourceParams)
    if sp.kind == "live":  # opened once, by the source stage (a camera or a listen=1 server serves one client)
        return TrackPlan(request, plan, None)
    first = check_source(sp, request.init)  # readable, start inside it, init on the image: before anything starts
    shape = first.image.shape if first.image is not None else None
    return TrackPlan(request, plan, count_frames(sp), shape)


class PushedRun:
    """The graph of a request run in this process on frames pushed one at a time (the Python API's
    :class:`gflow.Tracker` for a tracker that is not on the protocol), exactly as ``--inline``
    runs it: every message encoded and decoded, delivered in the same order. The source stage
    only validates and stamps the frames it is given (media time at ``request.fps``); no recorder
    runs.

    problems : ``(frame, "stage: kind: message")`` of every error report, in order.
    """

    def __init__(self, request: TrackRequest, tracker: Any) -> None:
        from collections import deque

        from pipeline.runtime.build import make_stage
        from pipeline.runtime.stage_host import StageHost
        from stages.source import SourceStage

        plan = _graph_plan(request, tracker, {"kind": "synthetic", "fps": request.fps, "start": 0, "stop": None})
        self.queue: deque[tuple[str, bytes, int, str]] = deque()
        self.hosts: dict[str, StageHost] = {}
        for name, sp in plan.stages.items():
            if sp.kind == "recorder":
                continue
            try:
                stage = make_stage(plan, name)
            except (OSError, ValueError) as e:
                raise RequestError(f"stage {name}: {e}") from None
            self.hosts[name] = StageHost(stage, sp.inputs, sp.outputs, plan.error_topic, self._publish, ahead=False)
            if isinstance(stage, SourceStage):
                self.source, self.source_stage = self.hosts[name], stage
        self.subscribers: dict[str, list[StageHost]] = {}
        for h in self.hosts.values():
            for topic in h.topics_in.values():
                self.subscribers.setdefault(topic, []).append(h)
        self.estimate_topics = {t for s in plan.stages.values() for p, t in s.outputs.items() if p == "estimate"}
        self.error_topic = plan.error_topic
        self.problems: list[tuple[int, str]] = []

    def _publish(self, topic: str, payload: bytes, seq: int, type_name: str = "") -> None:
        self.queue.append((topic, payload, seq, type_name))

    def _drain(self) -> list[Estimate | PoseEstimate]:
        """Deliver what was published, in order; the estimates among it."""
        out: list[Estimate | PoseEstimate] = []
        while self.queue:
            topic, payload, seq, type_name = self.queue.popleft()
            if topic in self.estimate_topics or topic == self.error_topic:
                msg = decode(payload)
                if isinstance(msg, (Estimate, PoseEstimate)):
                    out.append(msg)
                elif isinstance(msg, ErrorReport):
                    self.problems.append((seq, f"{msg.stage}: {msg.kind}: {msg.message}"))
            for h in self.subscribers.get(topic, ()):
                h.deliver(topic, payload)
        return out

    def push(self, image: Any, t: int) -> list[Estimate | PoseEstimate]:
        """Frame ``t`` (an image, or None: no frame) through the graph; the estimates it produced."""
        from stages.source import RawFrame

        if image is not None:
            src = self.source
            outs = self.source_stage.emit(RawFrame(t, image))
            src._flush_reports()
            src._emit(outs)
        return self._drain()

    def finish(self) -> list[Estimate | PoseEstimate]:
        """End of the frames: every stage closes; the estimates that produced."""
        for h in self.hosts.values():
            h.close("end")
        return self._drain()


@dataclass
class TrackResult:
    """What one run of a :class:`TrackPlan` came to: its estimates by frame and how it went."""

    estimates: dict[int, Any]
    recording: str | None
    seconds: float
    frames: int
    info: dict
    kept: str = ""  # what the user is told about the recording
    temporary: bool = False  # no_record: no recording kept
    lines: list[str] = field(default_factory=list)  # what is missing, coasted, restarted
    incomplete: str = ""  # why the run is incomplete, or ""
    live: LiveSummary | None = None  # a live source's figures: skipped, gaps, latency

    @property
    def frame_of(self) -> dict[int, int]:
        """{sequence number: camera frame} of a live run (empty otherwise: rows are the sequence numbers)."""
        return self.live.frames if self.live is not None else {}

    def columns(self) -> tuple[dict[int, Box], dict[int, float], dict[int, str]]:
        """The CSV's columns by frame: boxes, confidences, target states."""
        boxes, confidence, states = estimate_columns(self.estimates)
        frame_of = self.frame_of
        return renumber(boxes, frame_of), renumber(confidence, frame_of), renumber(states, frame_of)

    def points(self) -> dict:
        """G-flow's face: {frame: (landmark ids (n,), points (n, 2))}, by the reference landmark each vertex came from."""
        frame_of = self.frame_of
        return {frame_of.get(k, k): (v.landmarks.array(), v.mean_points.array()) for k, v in self.estimates.items()
                if getattr(v, "landmarks", None) is not None}

    def write_csv(self, path: str | Path) -> None:
        """The boxes CSV: frame,x,y,w,h,confidence,state (and a live source's input: ok / damaged)."""
        boxes, confidence, states = self.columns()
        write_boxes(path, boxes, confidence, states, self.live.inputs(boxes) if self.live is not None else None)


def run(tp: TrackPlan) -> Generator[Estimate | PoseEstimate, None, TrackResult]:
    """Run a plan (inline or as processes) and yield each estimate as the :class:`EstimateSink`
    takes it from the run, while the run goes on (the graph runs on a thread of its own); at the
    end, any the sink lost that the recording holds, in frame order. The generator's return value
    is the :class:`TrackResult`, whatever happened to the run.

    Closing the generator early (``break`` out of a ``for`` loop, ``close()``) stops the run (as
    :class:`RunStop` says: the stages close, the recording is closed properly) and returns once it
    has stopped; an error of the run is raised from the generator."""
    import queue
    import threading

    items: queue.SimpleQueue = queue.SimpleQueue()
    end = object()
    stop = RunStop()
    outcome: dict[str, Any] = {}

    def work() -> None:
        try:
            outcome["result"] = _execute(tp, items.put, stop)
        except BaseException as e:  # noqa: BLE001 (raised again in the consumer's thread)
            outcome["error"] = e
        finally:
            items.put(end)

    runner = threading.Thread(target=work, name="gflow-run")
    runner.start()
    seen: set[int] = set()
    try:
        while (item := items.get()) is not end:
            seen.add(item.header.seq)
            yield item
    finally:
        if runner.is_alive():  # the consumer stopped early (or was interrupted): end the run
            stop.set()
        runner.join()
    if "error" in outcome:
        raise outcome["error"]
    result: TrackResult = outcome["result"]
    yield from (e for k, e in result.estimates.items() if k not in seen)  # filled in from the recording
    return result


def _execute(tp: TrackPlan, on_estimate: Callable[[Estimate | PoseEstimate], None] | None = None,
             stop: RunStop | None = None) -> TrackResult:
    """Run a plan in this thread: what it came to (``on_estimate``: told of each estimate as the
    sink takes it; ``stop``: ends the run early)."""
    from pipeline.runtime.live_plan import listen_early, live_source, prepare_live
    from pipeline.recording.live_record import live_summary

    req, plan = tp.request, tp.plan
    rec = plan.recorder()
    if rec is not None:  # recordings/track-TIME-RUNID.mcap, named when the run starts (Plan.recording_path)
        rec.params["path"] = "recordings/track-{time}.mcap"
    is_live = live_source(plan) is not None
    # a live run's camera frames and figures are read from its recording (a temporary one with no_record)
    target = RecordingTarget(plan, req.record, req.no_record, req.record_topics, None,
                             needed=("estimate",) if is_live else ())
    prepare_live(plan)  # after the recording: its topics may ask for the skipped frames
    network = req.network
    live = None
    # a UDP source's port, bound before anything starts (what a sender sends first is kept)
    listeners = listen_early(plan, say=None if req.quiet else lambda line: print(line, file=sys.stderr))
    try:
        hosts = place(plan, (), req.inline, req.stream)  # the run's stream names its topics
        sink = EstimateSink((t for s in plan.stages.values() for p, t in s.outputs.items() if p == "estimate"),
                            plan.error_topic, on_estimate)
        path, secs, frames, info = run_graph(plan, inline=req.inline, zenoh=lambda: network or default_zenoh(),
                                             listen_given=req.listen_given, recording=target.path, total=tp.total,
                                             hosts=hosts, quiet=req.quiet, strict=False, sink=sink,
                                             no_record=req.no_record, stop=stop)
        target.written(path)
        out: RunOutcome = run_outcome(path, plan, info, req.start, heard=sink.estimates, reported=sink.reported)
        if is_live and path:
            live = live_summary(path)
    finally:
        target.cleanup()
        for relay in listeners:
            relay.close()
    return TrackResult(estimates=dict(sorted(out.estimates.items())), recording=path, seconds=secs, frames=frames,
                       info=info, kept=target.kept, temporary=target.temporary or path is None,
                       lines=list(out.lines) + (live.lines() if live else []) + [x for r in listeners for x in r.lines()],
                       incomplete=out.why if out.incomplete else "", live=live)


def track(tp: TrackPlan) -> TrackResult:
    """Run a plan to its end in this thread (``gflow track``: Ctrl-C stops it as :func:`run` says)
    and return what it came to."""
    return _execute(tp)


def default_listen() -> tuple[str, ...]:
    """Where a launcher listens unless told: 7447 on loopback (so `gflow topics` finds the run), or
    a free port when 7447 is busy."""
    import socket

    with socket.socket() as s:
        try:
            s.bind(("127.0.0.1", 7447))
            return (DEFAULT_ENDPOINT,)
        except OSError:
            return (f"tcp/127.0.0.1:{free_port()}",)


def default_zenoh() -> ZenohSettings:
    """A run's zenoh settings when none are given: peer mode on loopback, multicast scouting off."""
    return ZenohSettings(mode="peer", listen=default_listen(), connect=(), multicast=False, security=None)
