"""Join a stage's input ports by sequence number (see ``stages/base.py`` for the contract).

Messages on one port arrive in increasing ``seq``. A stage whose output must not depend on
arrival timing requires every port it reads (the default): a port it does not require may
or may not have arrived when its frame is released. ``SeqJoin`` keeps what has arrived per
``seq`` and releases sequence numbers strictly in ascending order, each one as soon as every
port the stage requires for it is *decided*: either its message is here, or the port has
moved past that ``seq`` (a later message or an end of stream arrived), in which case the
stage gets ``None`` for it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, Iterator

__all__ = ["SeqJoin"]


@dataclass
class SeqJoin:
    ports: tuple[str, ...]
    drivers: frozenset[str]
    pending: dict[int, dict[str, Any]] = field(default_factory=dict)
    high: dict[str, int] = field(default_factory=dict)
    eos: dict[str, int] = field(default_factory=dict)
    done_below: int = -1  # every seq <= done_below has been released or dropped
    stale: int = 0
    gaps: dict[str, int] = field(default_factory=dict)

    def push(self, port: str, seq: int, msg: Any) -> None:
        """Store one message. Late or duplicate messages (seq already released) are counted and dropped."""
        if port not in self.ports:
            raise KeyError(f"unknown port {port!r}")
        prev = self.high.get(port)
        if prev is not None and seq <= prev:
            self.stale += 1  # out of order or repeated on this port
            return
        if prev is not None and seq > prev + 1:
            self.gaps[port] = self.gaps.get(port, 0) + (seq - prev - 1)
        self.high[port] = seq
        if seq <= self.done_below:
            self.stale += 1  # its frame was already released without it
            return
        self.pending.setdefault(seq, {})[port] = msg

    def end(self, port: str, seq: int) -> None:
        """End of stream on ``port``: nothing with ``seq >= seq`` will come."""
        self.eos[port] = seq
        self.high[port] = max(self.high.get(port, -1), seq)

    def _decided(self, port: str, seq: int, have: dict[str, Any]) -> bool:
        return port in have or self.high.get(port, -1) > seq or self.eos.get(port, 1 << 62) <= seq

    def _driver_end(self) -> int | None:
        ends = [self.eos[p] for p in self.drivers if p in self.eos]
        return min(ends) if ends else None

    def ready(self, required: Callable[[int], frozenset[str]]) -> Iterator[tuple[int, dict[str, Any]]]:
        """Yield ``(seq, {port: message or None})`` in ascending seq while the lowest one is decided."""
        while self.pending:
            seq = min(self.pending)
            end = self._driver_end()
            if end is not None and seq >= end:
                # the stream has ended: what remains can never be complete
                self.pending.clear()
                return
            have = self.pending[seq]
            req = required(seq)
            if not all(self._decided(p, seq, have) for p in req):
                return
            del self.pending[seq]
            self.done_below = seq
            if not any(p in have for p in req):
                continue  # nothing the stage needs for this seq arrived at all
            yield seq, {p: have.get(p) for p in self.ports}

    @property
    def finished(self) -> bool:
        """True once a driver port (or every port) has ended and nothing before the end is pending."""
        if self.ports and all(p in self.eos for p in self.ports):
            return not self.pending
        end = self._driver_end()
        if end is None:
            return False
        return not any(s < end for s in self.pending)
