"""Inspect a live pipeline: ``gflow topics``, ``gflow echo``, ``gflow hz``, and ``gflow replay``."""

from __future__ import annotations

import queue
import sys
import time
from typing import TextIO

from stages.messages import MessageError, NDArray, decode

from .mcap_io import iter_records
from .transport import Bus, ZenohSettings, open_session

__all__ = ["list_topics", "echo", "hz", "replay", "describe"]


def describe(payload: bytes, full: bool = False) -> str:
    """One line (or a few) about a payload: type, seq and its small fields; arrays as dtype+shape."""
    try:
        m = decode(payload)
    except MessageError as e:
        return f"<undecodable: {e}>"
    parts = [type(m).__name__]
    for name in m.__struct_fields__:
        v = getattr(m, name)
        if name == "header":
            parts.append(f"seq={v.seq} stamp={v.stamp_ns / 1e9:.3f}s")
        elif isinstance(v, NDArray):
            parts.append(f"{name}={v.dtype}{list(v.shape)}")
        elif isinstance(v, float):
            parts.append(f"{name}={v:.4g}")
        elif isinstance(v, tuple) and v and isinstance(v[0], float):
            parts.append(f"{name}=(" + ", ".join(f"{x:.2f}" for x in v) + ")")
        elif v not in (None, "", {}, ()) or full:
            parts.append(f"{name}={v}")
    return " ".join(parts)


def _session(settings: ZenohSettings):
    return open_session(settings)


def list_topics(settings: ZenohSettings, duration: float, out: TextIO = sys.stdout) -> dict[str, int]:
    """Listen on ``gflow/**`` for ``duration`` seconds and print each topic with its count and rate."""
    s = _session(settings)
    counts: dict[str, int] = {}
    types: dict[str, str] = {}
    q: queue.SimpleQueue = queue.SimpleQueue()
    bus = Bus(s)
    bus.subscribe("gflow/**", lambda k, p, ns, seq: q.put((k, p)))
    end = time.monotonic() + duration
    while time.monotonic() < end:
        try:
            k, p = q.get(timeout=0.05)
        except queue.Empty:
            continue
        counts[k] = counts.get(k, 0) + 1
        if k not in types:
            try:
                types[k] = type(decode(p)).__name__
            except MessageError:
                types[k] = "?"
    s.close()
    if not counts:
        print(f"no messages on gflow/** in {duration:.1f} s (is a pipeline running, and reachable at "
              f"{', '.join(settings.connect) or 'the default endpoint'}?)", file=out)
    for k in sorted(counts):
        print(f"{k:45s} {types[k]:12s} {counts[k]:6d} msgs  {counts[k] / duration:7.1f} Hz", file=out)
    return counts


def echo(settings: ZenohSettings, key: str, count: int | None, timeout: float | None, out: TextIO = sys.stdout) -> int:
    """Print messages on ``key`` (a key expression) as they arrive."""
    s = _session(settings)
    q: queue.SimpleQueue = queue.SimpleQueue()
    Bus(s).subscribe(key, lambda k, p, ns, seq: q.put((k, p)))
    n = 0
    start = time.monotonic()
    try:
        while count is None or n < count:
            if timeout is not None and time.monotonic() - start > timeout:
                break
            try:
                k, p = q.get(timeout=0.1)
            except queue.Empty:
                continue
            print(f"{k}: {describe(p)}", file=out, flush=True)
            n += 1
    except KeyboardInterrupt:
        pass
    finally:
        s.close()
    return n


def hz(settings: ZenohSettings, key: str, duration: float, out: TextIO = sys.stdout) -> float:
    """Measure the message rate on ``key`` for ``duration`` seconds."""
    s = _session(settings)
    q: queue.SimpleQueue = queue.SimpleQueue()
    Bus(s).subscribe(key, lambda k, p, ns, seq: q.put(time.monotonic()))
    times: list[float] = []
    end = time.monotonic() + duration
    try:
        while time.monotonic() < end:
            try:
                times.append(q.get(timeout=0.05))
            except queue.Empty:
                pass
    except KeyboardInterrupt:
        pass
    s.close()
    if len(times) < 2:
        print(f"{key}: {len(times)} message(s) in {duration:.1f} s", file=out)
        return 0.0
    rate = (len(times) - 1) / (times[-1] - times[0])
    gaps = [b - a for a, b in zip(times, times[1:])]
    print(f"{key}: {rate:.2f} Hz over {len(times)} msgs, gap min {min(gaps) * 1e3:.1f} ms max {max(gaps) * 1e3:.1f} ms",
          file=out)
    return rate


def replay(settings: ZenohSettings, path: str, speed: float | None, topics: list[str] | None,
           out: TextIO = sys.stderr, settle: float = 1.0) -> int:
    """Republish a recording on zenoh with its original timing scaled by ``speed`` (None: as fast as possible).

    Payloads go out byte for byte as recorded, on their recorded topics, with their sequence numbers.
    """
    s = _session(settings)
    bus = Bus(s)
    time.sleep(settle)  # let subscribers' declarations arrive before the first sample
    n = 0
    t_first = None
    wall0 = time.monotonic()
    truncated: list[str] = []
    try:
        for r in iter_records(path, topics=topics, on_truncated=truncated.append):
            if "/_status/" in r.topic or r.topic.endswith("/_control"):
                continue  # the recorded pipeline's own heartbeats would confuse a live one
            if speed is not None:
                t_first = r.log_ns if t_first is None else t_first
                due = wall0 + (r.log_ns - t_first) / 1e9 / speed
                delay = due - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
            bus.publish(r.topic, r.data, r.seq)
            n += 1
    except KeyboardInterrupt:
        pass
    finally:
        time.sleep(0.2)
        s.close()
    for t in truncated:
        print(t, file=out)
    return n
