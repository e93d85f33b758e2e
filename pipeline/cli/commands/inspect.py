"""``gflow ps``, ``gflow topics``, ``gflow echo``, ``gflow hz``, ``gflow pub``: look at (and poke)
a live pipeline.

Without ``--connect`` the tools join the pipelines announced on this machine (see
:mod:`pipeline.runtime.running`) and say so, with a non-zero exit, when none is running.
"""

from __future__ import annotations

ORDER = 60

import argparse
import json
import sys
import time
from typing import Any, cast

from pipeline.cli.commands.common import (CliError, add_zenoh_args, nonnegative_int, positive_float, positive_int,
                                          stream_name, stream_of, tool_zenoh, whole_number)


def _run_stream(stream: str) -> str:
    """A stream as given, or, when it names a graph's stream (``demo``) while one run of that
    graph runs (``demo-3f9c2a``: every run has its own stream), that run's stream."""
    from pipeline.runtime.running import runs_of_camera, running

    if running(stream):
        return stream
    runs = runs_of_camera(stream)
    if len(runs) > 1:
        raise CliError(f"several runs of stream {stream!r} are running ({', '.join(r['stream'] for r in runs)}): "
                       f"name one")
    if runs:
        print(f"(stream {stream}: the running run {runs[0]['stream']})", file=sys.stderr)
        return runs[0]["stream"]
    return stream


def _in_stream(topic: str) -> bool:
    """A topic typed as the name inside a stream: ``estimate``, ``_status/filter`` (the names with
    a ``/`` inside a stream all start with ``_``); ``cam0/estimate`` names its stream."""
    return not topic.startswith("gflow/") and ("/" not in topic or topic.startswith("_"))


def _key_expr(topic: str) -> str:
    """A topic as typed, with shell wildcards, as a zenoh key expression (``est*`` -> ``est$*``); zenoh's own
    ``$*``, typed as such, is kept (it was escaped again, to ``$$*``, and refused as malformed), and wildcards
    side by side are one (zenoh refuses ``$*$*``)."""
    import re

    def chunk(c: str) -> str:
        if c in ("*", "**"):
            return c
        c = "$*".join(part.replace("*", "$*").replace("?", "$*") for part in c.split("$*"))
        return re.sub(r"(?:\$\*){2,}", "$*", c)
    return "/".join(chunk(c) for c in topic.split("/"))


def _check_topic(topic: str) -> None:
    """Refuse, before any wait, a topic that makes no zenoh key expression (``''``, ``x//y``, ``a#b``,
    ``a/**/**/b``): the subscriber would raise only once a pipeline had been waited for and joined. The
    key is checked as :func:`_topic` and :func:`_key_expr` build it, with any stream in the place of one not
    yet resolved."""
    from pipeline.runtime.transport import check_key_expr

    if not topic.strip():
        raise CliError(f"topic {topic!r} is empty: give one, e.g. estimate, gflow/cam0/estimate or cam0/**")
    key = _key_expr(f"gflow/*/{topic}" if _in_stream(topic) else topic if topic.startswith("gflow/")
                    else f"gflow/{topic}")
    try:
        check_key_expr(key)
    except ValueError as e:
        raise CliError(f"topic {topic!r} is malformed (key expression {key}): {e}") from None


def _topic(topic: str) -> str:
    """The full name of a topic as the user typed it (pipeline/recording/topics.py), wildcards as typed: the
    name in the stream (``estimate``: of the one pipeline running, or of any while none or several run),
    the full name with or without ``gflow/`` and with or without the run id (STREAM resolved by
    :func:`_run_stream`). What the messages name; zenoh is given its :func:`_key_expr`."""
    from pipeline.runtime.running import running

    if _in_stream(topic):  # of the one pipeline running, or of any while none or several run
        streams = sorted({str(i.get("stream")) for i in running()})
        return f"gflow/{streams[0] if len(streams) == 1 else '*'}/{topic}"
    key = topic if topic.startswith("gflow/") else f"gflow/{topic}"
    stream = stream_of(key)
    if stream is None:
        return key
    parts = key.split("/", 2)
    return "/".join(["gflow", _run_stream(stream), *parts[2:]])


