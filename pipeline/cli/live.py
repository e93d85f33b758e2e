"""Inspect a live pipeline: ``gflow topics``, ``gflow echo``, ``gflow hz``, and ``gflow replay``."""

from __future__ import annotations

import queue
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, TextIO

from gflow_msgs.messages import Capture, MessageError, StageStatus, decode

from pipeline.io.mcap_io import iter_records
from pipeline.recording.plain import describe, to_plain
from pipeline.runtime.graph import PROGRESS
from pipeline.runtime.multihost import replay_token
from pipeline.runtime.security import Signer
from pipeline.runtime.transport import Bus, ZenohSettings, open_reaching

__all__ = ["list_topics", "echo", "hz", "rate_stats", "RateStats", "json_line", "replay", "ReplayOptions",
           "StreamInUse"]


def _session(settings: ZenohSettings):
    """A session for a live tool; reaching nothing at its ``connect`` endpoints is an error."""
    return open_reaching(settings)


def list_topics(settings: ZenohSettings, duration: float, out: TextIO = sys.stdout, key: str = "gflow/**",
                as_json: bool = False, wait: float = 0.0) -> dict[str, int]:
    """Listen on ``key`` for ``duration`` seconds and print each topic with its type, count, rate and
    bandwidth (one JSON object with ``as_json``). With ``wait``, the ``duration`` starts at the first
    message, waited for up to ``wait`` s (a pipeline just started may take seconds to beat)."""
    s = _session(settings)
    counts: dict[str, int] = {}
    nbytes: dict[str, int] = {}
    types: dict[str, str] = {}
    q: queue.SimpleQueue = queue.SimpleQueue()
    bus = Bus(s)
    bus.subscribe(key, lambda k, p, ns, seq: q.put((k, p)))
    first: list[tuple[str, bytes]] = []
    end = time.monotonic() + duration
    if wait > 0:
        try:
            first.append(q.get(timeout=wait))
            end = time.monotonic() + duration
        except queue.Empty:
            end = 0.0  # nothing came
    while first or time.monotonic() < end:
        if first:
            k, p = first.pop()
        else:
            try:
                k, p = q.get(timeout=0.05)
            except queue.Empty:
                continue
        counts[k] = counts.get(k, 0) + 1
        nbytes[k] = nbytes.get(k, 0) + len(p)
        if k not in types:
            try:
                types[k] = type(decode(p)).__name__
            except MessageError:
                types[k] = "?"
    s.close()
    if as_json:
        import json

        print(json.dumps({k: {"type": types[k], "messages": counts[k], "rate_hz": counts[k] / duration,
                              "bytes_per_s": nbytes[k] / duration} for k in sorted(counts)}, indent=1), file=out)
        return counts
    if not counts:
        print(f"no messages on {key} in {max(wait, duration):.1f} s (is a pipeline running, and reachable at "
              f"{', '.join(settings.connect) or 'the default endpoint'}?)", file=sys.stderr)
    for k in sorted(counts):
        print(f"{k:45s} {types[k]:18s} {counts[k]:6d} msgs  {counts[k] / duration:7.1f} Hz  "
              f"{nbytes[k] / duration / 1024:9.1f} KiB/s", file=out)
    return counts


def json_line(key: str, payload: bytes, pub_ns: int) -> str:
    """One JSON object per message: topic, publish time and the decoded message."""
    import json

    try:
        m = to_plain(decode(payload))
    except MessageError as e:
        m = {"error": str(e)}
    return json.dumps({"topic": key, "publish_ns": pub_ns, "message": m}, allow_nan=False, default=str)


