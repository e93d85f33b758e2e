"""Join a stage's input ports by sequence number (see ``stages/base.py`` for the contract).

Messages on one port arrive in increasing ``seq``. A stage whose output must not depend on
arrival timing requires every port it reads (the default): a port it does not require may
or may not have arrived when its frame is released. ``SeqJoin`` keeps what has arrived per
``seq`` and releases sequence numbers strictly in ascending order, each one as soon as every
port the stage requires for it is *decided*: either its message is here, or the port has
moved past that ``seq`` (a later message or an end of stream arrived), in which case the
stage gets ``None`` for it.

Faults (a lost, late or displaced message) must never stop the join. Besides the rule
above, a port counts as missing for ``seq``

* when the stream has gone ``lag`` frames past ``seq`` (the highest ``seq`` seen on any
  port, or the source's position given in ``horizon``): a timeout counted in frames;
* when the runner forces it (``force_below``; the node does so after a wall-time wait
  while the source is ahead or a driver has ended);
* right after a restart (``resumed``): the frames the stage missed while it was down, up to
  the first one whose driver ports are here, cannot be completed by anyone (in a
  proposal -> filter cycle the stage itself was the producer), so they are released with
  what they have, and the stage re-seeds from its own restored state.

With ``fill_gaps``, a ``seq`` for which nothing arrived at all but which the stream has
moved past is released too, with every port ``None`` (a filter then coasts, so its output
keeps one message per frame); without it such a ``seq`` is skipped.
"""

from __future__ import annotations

import time
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
    lag: int = 0  # frames behind the stream after which a missing input is given up (0: never)
    horizon: int = -1  # the source's position, when the runner knows it
    force_below: int = -1  # every seq <= force_below is decided on every port
    resumed: bool = False
    fill_gaps: bool = False
    hold: bool = False  # suspend the lag rule (a producer is restarting and will catch up)
    timed_out: int = 0  # (seq, port) pairs given up by the lag, force or resume rules
    since: dict[int, float] = field(default_factory=dict)  # when each pending seq first arrived (monotonic s)

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
        if seq not in self.pending:
            self.since[seq] = time.monotonic()
        self.pending.setdefault(seq, {})[port] = msg

    def accepts(self, port: str, seq: int) -> str:
        """'' if a message of ``seq`` on ``port`` would be joined, else why not: ``duplicate``
        (this seq already came on this port), ``old`` (behind what was consumed or what came
        on this port)."""
        prev = self.high.get(port)
        if prev is not None and seq == prev:
            return "duplicate"
        if seq <= self.done_below or (prev is not None and seq < prev):
            return "old"
        return ""

    def top(self) -> int:
        """The furthest the stream is known to have got: the highest seq on any port, or the horizon."""
        return max([self.horizon, *self.high.values()])

    def end(self, port: str, seq: int) -> None:
        """End of stream on ``port``: nothing with ``seq >= seq`` will come."""
        self.eos[port] = seq
        self.high[port] = max(self.high.get(port, -1), seq)

    def _decided(self, port: str, seq: int, have: dict[str, Any]) -> bool:
        return port in have or self.high.get(port, -1) > seq or self.eos.get(port, 1 << 62) <= seq

    def _given_up(self, seq: int, resume_upto: int) -> bool:
        return (seq <= self.force_below or seq <= resume_upto
                or (self.lag > 0 and not self.hold and self.top() - seq >= self.lag))

    def _resume_upto(self) -> int:
        """After a restart: the first pending seq whose drivers are all here (-1 if none yet)."""
        if not self.resumed:
            return -1
        for seq in sorted(self.pending):
            if all(p in self.pending[seq] for p in self.drivers):
                return seq
        return -1

    def waiting(self, required: Callable[[int], frozenset[str]]) -> tuple[int, list[str]] | None:
        """(lowest pending seq, ports it waits for), or None when nothing waits."""
        if not self.pending:
            return None
        seq = min(self.pending)
        have = self.pending[seq]
        return seq, sorted(p for p in required(seq) if not self._decided(p, seq, have))

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
                self.since.clear()
                return
            resume_upto = self._resume_upto()
            if self.fill_gaps and self.done_below >= 0 and seq > self.done_below + 1:
                gap = self.done_below + 1  # nothing arrived for it, and the stream has moved past
                req = required(gap)
                undecided = [p for p in req if not self._decided(p, gap, {})]
                if undecided and not self._given_up(gap, resume_upto):
                    return
                self.timed_out += len(undecided)
                self.done_below = gap
                yield gap, {p: None for p in self.ports}
                continue
            have = self.pending[seq]
            req = required(seq)
            undecided = [p for p in req if not self._decided(p, seq, have)]
            if undecided:
                if not self._given_up(seq, resume_upto):
                    return
                self.timed_out += len(undecided)
            del self.pending[seq]
            self.since.pop(seq, None)
            self.done_below = seq
            if seq >= resume_upto >= 0:
                self.resumed = False
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