def _await_pipeline(args, topic: str | None, wait: float) -> bool:
    """Wait up to ``wait`` s for a pipeline to be announced on this machine (of the stream ``topic``
    names, if it names one), so a tool started before its run does not give up at once. False when
    none came within ``wait`` s (:func:`_none_came`); True otherwise, also when there is nothing to
    wait for (no ``wait``, or endpoints given: the tool does not look for an announced pipeline)."""
    from pipeline.runtime.running import await_running

    if wait <= 0 or args.connect or args.mode == "router" or args.multicast:
        return True
    stream = stream_of(topic if topic.startswith("gflow/") else f"gflow/{topic}") if topic and not _in_stream(
        topic) else None
    if await_running(stream, until=time.monotonic()):
        return True
    print(f"waiting up to {wait:g} s for a pipeline" + (f" of stream {stream}" if stream else "") + " to start",
          file=sys.stderr, flush=True)
    return await_running(stream, until=time.monotonic() + wait)


def _none_came(tool: str, topic: str, seconds: float) -> int:
    """Exit 1, saying in one line that no message came on ``topic`` in the ``seconds`` waited for a pipeline
    to start, and what runs instead: a wait that ran out is an answer, as a topic that stays silent is (exit
    1), not a mistake in the command line (exit 2: a malformed topic, a stream not running and not waited for)."""
    from pipeline.runtime.running import describe_none

    name = _topic(topic)
    print(f"gflow {tool}: no message on {name} in {seconds:g} s: {describe_none(stream_of(name))}", file=sys.stderr)
    return 1


def _say_where(found: list[dict]) -> None:
    for i in found:
        print(f"(pipeline {i.get('name')}, stream {i.get('stream')}, pid {i.get('pid')}, "
              f"at {', '.join(i.get('endpoints', []))})", file=sys.stderr)


def cmd_topics(args) -> int:
    from pipeline.cli.live import list_topics

    if args.stream:
        args.stream = _run_stream(args.stream)
    settings, found = tool_zenoh(args, args.stream)
    _say_where(found)
    key = f"gflow/{args.stream}/**" if args.stream else "gflow/**"
    counts = list_topics(settings, args.duration, out=sys.stdout, key=key, as_json=args.json, wait=args.wait)
    return 0 if counts else 1


def _heard_instead(settings, key: str, seconds: float = 1.5) -> str:
    """What the stream of ``key`` publishes, listened to for ``seconds``: the end of the line that
    says nothing came on ``key``, so that a mistyped topic is plain (``; gflow/cam0/ has: estimate,
    frames, ...``)."""
    import io

    from pipeline.cli.live import list_topics

    parts = key.split("/")
    prefix = "/".join(parts[:2]) + "/" if len(parts) > 2 and "*" not in parts[1] else "gflow/"
    counts = list_topics(settings, seconds, out=io.StringIO(), key=prefix + "**", as_json=True)
    names = sorted(k[len(prefix):] for k in counts  # the heartbeats left out: every stage has one
                   if not any(c == "_status" or c.startswith("@") for c in k.split("/")))
    if not names:
        return f"; nothing heard on {prefix}** in {seconds:g} s either"
    return f"; {prefix} has: " + ", ".join(names[:30]) + (", ..." if len(names) > 30 else "")


def cmd_echo(args) -> int:
    from pipeline.cli.live import echo

    _check_topic(args.topic)
    t0 = time.monotonic()  # --timeout bounds the whole wait: for a pipeline to start, then for its messages
    if not _await_pipeline(args, args.topic, args.timeout or 0.0):
        return _none_came("echo", args.topic, args.timeout)
    name = _topic(args.topic)  # as typed, in the messages; zenoh is given its key expression
    key = _key_expr(name)
    settings, found = tool_zenoh(args, stream_of(key))
    if not args.json:
        _say_where(found)
    n = echo(settings, key, args.count, args.timeout, as_json=args.json, since=t0, name=name)
    if n == 0:
        print(f"gflow echo: no message on {name}" + (f" in {args.timeout:g} s" if args.timeout else "")
              + (_heard_instead(settings, key) if args.timeout else ""), file=sys.stderr)
        return 1
    return 0


def cmd_hz(args) -> int:
    from pipeline.cli.live import hz

    if args.window is not None and args.window < 1:
        raise CliError(f"--window must be at least 1 gap, got {args.window}")
    _check_topic(args.topic)
    t0 = time.monotonic()  # --wait bounds the whole wait: for a pipeline to start, then for its first message
    if not _await_pipeline(args, args.topic, args.wait):  # --wait: also for a run that has not started yet
        return _none_came("hz", args.topic, args.wait)
    name = _topic(args.topic)  # as typed, in the messages; zenoh is given its key expression
    key = _key_expr(name)
    settings, found = tool_zenoh(args, stream_of(key))
    _say_where(found)
    st = hz(settings, key, args.duration, wait=args.wait, window=args.window, since=t0, name=name)
    if st is None:
        print(f"gflow hz: fewer than 2 messages on {name} (waited {args.wait:g} s for the first)"
              + _heard_instead(settings, key), file=sys.stderr)
        return 1
    return 0