def echo(settings: ZenohSettings, key: str, count: int | None, timeout: float | None, out: TextIO = sys.stdout,
         as_json: bool = False, since: float | None = None, name: str | None = None) -> int:
    """Print messages on ``key`` (a key expression) as they arrive; returns how many. ``timeout`` (s) counts
    from ``since`` (a ``time.monotonic()``: the caller's start, so that what it waited for before, a
    pipeline to start, is part of it), or from the call. ``name``: the topic as the user typed it, for
    the messages (default ``key``)."""
    begun = time.monotonic()
    end = None if timeout is None else (begun if since is None else since) + timeout
    s = _session(settings)
    q: queue.SimpleQueue = queue.SimpleQueue()
    Bus(s).subscribe(key, lambda k, p, ns, seq: q.put((k, p, ns)))
    n = 0
    start = time.monotonic()
    told = False
    try:
        while count is None or n < count:
            if end is not None and time.monotonic() > end:
                break
            if not told and n == 0 and time.monotonic() - start > 2.0:
                print(f"waiting for messages on {name or key} (Ctrl-C to stop)", file=sys.stderr, flush=True)
                told = True
            try:
                k, p, ns = q.get(timeout=0.1)
            except queue.Empty:
                continue
            n += 1  # counted first: a Ctrl-C right after the line is printed must not say none came
            print(json_line(k, p, ns) if as_json else f"{k}: {describe(p)}", file=out, flush=True)
    except KeyboardInterrupt:
        pass
    finally:
        s.close()
    return n


@dataclass
class RateStats:
    """Rate over a window of arrival gaps (what ``ros2 topic hz`` prints); for messages stamped
    by a live source, also the latency from capture to arrival here and the frames it skipped."""

    messages: int
    rate_hz: float
    min_ms: float
    max_ms: float
    std_ms: float
    window: int
    latency_p50_ms: float = float("nan")
    latency_p99_ms: float = float("nan")
    skipped: int = -1  # frames the live source skipped over the window (-1: not a live source)
    captured: int = 0

    def line(self, key: str) -> str:
        out = (f"{key}: average rate {self.rate_hz:.2f} Hz  min {self.min_ms:.1f} ms  max {self.max_ms:.1f} ms  "
               f"std dev {self.std_ms:.2f} ms  window {self.window}")
        if self.latency_p50_ms == self.latency_p50_ms:  # not NaN
            out += f"  latency p50 {self.latency_p50_ms:.1f} ms p99 {self.latency_p99_ms:.1f} ms"
        if self.skipped >= 0:
            out += f"  skipped {self.skipped} of {self.captured} frames captured"
        return out


#: stamps after 2001-09-09 (1e18 ns since 1970) are the host clock; a file's media time starts at 0
HOST_CLOCK_NS = 10**18


def _stamp_of(payload: bytes) -> int:
    """The capture stamp in a message's header (0: none, or not a gflow message)."""
    try:
        return int(decode(payload).header.stamp_ns)
    except (MessageError, AttributeError):
        return 0


def rate_stats(times: list[float], window: int | None = None) -> RateStats | None:
    """Statistics of the last ``window`` gaps between arrival ``times`` (seconds); None under 2 messages."""
    import numpy as np

    if len(times) < 2:
        return None
    t = np.asarray(times[-(window + 1):] if window else times, dtype=float)
    gaps = np.diff(t)
    mean = float(gaps.mean())
    return RateStats(messages=len(times), rate_hz=1.0 / mean if mean > 0 else float("inf"),
                     min_ms=float(gaps.min()) * 1e3, max_ms=float(gaps.max()) * 1e3, std_ms=float(gaps.std()) * 1e3,
                     window=len(gaps))


