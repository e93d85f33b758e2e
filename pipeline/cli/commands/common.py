"""Helpers shared by the commands: errors, zenoh options, running a plan."""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time

from pathlib import Path
from typing import Any

import numpy as np

from pipeline.runtime.graph import Plan
from pipeline.runtime.transport import SessionError, ZenohSettings, free_port
from pipeline.cli.endpoints import parse_endpoint
from pipeline.cli.security_options import add_security_args, apply_security

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"


class CliError(Exception):
    """A user error: printed as one line, exit status 2."""


def parse_box(text: str) -> tuple[float, float, float, float]:
    try:
        vals = tuple(float(v) for v in text.replace(" ", "").split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected X,Y,W,H numbers, got {text!r}") from None
    if len(vals) != 4:
        raise argparse.ArgumentTypeError(f"expected 4 numbers X,Y,W,H, got {len(vals)}")
    if not all(np.isfinite(vals)):
        raise argparse.ArgumentTypeError("box has NaN or inf")
    if vals[2] <= 0 or vals[3] <= 0:
        raise argparse.ArgumentTypeError(f"box width and height must be positive, got W={vals[2]}, H={vals[3]}")
    return vals


def positive_float(text: str) -> float:
    """A finite number > 0 (argparse type)."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not (np.isfinite(v) and v > 0):
        raise argparse.ArgumentTypeError(f"must be a number > 0, got {text}")
    return v


def check_outputs(**paths: str | None) -> None:
    """Refuse, before any work, output paths that are folders or cannot be written.

    ``check_outputs(out=args.out, record=args.record)``: each keyword names the option (an
    upper-case keyword, ``FIXED=...``, names a positional argument).
    """
    from pipeline.runtime.preflight import check_writable

    for opt, path in paths.items():
        if path:
            check_writable(path, opt if opt.isupper() else "--" + opt.replace("_", "-"))


def check_stage_values(graph: str, given: dict[str, tuple[str, str, Any]], others: dict[str, dict] | None = None) -> None:
    """Refuse stage parameters given on the command line that the graph's stage would refuse, in the
    words of the options that gave them: ``given`` = {how it was given (``--particles 0``,
    ``--set filter.particles=0``): (stage, parameter, value)}, checked together per stage, on top of
    the graph's values and ``others`` ({stage: {parameter: value}} set otherwise). A stage the graph
    does not have is left to the graph's own error. The same line as ``gflow track --particles 0``,
    with no graph path."""
    from pipeline.runtime.graph import GraphError, load_graph, params_error

    if not given:
        return
    try:
        stages = load_graph(graph).stages
    except GraphError:  # the graph's own fault: said by the load that follows, with the overrides
        return
    for stage in dict.fromkeys(st for st, _, _ in given.values()):
        if stage not in stages:
            continue
        mine = {how: (param, value) for how, (st, param, value) in given.items() if st == stage}
        base = {**stages[stage].params, **(others or {}).get(stage, {})}
        why = params_error(stages[stage].kind, {**base, **{param: value for param, value in mine.values()}})
        if why is not None:  # named by the values refused alone, else by all of them
            alone = [how for how, (param, value) in mine.items() if params_error(stages[stage].kind, {**base, param: value})]
            raise CliError(f"{' '.join(alone or mine)}: {why}")


def sets_as_given(items: list[str] | None) -> dict[str, tuple[str, str, Any]]:
    """Each ``--set stage.param=value`` as :func:`check_stage_values` takes it: {``--set ITEM``: (stage, param, value)}."""
    return {f"--set {it}": (stage, param, value) for it in items or ()
            for stage, kv in parse_sets([it]).items() for param, value in kv.items()}


def parse_sets(items: list[str]) -> dict[str, dict]:
    """``stage.param=value`` (value parsed as YAML: numbers, lists, true/false) -> overrides."""
    import yaml

    out: dict[str, dict] = {}
    for it in items or []:
        if "=" not in it or "." not in it.split("=", 1)[0]:
            raise CliError(f"--set expects stage.param=value, got {it!r}")
        key, val = it.split("=", 1)
        stage, param = key.split(".", 1)
        out.setdefault(stage, {})[param] = yaml.safe_load(val)
    return out


def zenoh_from_args(args, default_connect: bool) -> ZenohSettings:
    security = apply_security(args)
    listen = tuple(args.listen or ())
    connect = tuple(args.connect or ())
    if default_connect and not connect and args.mode != "router":
        connect = (DEFAULT_ENDPOINT,)
    if not listen:
        listen = ("tcp/127.0.0.1:0",)
    return ZenohSettings(mode=args.mode, listen=listen, connect=connect, multicast=args.multicast, security=security)


def tool_zenoh(args, stream: str | None = None, require: bool = True) -> tuple[ZenohSettings, list[dict]]:
    """Settings for a tool joining a live pipeline, and the announcements it connects to.

    With ``--connect`` (or in router / client mode with explicit endpoints) the user's endpoints
    are used. Otherwise the tool connects to every pipeline announced on this machine (of
    ``stream`` when given: see :mod:`pipeline.runtime.running`); with ``require`` and none running it is
    a :class:`CliError` saying so.
    """
    from pipeline.runtime.running import describe_none, running

    security = apply_security(args)
    if args.connect or args.mode == "router" or args.multicast:
        return zenoh_from_args(args, default_connect=False), []
    found = running(stream)
    if not found and require:
        raise CliError(describe_none(stream))
    endpoints = tuple(dict.fromkeys(e for i in found for e in i.get("endpoints", [])))
    listen = tuple(args.listen or ()) or ("tcp/127.0.0.1:0",)
    return ZenohSettings(mode=args.mode, listen=listen, connect=endpoints, multicast=False, security=security), found


def stream_of(key: str) -> str | None:
    """The stream named by a key expression ``gflow/<stream>/...`` (None for a wildcard)."""
    parts = key.split("/")
    if len(parts) >= 2 and parts[0] == "gflow" and parts[1] and "*" not in parts[1] and "$" not in parts[1]:
        return parts[1]
    return None


def launcher_zenoh(args) -> ZenohSettings:
    """The launcher listens on 7447 (so `gflow topics` finds it) unless busy or told otherwise."""
    security = apply_security(args)
    if args.listen:
        listen = tuple(args.listen)
    else:
        import socket

        with socket.socket() as s:
            try:
                s.bind(("127.0.0.1", 7447))
                listen = (DEFAULT_ENDPOINT,)
            except OSError:
                listen = (f"tcp/127.0.0.1:{free_port()}",)
    return ZenohSettings(mode=args.mode, listen=listen, connect=tuple(args.connect or ()), multicast=args.multicast,
                         security=security)


def add_record_args(p: argparse.ArgumentParser, default: str) -> None:
    """``--record FILE``, ``--no-record`` and ``--record-topics PATTERN``."""
    g = p.add_mutually_exclusive_group()
    g.add_argument("--record", metavar="FILE", help=f"recording path (default {default})")
    g.add_argument("--no-record", action="store_true",
                   help="keep no recording (results are still written; a re-run, replay or render needs one)")
    p.add_argument("--record-topics", action="append", metavar="PATTERN[,PATTERN]",
                   help="record only these topics, as shell patterns on the name after gflow/STREAM/, e.g. "
                        "'estimate,particles' or '*' (errors and heartbeats are always kept; raw frames are "
                        "most of a recording's size)")


class Recording:
    """Where a run records, from ``--record / --no-record / --record-topics``.

    ``needed`` are topics the command reads back after the run (``track`` reads the estimates):
    they are always recorded, and with ``--no-record`` they go to a temporary file that
    :meth:`cleanup` deletes. ``path`` is what to pass to the launcher (None: no recorder).
    """

    def __init__(self, plan: Plan, args, default: str | None, needed: tuple[str, ...] = ()) -> None:
        import tempfile

        self.tmpdir: str | None = None
        self.temporary = False
        rec = plan.recorder()
        pats = [p.strip() for item in (getattr(args, "record_topics", None) or []) for p in item.split(",") if p.strip()]
        if rec is None:
            if pats or needed:
                raise CliError(f"the graph {plan.name!r} has no recorder stage, so there is nothing to "
                               + ("select topics of" if pats else "read the results from"))
            self.path = None
            return
        if getattr(args, "no_record", False):
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
        self.path = getattr(args, "record", None) or default
        from pipeline.io.recording_files import refuse_existing
        from pipeline.runtime.preflight import check_writable

        if self.path:  # a recording never overwrites a file (the recorder also creates it exclusively)
            refuse_existing(self.path, "--record" if getattr(args, "record", None) else "the recording")
        path = self.path or plan.recording_path()  # None: named when the run starts, with its run id
        assert path is not None  # the plan has its recorder
        given = bool(getattr(args, "record", None))  # the default recordings/ folder is made; a typed one must exist
        check_writable(path, "--record" if given else "the recording", make_folder=not given)  # before any work

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


def add_zenoh_args(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("zenoh network (default: peer mode on loopback, multicast scouting off)")
    g.add_argument("--mode", choices=["peer", "client", "router"], default="peer", help="zenoh session mode")
    g.add_argument("--listen", action="append", metavar="ENDPOINT", type=parse_endpoint,
                   help="endpoint to listen on, e.g. tcp/0.0.0.0:7447 (repeatable)")
    g.add_argument("--connect", action="append", metavar="ENDPOINT", type=parse_endpoint,
                   help="endpoint to connect to, e.g. tcp/10.0.0.5:7447 for a zenoh router (repeatable)")
    g.add_argument("--multicast", action="store_true", help="enable multicast scouting (off by default)")
    add_security_args(p.add_argument_group("security (TLS, login, signed runs: docs/security.md)"))


def add_placement_args(p: argparse.ArgumentParser, hosts: bool = True) -> None:
    """``--stream NAME`` (the run's stream; default: the graph's plus a new run id) and, for
    ``gflow run``, ``--host LABEL`` (repeatable: start only the stages placed there)."""
    g = p.add_argument_group("placement and run id (docs/deployment.md)")
    g.add_argument("--stream", metavar="NAME",
                   help="this run's stream: topics are gflow/NAME/... (default: the graph's stream plus a new run id, "
                        "so two runs never mix; with --host, the graph's stream: give every host the same NAME)")
    if hosts:
        g.add_argument("--host", action="append", metavar="LABEL", dest="hosts",
                       help="start only the stages placed on this host (host: LABEL in the graph; repeatable); "
                            "without it every stage runs here")


def place(plan: Plan, args) -> tuple[str, ...]:
    """Check ``--host`` against the whole graph and choose the run's stream (see
    :mod:`pipeline.runtime.runid`); return the host labels this process runs."""
    from pipeline.runtime.placement import local_stages
    from pipeline.runtime.runid import choose_stream

    hosts = tuple(getattr(args, "hosts", None) or ())
    local_stages(plan, hosts)  # an unknown label: one line naming the graph's labels
    if hosts and getattr(args, "inline", False):
        raise CliError("--host runs the stages placed on this host as processes; it cannot be combined with --inline")
    if getattr(args, "inline", False) and not getattr(args, "stream", None):
        return hosts  # one process, no network: nothing to mix with
    choose_stream(plan, getattr(args, "stream", None), placed=bool(hosts))
    return hosts


def temporary_recording(path: str | None) -> bool:
    """A recording :class:`Recording` made for ``--no-record`` (read back, then removed)."""
    return bool(path) and Path(str(path)).parent.name.startswith("gflow-norecord-")


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


def run_plan(plan: Plan, args, recording: str | None, total: int | None, quiet: bool = False, strict: bool = True):
    """Run a plan inline or as processes; return (recording path, seconds, frames, per-stage info).
    With ``strict=False`` a run that did not finish cleanly returns (``info["ok"]`` False) instead of
    raising, so the caller can keep what was tracked."""
    hosts = place(plan, args)
    if getattr(args, "inline", False):
        from pipeline.runtime.inline import run_inline

        last = [0.0]

        def progress(n: int) -> None:
            now = time.monotonic()
            if not quiet and now - last[0] > 1.0:
                last[0] = now
                print(f"  {n}" + (f"/{total}" if total else "") + " frames", file=sys.stderr)

        md = {"gflow.graph": {"name": plan.name, "stream": plan.stream, "yaml": plan.source_text},
              "gflow.config": plan.config_metadata()}
        r = run_inline(plan, progress=progress, recording=recording, metadata=md)
        bad = {n: e for n, e in r.errors.items() if e}
        return r.recording, r.seconds, r.frames, {"mode": "inline", "steps": r.steps, "errors": bad}
    from pipeline.runtime.launcher import Launcher
    from pipeline.runtime.running import announce
    from pipeline.runtime.zygote import preload

    preload(s.kind for s in plan.stages.values())  # the stage processes' zygote imports their modules (once)

    zenoh = launcher_zenoh(args)
    while True:
        launcher = Launcher(plan, zenoh=zenoh, recording=recording, progress=not quiet,
                            total_frames=total, hosts=hosts, say_recording=not temporary_recording(recording))
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
                      camera=plan.seed_stream, no_record=temporary_recording(recording),
                      recording=(launcher.recording if rec and rec.name in launcher.local
                                 and not temporary_recording(recording) else None)):
            try:
                res = launcher.run()
            except SessionError as e:  # 7447, free a moment ago, taken by a run started at the same time
                if args.listen or zenoh.listen != (DEFAULT_ENDPOINT,) or "in use" not in str(e):
                    raise CliError(str(e)) from None
                zenoh = dataclasses.replace(zenoh, listen=(f"tcp/127.0.0.1:{free_port()}",))
                continue  # nothing had started: the session is the launcher's first step
            except RuntimeError as e:  # start-up: a stage died, a host did not come, the stream is taken
                raise CliError(_startup_failure(plan, launcher, str(e))) from None
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
    if res.stall:
        print(res.stall, file=sys.stderr)
    unsigned = {n: st.rejected["unsigned"] for n, st in res.status.items() if st.rejected.get("unsigned")}
    if unsigned:  # --run-key: what came from outside the run was dropped; say so
        info["unsigned"] = unsigned
        print("ignored messages not signed with the run key (from outside the run), by stage: "
              + ", ".join(f"{n} {c}" for n, c in sorted(unsigned.items())), file=sys.stderr)
    if strict and not res.ok and not res.interrupted:
        raise CliError("the pipeline did not finish cleanly (see the messages above)")
    return res.recording, res.seconds, frames, info