def _stage_states(settings, streams: list[str], seconds: float,
                  expect: dict[str, set[str]] | None = None) -> dict[str, dict]:
    """{stream: {stage: StageStatus}} heard on the heartbeats within ``seconds``, or until every stage
    ``expect`` names ({stream: stages}) has been heard (each stage's first heartbeat then)."""
    import queue

    from gflow_msgs.messages import MessageError, StageStatus, decode

    from pipeline.runtime.transport import Bus, open_session

    s = open_session(settings)
    q: queue.SimpleQueue = queue.SimpleQueue()
    bus = Bus(s)
    for st in streams:
        bus.subscribe(f"gflow/{st}/_status/*", lambda k, p, ns, seq: q.put(p))
    out: dict[str, dict] = {st: {} for st in streams}
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        try:
            p = q.get(timeout=0.05)
        except queue.Empty:
            continue
        try:
            m = decode(p)
        except MessageError:
            continue
        if isinstance(m, StageStatus):
            out.setdefault(m.header.stream, {})[m.stage] = m
            if expect and all(names <= set(out.get(st, {})) for st, names in expect.items()):
                break
    s.close()
    return out


def _user(uid: int) -> str:
    try:
        import pwd

        return pwd.getpwuid(uid).pw_name
    except (ImportError, KeyError):
        return str(uid)


def cmd_ps(args) -> int:
    from pipeline.runtime.running import describe_none, running, runtime_dir

    found = running(args.stream, everyone=args.all)
    if not found:
        others = [] if args.all else running(args.stream, everyone=True)
        why = describe_none(args.stream) + (f" ({len(others)} of other users: gflow ps --all)" if others else "")
        if args.stream:  # a stream named that is not running: the user's mistake (a typo), said as topics/echo say it
            raise CliError(why)
        print(why, file=sys.stderr)  # nothing running at all: the answer, not a mistake (exit 1, as before)
        return 1
    if args.json:
        rows = []
    for info in found:
        settings, _ = tool_zenoh(argparse.Namespace(connect=info["endpoints"], listen=None, mode="peer",
                                                    multicast=False), require=False)
        stages = set(info.get("stages") or ())
        states = _stage_states(settings, [info["stream"]], args.listen_for,
                               {info["stream"]: stages} if stages else None).get(info["stream"], {})
        if args.json:
            rows.append(dict(info, states={n: {"state": st.state, "steps": st.steps, "fps": st.fps,
                                                "last_seq": st.last_seq, "errors": st.errors, "rss_mb": st.rss_mb,
                                                "pid": st.pid} for n, st in states.items()}))
            continue
        up = time.time() - float(info.get("started", time.time()))
        print(f"{info.get('kind', 'pipeline')} {info.get('name')}  stream {info['stream']}  pid {info['pid']}  "
              f"up {up:.0f} s  at {', '.join(info['endpoints'])}" + (f"  user {_user(info['uid'])}" if args.all else "")
              + ("  not recording (--no-record)" if info.get("no_record")
                 else f"  recording {info['recording']}" if info.get("recording") else ""))
        for name in info.get("stages") or sorted(states):
            st = states.get(name)
            if st is None:
                print(f"  {name:14s} {'(no heartbeat)':10s}")
            else:
                print(f"  {name:14s} {st.state:10s} steps {st.steps:6d}  last frame {st.last_seq:6d}  "
                      f"{st.fps:6.1f} fps  {st.rss_mb:6.0f} MB  pid {st.pid}"
                      + (f"  errors {st.errors}" if st.errors else ""))
    if args.json:
        print(json.dumps(rows, indent=1))
    if args.verbose_dir:
        print(f"(announcements in {runtime_dir()})", file=sys.stderr)
    return 0