def hz(settings: ZenohSettings, key: str, duration: float | None = None, out: TextIO = sys.stdout,
       wait: float = 10.0, window: int | None = None, every: float = 1.0,
       since: float | None = None, name: str | None = None) -> RateStats | None:
    """A rolling rate on ``key``: wait up to ``wait`` s for the first message, then print the rate,
    min / max / std of the gaps over the last ``window`` messages every ``every`` s, for
    ``duration`` s (None: until Ctrl-C). Returns the last statistics (None: fewer than 2 messages).
    ``wait`` counts from ``since`` (a ``time.monotonic()``: the caller's start, so that what it waited for
    before, a pipeline to start, is part of it), or from the call. ``name``: the topic as the user typed
    it, for the lines printed (default ``key``)."""
    s = _session(settings)
    q: queue.SimpleQueue = queue.SimpleQueue()
    # arrival (monotonic), latency (ms, NaN when the stamp is not the host clock)
    bus = Bus(s)
    bus.subscribe(key, lambda k, p, ns, seq: q.put((time.monotonic(), time.time_ns(), p)))
    live = _LiveCounts()
    parts = key.split("/")
    if len(parts) > 2 and parts[0] == "gflow" and "*" not in parts[1]:  # the stream's live source, if any
        bus.subscribe(f"gflow/{parts[1]}/captures", lambda k, p, ns, seq: live.add(p))
    times: list[float] = []
    lat: list[float] = []
    last: RateStats | None = None

    def take(item) -> None:
        t, now_ns, payload = item
        times.append(t)
        stamp = _stamp_of(payload)
        lat.append((now_ns - stamp) / 1e6 if stamp > HOST_CLOCK_NS else float("nan"))

    def stats() -> RateStats | None:
        st = rate_stats(times, window)
        if st is None:
            return None
        import numpy as np

        ms = np.asarray(lat[-(st.window + 1):], dtype=float)
        ms = ms[np.isfinite(ms)]
        if ms.size:
            st.latency_p50_ms, st.latency_p99_ms = float(np.percentile(ms, 50)), float(np.percentile(ms, 99))
        if live.sent:
            st.skipped, st.captured = live.window(window)
        return st

    try:
        wait_end = (time.monotonic() if since is None else since) + wait
        while not times:
            try:
                take(q.get(timeout=0.05))
            except queue.Empty:
                if time.monotonic() > wait_end:
                    return None
        end = None if duration is None else times[0] + duration
        next_print = times[0] + every
        while end is None or time.monotonic() < end:
            try:
                take(q.get(timeout=0.05))
            except queue.Empty:
                pass
            if window:
                del times[:-(window + 1)]
                del lat[:-(window + 1)]
            if time.monotonic() >= next_print:
                next_print += every
                st = stats()
                if st is not None:
                    last = st
                    print(st.line(name or key), file=out, flush=True)
    except KeyboardInterrupt:
        pass
    finally:
        s.close()
    return stats() or last


class _LiveCounts:
    """The live source's Capture messages heard (on zenoh's thread): frames sent and skipped."""

    def __init__(self) -> None:
        self.skips: list[tuple[int, int]] = []  # (camera frame, skipped before it)
        self.sent = 0

    def add(self, payload: bytes) -> None:
        try:
            m = decode(payload)
        except MessageError:
            return
        if isinstance(m, Capture):
            self.skips.append((m.frame, m.skipped))
            self.sent += 1

    def window(self, n: int | None) -> tuple[int, int]:
        """(skipped, captured) over the last ``n`` frames sent (all: None)."""
        w = list(self.skips[-n:] if n else self.skips)
        skipped = sum(k for _, k in w)
        return skipped, len(w) + skipped


@dataclass
class ReplayOptions:
    """What to replay and how fast.

    speed : timing factor on the recorded log times; None = as fast as possible.
    topics : only these topics (full names); None = all but heartbeats and control.
    start_seq / end_seq : only frames with start_seq <= seq < end_seq.
    start_s / end_s : only messages logged in [start_s, end_s) seconds after the first one.
    loops : how many times to play the file (0 = until interrupted).
    lockstep : stage names; before sending a frame with a new sequence number, wait until
        each of them has reported (on its heartbeat) that it has processed the previous one.
    ack_timeout : seconds to wait for an acknowledgement before giving up.
    stream : publish on ``gflow/<stream>/...`` instead of the recorded stream (None: the recorded one).
    """

    speed: float | None = 1.0
    topics: list[str] | None = None
    start_seq: int | None = None
    end_seq: int | None = None
    start_s: float | None = None
    end_s: float | None = None
    loops: int = 1
    lockstep: tuple[str, ...] = ()
    ack_timeout: float = 10.0
    settle: float = 1.0
    stream: str | None = None


