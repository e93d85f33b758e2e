"""Topic names as a user types them, matched against the topics a recording (or a live run) holds.

Topics are ``gflow/<stream>/<name>``, and a run's stream carries its run id (``demo-3f9c2a``:
see :mod:`pipeline.runtime.runid`), which a user rarely knows. Every command that takes topics
(``replay``, ``diff``, ``echo``, ``hz``, ``step``, ``rerun``, ``foxglove``) reads them through
:func:`select_topics`, which accepts, for the topic ``gflow/demo-3f9c2a/estimate``:

* the name inside the stream: ``estimate`` (``_status/filter``, ``_snapshot/*``);
* the full name, with or without the run id: ``gflow/demo-3f9c2a/estimate``, ``gflow/demo/estimate``,
  also without the leading ``gflow/`` (``demo/estimate``);
* shell wildcards in any of these: ``*``, ``gflow/*/estimate``, ``_status/*``, ``est*``.

A pattern that matches nothing is an error (:class:`TopicError`) that lists the topics there are:
a filter that silently matched nothing once made ``gflow diff`` say "identical".
"""

from __future__ import annotations

import fnmatch
import re
from typing import Iterable

__all__ = ["TopicError", "topic_matches", "select_topics", "split_topic", "describe_topics", "stream_prefix",
           "without_run_id", "streams_paired_across_run_ids"]

#: a run id appended to a graph's stream (pipeline/runtime/runid.py: six hex digits)
_RUN_ID = re.compile(r"-[0-9a-f]{6}$")


class TopicError(ValueError):
    """A topic pattern that matches none of the topics there are (the message lists them): ``pattern`` as typed,
    ``where`` it looked and ``held``, the topics there as :func:`describe_topics` says them."""

    def __init__(self, pattern: str, where: str, held: str) -> None:
        super().__init__(f"no topic of {where} matches {pattern!r}; it holds: {held}")
        self.pattern, self.where, self.held = pattern, where, held


def split_topic(topic: str) -> tuple[str, str] | None:
    """``gflow/STREAM/NAME`` -> (STREAM, NAME); None for a topic outside that form."""
    parts = topic.split("/", 2)
    if len(parts) == 3 and parts[0] == "gflow" and parts[1] and parts[2]:
        return parts[1], parts[2]
    return None


def without_run_id(topic: str) -> str:
    """``gflow/demo-3f9c2a/estimate`` -> ``gflow/demo/estimate``; a topic with no run id as it is."""
    parts = split_topic(topic)
    if parts is None:
        return topic
    return f"gflow/{_RUN_ID.sub('', parts[0])}/{parts[1]}"


def streams_paired_across_run_ids(a: Iterable[str], b: Iterable[str]) -> tuple[str, str] | None:
    """The streams (A's, B's) of two sets of topics that differ only by run id, else None.

    Two runs of one graph record ``gflow/demo-43159e/...`` and ``gflow/demo-a1b2c3/...``: each set is
    of one stream, the streams differ, and they are the same stream once the run id is removed
    (``demo``). Topics of one set missing from the other do not prevent the pairing.
    """
    pa, pb = stream_prefix(a), stream_prefix(b)
    if not pa or not pb or pa == pb:
        return None
    sa, sb = pa[len("gflow/"):-1], pb[len("gflow/"):-1]
    if _RUN_ID.sub("", sa) != _RUN_ID.sub("", sb):
        return None
    return sa, sb


def _stream_matches(pattern: str, stream: str) -> bool:
    """A stream pattern matches the stream itself, or the stream without its run id."""
    if fnmatch.fnmatchcase(stream, pattern):
        return True
    bare = _RUN_ID.sub("", stream)
    return bare != stream and fnmatch.fnmatchcase(bare, pattern)


def topic_matches(pattern: str, topic: str) -> bool:
    """Whether the user's ``pattern`` names ``topic`` (see the module docstring for the forms)."""
    pattern = pattern.strip()
    if not pattern:
        return False
    if fnmatch.fnmatchcase(topic, pattern):
        return True
    parts = split_topic(topic)
    if parts is None:
        return False
    stream, name = parts
    if not pattern.startswith("gflow/") and fnmatch.fnmatchcase(name, pattern):
        return True  # the name inside the stream: frames, _status/filter
    full = pattern if pattern.startswith("gflow/") else "gflow/" + pattern
    pp = split_topic(full)
    return pp is not None and _stream_matches(pp[0], stream) and fnmatch.fnmatchcase(name, pp[1])


def stream_prefix(topics: Iterable[str]) -> str:
    """``gflow/STREAM/`` when every topic is of that one stream, else ""."""
    streams = {parts[0] if parts is not None else None for parts in map(split_topic, topics)}
    if len(streams) != 1 or None in streams:
        return ""
    return f"gflow/{next(iter(streams))}/"


def describe_topics(topics: Iterable[str], limit: int = 40, counts: dict[str, int] | None = None) -> str:
    """The topics as one line, the stream said once when they share it: ``gflow/demo-3f9c2a/: estimate,
    frames`` (the first ``limit``, then how many more; with ``counts``, each topic's count after it)."""
    ts = sorted(set(topics))
    if not ts:
        return "none"
    prefix = stream_prefix(ts)
    more = f" and {len(ts) - limit} more" if len(ts) > limit else ""
    names = [t[len(prefix):] + (f" {counts[t]}" if counts is not None else "") for t in ts[:limit]]
    return (f"{prefix}: " if prefix else "") + ", ".join(names) + more


def select_topics(patterns: Iterable[str] | None, available: Iterable[str], where: str = "the recording") -> list[str]:
    """The topics of ``available`` that the user's ``patterns`` name, in sorted order.

    Each pattern may also be a comma-separated list. ``patterns`` None or empty: every topic.
    A pattern that matches nothing raises :class:`TopicError` naming it, ``where`` it looked and
    the topics there are.
    """
    avail = sorted(set(available))
    pats = [p.strip() for item in (patterns or ()) for p in item.split(",") if p.strip()]
    if not pats:
        return avail
    chosen: set[str] = set()
    for p in pats:
        hit = [t for t in avail if topic_matches(p, t)]
        if not hit:
            raise TopicError(p, where, describe_topics(avail))
        chosen.update(hit)
    return sorted(chosen)