def cmd_pub(args) -> int:
    import msgspec

    from gflow_msgs.messages import MESSAGE_TYPES, Header, encode

    from pipeline.runtime.security import Signer
    from pipeline.runtime.transport import Bus, open_reaching

    _check_topic(args.topic)
    name = _topic(args.topic)  # as typed, in the messages; zenoh is given its key expression
    key = _key_expr(name)
    typ = MESSAGE_TYPES.get(args.type)
    if typ is None:
        raise CliError(f"unknown message type {args.type!r} (known: {', '.join(sorted(MESSAGE_TYPES))})")
    try:
        fields = json.loads(args.fields) if args.fields else {}
    except json.JSONDecodeError as e:
        raise CliError(f"FIELDS is not valid JSON: {e}") from None
    if not isinstance(fields, dict):
        raise CliError("FIELDS must be a JSON object, e.g. '{\"command\": \"stop\"}'")
    stream = stream_of(key)
    if stream is None:
        raise CliError(f"publish on a concrete topic gflow/<stream>/<name>, not {name!r}")
    _refuse_unknown_fields(fields, typ, Header, args.type)
    fields.setdefault("header", {})
    fields["header"] = dict({"stream": stream, "seq": args.seq, "stamp_ns": time.time_ns()}, **fields["header"])
    try:
        msg: Any = msgspec.convert(fields, typ)  # the message type named on the command line
    except msgspec.ValidationError as e:
        raise CliError(f"not a valid {args.type}: {e}") from None
    assert isinstance(msg.header, Header)
    settings, found = tool_zenoh(args, stream)
    # an endpoint that leads nowhere opens without error: said here (exit 2, as topics, echo and hz say it), not
    # taken for "no subscriber"
    s = open_reaching(settings)
    try:
        bus = Bus(s, signer=Signer.of(settings.security))
        pub = bus.publisher(key)
        end = time.monotonic() + args.wait
        # zenoh's stub says matching_status is a bool; it is a MatchingStatus, whose .matching is the bool
        while not cast(Any, pub.matching_status).matching:
            if time.monotonic() > end:  # nothing arrived: an answer (exit 1), as echo's silent topic, not a mistake
                print(f"gflow pub: no subscriber of {name} appeared within {args.wait:g} s; nothing sent",
                      file=sys.stderr)
                return 1
            time.sleep(0.02)
        for i in range(args.count):
            if i:
                time.sleep(1.0 / args.rate)
            bus.publish(key, encode(msg), msg.header.seq, args.type)
        time.sleep(0.2)  # let the samples leave before the session closes
    finally:
        s.close()
    print(f"published {args.count} {args.type} on {name}", file=sys.stderr)
    return 0


#: the commands a stage acts on (pipeline.runtime.node_base): another is logged and ignored by every stage
CONTROL_COMMANDS = ("start", "stop")


def _refuse_unknown_fields(fields: dict, typ: type, header: type, name: str) -> None:
    """A field of FIELDS (or of its header) that message type ``typ`` does not have (``{"comand": "stop"}``,
    ``{"header": {"sq": 5}}``): msgspec drops it, and the message went out without it, without a word; and a
    Control command no stage acts on (``{"command": "halt"}``), which every stage logged and ignored."""
    import msgspec
    import msgspec.inspect

    for given, struct, where in ((fields, typ, name), (fields.get("header"), header, f"{name}'s header")):
        if not isinstance(given, dict):
            continue
        known = [f.name for f in msgspec.structs.fields(struct)]
        tag = getattr(msgspec.inspect.type_info(struct), "tag_field", None)  # "type" of a tagged message
        unknown = [k for k in given if k not in known and k != tag]
        if unknown:
            raise CliError(f"FIELDS: {where} has no field {unknown[0]!r} (its fields: {', '.join(known)})")
    if name == "Control" and fields.get("command") not in (None, *CONTROL_COMMANDS):
        raise CliError(f"FIELDS: no stage acts on Control command {fields['command']!r} (known: "
                       f"{', '.join(CONTROL_COMMANDS)})")