class _Acks:
    """Last sequence number each live stage reports in its heartbeat."""

    def __init__(self) -> None:
        self.last: dict[str, int] = {}
        self.changed = threading.Event()

    def on_status(self, key: str, payload: bytes, pub_ns: int, seq: int) -> None:
        try:
            m = decode(payload)
        except MessageError:
            return
        if isinstance(m, StageStatus):
            self.last[m.stage] = (1 << 60) if m.state in ("done", "stopped") else m.last_seq
            self.changed.set()

    def wait(self, stages: tuple[str, ...], seq: int, timeout: float) -> None:
        """Until each of ``stages`` has processed frame ``seq`` (``seq`` -1: until each has been
        heard at all; a stage beats only after declaring its subscribers, so it will hear what
        is sent next)."""
        end = time.monotonic() + timeout
        while True:
            behind = [s for s in stages if self.last.get(s, -2) < seq]
            if not behind:
                return
            left = end - time.monotonic()
            if left <= 0:
                what = "heartbeat" if seq < 0 else f"acknowledgement of frame {seq}"
                # the stages that were heard: a mistyped name shows beside the real ones
                heard = sorted(set(self.last) - set(behind))
                raise TimeoutError(f"lockstep: no {what} from {', '.join(behind)} "
                                   f"within {timeout:.0f} s (are they running, on this network?"
                                   + (f" heard from: {', '.join(heard)})" if heard else ")"))
            self.changed.clear()
            self.changed.wait(min(left, 0.05))


class StreamInUse(RuntimeError):
    """A replay would publish into the stream of a pipeline that runs: refused, in one line."""


class NoSuchStage(RuntimeError):
    """``--lockstep`` names a stage that no pipeline running on the stream has: refused, in one line."""


def _check_lockstep(names: tuple[str, ...], stream: str) -> None:
    """:class:`NoSuchStage` when the pipelines announced on this machine on ``stream`` are known and none of their
    graphs has a stage of ``names`` (a mistyped name would otherwise wait ``--ack-timeout`` for a heartbeat that
    never comes). With no such announcement (a pipeline on another host, or one not started yet) the replay waits
    for the stages' heartbeats as before."""
    from pipeline.runtime.running import running

    found = [i for i in running(stream) if i.get("graph")]
    known = {s for i in found for s in i["graph"]}
    missing = [n for n in names if n not in known]
    if found and missing:
        who = ", ".join(f"{i.get('name', stream)} (pid {i.get('pid')})" for i in found)
        raise NoSuchStage(f"--lockstep {','.join(missing)}: no such stage in the pipeline running on stream "
                          f"{stream!r}: {who}; its stages: {', '.join(sorted(known))}")


def _stream_holders(session, stream: str, topics: set[str]) -> list[str]:
    """What runs on ``stream`` now: the pipelines and replays announced on this machine and the
    stages holding a liveliness token on the network. Empty when nothing does (a replay there is
    its own run) or when the pipelines announced there take every one of ``topics`` from outside
    (a graph with ``external`` inputs: what a replay is for)."""
    from pipeline.runtime.multihost import alive_stages, replays_on
    from pipeline.runtime.running import running

    found = running(stream)
    if found and all(topics <= set(i.get("external") or ()) for i in found):
        return []
    held = [f"{i.get('kind', 'pipeline')} {i.get('pid')}" for i in found]
    return held + [f"stage {n}" for n in sorted(alive_stages(session, stream))] + [
        f"replay {p}" for p in sorted(replays_on(session, stream)) if f"replay {p}" not in held]


def _window(opts: ReplayOptions) -> str:
    """The replay window ``opts`` asks for, as the options that set it."""
    parts = [f"{name} {v}" for name, v in (("--from-seq", opts.start_seq), ("--to-seq", opts.end_seq),
                                             ("--start", opts.start_s), ("--end", opts.end_s)) if v is not None]
    return ", ".join(parts) or "the whole recording"


