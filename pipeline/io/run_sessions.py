"""Which messages of a recording came from the run's own stages, and which from outside it.

Every sample a gflow process publishes names its zenoh session (the source info of
:meth:`pipeline.runtime.transport.Bus.publish`), and the recorder files each session's samples
in a channel of their own (``gflow.source``). A run's own sessions are those that sent a
stage's heartbeat (``gflow/<stream>/_status/<stage>``: every stage process beats from its
start, a restarted one from its new session, a stage on another host too). A message on a topic
the run's own stages publish, from any other session, is **from outside the run**: a peer on
the same zenoh network writing on the run's topics. It stays in the recording, is left out of
the run's results (boxes, latency) and is counted (:meth:`RunSessions.lines`).

A topic no stage of the run publishes (the frames a ``gflow replay`` feeds to a graph without a
source, the launcher's control topic) has no such owner: whoever sends on it is not an
outsider. Recordings made before sessions were recorded name none: everything in them counts.

Without a run key nothing is authenticated: a peer that also forges heartbeats or the source
info is not told apart. ``--run-key`` refuses every message not signed with the run's key
(docs/security.md).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # the reader imports this module
    from pipeline.io.mcap_io import Record

__all__ = ["RunSessions"]


@dataclass
class RunSessions:
    """The run's sessions and the messages from outside it, learnt from records fed by :meth:`add`
    (a whole recording: the verdicts hold once every record has been seen)."""

    own: set[str] = field(default_factory=set)  # the sessions that sent a stage heartbeat
    counts: dict[tuple[str, str, str], int] = field(default_factory=dict)  # (topic, type, session) -> messages

    def add(self, r: "Record") -> None:
        if r.source and r.type == "StageStatus" and "/_status/" in r.topic:
            self.own.add(r.source)
        key = (r.topic, r.type, r.source)
        self.counts[key] = self.counts.get(key, 0) + 1

    def owned_topics(self) -> set[str]:
        """Topics a session of the run published on."""
        return {t for t, _, s in self.counts if s in self.own}

    def is_own(self, topic: str, source: str) -> bool:
        """Whether a message on ``topic`` from ``source`` ("" when its sample named none) belongs to
        the run's results (everything does in a recording that names no sessions)."""
        return not self.own or source in self.own or topic not in self.owned_topics()

    def outsiders(self) -> dict[tuple[str, str, str], int]:
        """(topic, type, session) -> messages from outside the run on the run's own topics."""
        owned = self.owned_topics()
        return {k: n for k, n in self.counts.items() if self.own and k[2] not in self.own and k[0] in owned}

    def lines(self) -> list[str]:
        """One line per outside session and topic (empty when there were none)."""
        return [f"{n} {typ} message(s) from outside the run on {topic} "
                f"({f'zenoh session {src}' if src else 'a publisher that names no session'}), left out of the results"
                for (topic, typ, src), n in sorted(self.outsiders().items())]

    def to_json(self) -> list[dict]:
        return [{"topic": t, "type": typ, "session": s, "messages": n}
                for (t, typ, s), n in sorted(self.outsiders().items())]