def register(sub) -> None:
    p = sub.add_parser("ps", help="list the running pipelines and the state of their stages",
                       description="Lists the user's pipelines (and replays) running on this machine, as announced "
                                   "in the user's runtime folder, with each stage's state, progress, rate and memory "
                                   "from its heartbeat.")
    p.add_argument("--stream", type=stream_name, help="only the pipeline of this stream")
    p.add_argument("--all", action="store_true", help="also other users' pipelines (a runtime folder they share)")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.add_argument("--listen-for", type=positive_float, default=1.2, metavar="S",
                   help="seconds to collect heartbeats, at most: it ends once every stage of the pipeline has "
                        "been heard (default 1.2; stages beat every 0.5 s)")
    p.add_argument("--where", dest="verbose_dir", action="store_true", help="also say where the announcements are")
    p.set_defaults(func=cmd_ps)

    p = sub.add_parser("topics", help="list the topics of a live pipeline",
                       description="Listens on gflow/** for a while and prints each topic with its message type, "
                                   "count, rate and bandwidth. Without --connect it joins the pipelines running on "
                                   "this machine.")
    p.add_argument("--duration", type=positive_float, default=2.0,
                   help="seconds to listen, from the first message (default 2)")
    p.add_argument("--wait", type=positive_float, default=10.0,
                   help="seconds to wait for the first message, e.g. while a pipeline just started comes up "
                        "(default 10)")
    p.add_argument("--stream", type=stream_name, help="only the pipeline of this stream (when several run)")
    p.add_argument("--json", action="store_true", help="print JSON: type, messages, rate_hz, bytes_per_s per topic")
    add_zenoh_args(p)
    p.set_defaults(func=cmd_topics)

    p = sub.add_parser("echo", help="print the messages on a live topic",
                       description="Prints each message on a topic as it arrives: its type, frame number and small "
                                   "fields (arrays as dtype and shape), or one JSON object per line with --json. "
                                   "Exits 1 when no message came.",
                       epilog="examples:\n  gflow echo gflow/demo/estimate -n 5\n  gflow echo demo/_status/* --json "
                              "--timeout 2\n\n"
                              "exit status:\n  0  messages came (or Ctrl-C after at least one)\n"
                              "  1  no message came: within --timeout (also when no pipeline started in that time), "
                              "or before Ctrl-C\n"
                              "  2  a mistake in the command: a malformed topic, a stream that is not running (without "
                              "--timeout,\n     which waits for it), an endpoint that reaches nothing, a bad option",
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("topic", help="the name in the stream (estimate), the full name with or without the run id "
                                 "(gflow/cam0/estimate), or a pattern (cam0/**, _status/*)")
    p.add_argument("-n", "--count", type=positive_int, help="stop after N messages")
    p.add_argument("--timeout", type=positive_float, metavar="S",
                   help="stop after S seconds in all, counted from the start, a wait for the pipeline to start "
                        "included (when no message came, the error names the topics the stream has, listened to "
                        "for 1.5 s more)")
    p.add_argument("--json", action="store_true", help="one JSON object per message (small arrays as lists)")
    add_zenoh_args(p)
    p.set_defaults(func=cmd_echo)

    p = sub.add_parser("hz", help="measure the rate of a live topic",
                       description="Waits for the first message, then prints every second the average rate and the "
                                   "min / max / standard deviation of the gaps between messages, over a rolling "
                                   "window (like ros2 topic hz). Exits 1 when fewer than 2 messages came (also when "
                                   "no pipeline started within --wait), 2 at a mistake in the command (a malformed "
                                   "topic, a bad option).")
    p.add_argument("topic", help="the name in the stream (frames), the full name with or without the run id "
                                 "(gflow/cam0/frames), or a pattern")
    p.add_argument("--duration", type=positive_float, help="stop after this many seconds (default: until Ctrl-C)")
    p.add_argument("--window", type=whole_number, metavar="N", help="statistics over the last N gaps (default: all)")
    p.add_argument("--wait", type=positive_float, default=10.0, metavar="S",
                   help="wait up to S seconds in all for the first message, counted from the start, a wait for the "
                        "pipeline to start when none runs yet included (default 10)")
    add_zenoh_args(p)
    p.set_defaults(func=cmd_hz)

    p = sub.add_parser("pub", help="publish one message (or a few) on a live topic",
                       description="Builds a gflow message from JSON fields (the header is filled in: stream from the "
                                   "topic, --seq, the current time), waits until the topic has a subscriber, and "
                                   "publishes it.",
                       epilog="example: gflow pub gflow/demo/_control Control '{\"command\": \"stop\"}'\n\n"
                              "exit status:\n  0  sent\n"
                              "  1  no subscriber of the topic appeared within --wait, or nothing was reached at "
                              "the endpoints: nothing sent\n"
                              "  2  a mistake in the command: a malformed topic, an unknown type, FIELDS that are not "
                              "the type's,\n     a stream that is not running (without --connect), a bad option",
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("topic", help="topic, e.g. gflow/cam0/_control")
    p.add_argument("type", help="message type, e.g. Control, Estimate")
    p.add_argument("fields", nargs="?", help="JSON object of the message's fields (default {})")
    p.add_argument("--seq", type=nonnegative_int, default=0, help="header sequence number (default 0)")
    p.add_argument("-n", "--count", type=positive_int, default=1, help="how many times to publish (default 1)")
    p.add_argument("--rate", type=positive_float, default=1.0, help="messages per second with -n > 1 (default 1)")
    p.add_argument("--wait", type=positive_float, default=5.0, help="seconds to wait for a subscriber (default 5)")
    add_zenoh_args(p)
    p.set_defaults(func=cmd_pub)