def _held(records: list) -> str:
    """What a recording's ``records`` span, as a replay window names it (:func:`_span`)."""
    unit, seqs = _span(records)
    if unit == "frames":
        return f"frames {min(seqs)}..{max(seqs)}"
    return f"no frame; the messages chosen carry sequence numbers {min(seqs)}..{max(seqs)}"


def _span(records: list) -> tuple[str, list[int]]:
    """What ``records`` span, as a replay window counts it: ("frames", the sequence numbers of their Frame
    messages), or, with none, ("sequence numbers", those of their messages; [0] for none): a stage's output for
    frame k may carry k + 1 (the particles it sends on for the next frame)."""
    frames = [r.seq for r in records if r.type == "Frame"]
    if frames:
        return "frames", frames
    return "sequence numbers", [r.seq for r in records if r.type != "EndOfStream"] or [0]


def _chosen(path: str, records: list, opts: ReplayOptions) -> list:
    """The ``records`` in the window ``opts`` asks for (the end of stream marks whatever their frames); a window
    that selects no message is a ValueError naming it and what the recording holds."""
    t_first = min(r.log_ns for r in records)
    keep = []
    for r in records:
        rel = (r.log_ns - t_first) / 1e9
        if opts.start_s is not None and rel < opts.start_s or opts.end_s is not None and rel >= opts.end_s:
            continue
        if r.type != "EndOfStream" and (opts.start_seq is not None and r.seq < opts.start_seq
                                        or opts.end_seq is not None and r.seq >= opts.end_seq):
            continue
        keep.append(r)
    if all(r.type == "EndOfStream" for r in keep):  # a window that selects no message is a mistyped one
        raise ValueError(f"{path}: no message in the chosen window ({_window(opts)}); it holds {_held(records)} over "
                         f"{(max(r.log_ns for r in records) - t_first) / 1e9:.3f} s")
    return keep


def _note_window_past(path: str, records: list, keep: list, opts: ReplayOptions) -> None:
    """A line on stderr for each part of the window ``opts`` that runs past what ``records`` span: --from-seq
    before their first frame or --to-seq past their last (:func:`_span`), --end past their last message's time;
    said with what ``keep`` replays (a window clipped to the recording was replayed without a word)."""
    from pipeline.cli.commands.common import range_note, range_past_note, say_notes

    unit, held = _span(records)
    took = _span(keep)
    asked = [f"{name} {v}" for name, v in (("--from-seq", opts.start_seq), ("--to-seq", opts.end_seq)) if v is not None]
    if asked and took[0] == unit:
        start = min(held) if opts.start_seq is None else opts.start_seq
        say_notes(range_past_note(" ".join(asked), (start, opts.end_seq), path, (min(held), max(held)),
                                  (min(took[1]), max(took[1])), "replaying", unit))
    t_first = min(r.log_ns for r in records)
    last = (max(r.log_ns for r in records) - t_first) / 1e9
    if opts.end_s is not None and opts.end_s > last:
        rel = [(r.log_ns - t_first) / 1e9 for r in keep]
        say_notes(range_note(f"--end {opts.end_s:g}", path, f"{last:.3f} s",
                             f"replaying {min(rel):.3f}..{max(rel):.3f} s"))


@dataclass
class Replayed:
    """What a replay sent: ``sent`` messages of the ``planned`` its plays hold (0: played until interrupted), and
    whether a Ctrl-C ended it (``interrupted``) before they were all sent."""

    sent: int
    planned: int
    interrupted: bool = False


def replay(settings: ZenohSettings, path: str, opts: ReplayOptions, out: TextIO = sys.stderr,
           announce_endpoints: list[str] | None = None, ready: Callable[[], None] | None = None) -> Replayed:
    """Republish a recording on zenoh, byte for byte, on its recorded topics with its sequence numbers.

    Returns what was sent (:class:`Replayed`). Heartbeats and control messages of the recorded
    pipeline are never replayed (they would confuse a live one). With ``announce_endpoints``
    the replay announces itself (:mod:`pipeline.runtime.running`) there while it plays, so
    ``gflow topics`` and friends find it without a launcher. ``ready`` is called once the session is
    open and the replay announced, just before the first message; a Ctrl-C from then on ends the
    replay and returns the count sent so far, marked interrupted.

    A replay is a run of its own: on the recorded stream while no pipeline runs on it; a stream a
    running pipeline (or another replay) holds is refused (:class:`StreamInUse`, before anything is
    sent) unless the replay is meant to feed it (``opts.lockstep``, or ``opts.stream`` naming it).
    ``opts.stream`` republishes under another stream (the payloads unchanged).
    """
    records = [r for r in iter_records(path, topics=opts.topics)
               if "/_status/" not in r.topic and not r.topic.endswith("/_control")]
    if not records:
        from pipeline.io.mcap_io import damage_cause, torn_cause

        why = damage_cause(path) or torn_cause(path)  # the cut, not taken for what the run recorded
        raise ValueError(f"{path}: nothing to replay" + (f" on {opts.topics}" if opts.topics else "")
                         + (f": {why}" if why else ""))
    keep = _chosen(path, records, opts)
    _note_window_past(path, records, keep, opts)
    recorded = keep[0].topic.split("/")[1]
    stream = opts.stream or recorded

    def key(topic: str) -> str:  # the recorded key, under the stream the replay publishes on
        parts = topic.split("/", 2)
        return f"gflow/{stream}/{parts[2]}" if len(parts) == 3 and parts[1] == recorded else topic

    _check_lockstep(opts.lockstep, stream)
    s = _session(settings)
    announcement = token = None
    n, interrupted = 0, False
    loop = 0
    try:  # from here on a Ctrl-C ends the replay with the count sent so far and the session closed
        bus = Bus(s, signer=Signer.of(settings.security))
        if not opts.stream and not opts.lockstep:
            held = _stream_holders(s, stream, {key(r.topic) for r in keep})
            if held:
                raise StreamInUse(f"stream {stream!r} is in use ({', '.join(held)}): replayed there, the recording "
                                  f"would feed that run; replay beside it with --stream NAME, or into it on purpose "
                                  f"with --stream {stream}")
        # while it plays, a token says so on the network: a pipeline started there later is refused
        token = s.liveliness().declare_token(replay_token(stream))
        acks = _Acks()
        if opts.lockstep:
            bus.subscribe(f"gflow/{stream}/_status/*", acks.on_status)
            bus.subscribe(f"gflow/{stream}/{PROGRESS}/*", acks.on_status)  # each step a worker finished
        if announce_endpoints and stream:
            from pipeline.runtime.running import announce

            announcement = announce(stream, announce_endpoints, name=f"replay {Path(path).name}", kind="replay",
                                    recording=str(path))
        if ready is not None:
            ready()
        if opts.lockstep:  # the stages fed in lockstep have declared their subscribers once they beat
            acks.wait(opts.lockstep, -1, opts.ack_timeout)
        time.sleep(opts.settle)  # let other subscribers' declarations arrive before the first sample
        while opts.loops == 0 or loop < opts.loops:
            loop += 1
            wall0 = time.monotonic()
            t0 = keep[0].log_ns if keep else 0
            sent_seq = -1
            for r in keep:
                if opts.lockstep and r.seq > sent_seq >= 0:
                    acks.wait(opts.lockstep, sent_seq, opts.ack_timeout)
                if opts.speed is not None:
                    due = wall0 + (r.log_ns - t0) / 1e9 / opts.speed
                    delay = due - time.monotonic()
                    if delay > 0:
                        time.sleep(delay)
                bus.publish(key(r.topic), r.data, r.seq, r.type if r.type != "unknown" else "")
                if r.type != "EndOfStream":
                    sent_seq = max(sent_seq, r.seq)
                n += 1
    except KeyboardInterrupt:
        interrupted = True
    finally:
        time.sleep(0.2)
        if token is not None:
            token.undeclare()
        if announcement is not None:
            announcement.close()
        s.close()
    return Replayed(n, len(keep) * opts.loops, interrupted)
