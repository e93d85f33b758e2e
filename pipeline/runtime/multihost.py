"""A graph on several hosts: where stage processes listen, whether a stream is already taken,
and which hosts are up (zenoh liveliness tokens ``gflow/<stream>/_alive/<stage>``).

Every stage process holds a liveliness token; zenoh removes it within milliseconds when the
process dies, and when its host's link is gone for longer than the session lease (10 s by
default: a short cut is survived by TCP and noticed by nobody). A launcher watches the tokens
of the stages of other hosts: one that vanishes before its stage has said ``done`` means its
host is lost, reported by name; the run then stops cleanly (``on_host_lost: stop``, the
default) or waits for it (``on_host_lost: wait``; the stages hold their inputs meanwhile).

A ``gflow replay`` holds ``gflow/<stream>/_replay/<pid>`` while it publishes: a launcher that
joins the network refuses a stream a replay publishes on, unless its graph takes topics from
outside (what a replay is for).
"""

from __future__ import annotations

import dataclasses
import os
import threading
import time
from typing import Callable

import zenoh

from pipeline.runtime.graph import Plan
from pipeline.runtime.placement import describe_hosts
from pipeline.runtime.transport import ZenohSettings

__all__ = ["host_gateway", "node_listen", "stream_in_use", "replay_token", "replays_on", "HostWatch"]

_FINISHED = ("done", "stopped", "draining")


def host_gateway(launcher: ZenohSettings, placed: bool) -> ZenohSettings | None:
    """The launcher's settings as this host's zenoh router, when a peer-mode run reaches other hosts
    (placed on hosts, or ``--connect`` given); None otherwise.

    A zenoh router does not forward between two peers connected to it (measured with
    eclipse-zenoh 1.10: nothing crosses), so stage processes on two hosts, each a peer of one
    central router, never hear each other. Routers do forward to each other: with the launcher a
    router, each host's stages (peers, linked directly to each other and sharing memory) reach
    the other hosts through it, and data from another host arrives once per host, not once per
    process."""
    if launcher.mode == "peer" and (placed or launcher.connect):
        return dataclasses.replace(launcher, mode="router")
    return None


def node_listen(launcher: ZenohSettings) -> tuple[str, ...]:
    """Where the stage processes listen: on loopback when the launcher does, else on the launcher's
    own address (``tcp/0.0.0.0:0`` when it listens on every interface), so that stages of other
    hosts can link to them directly."""
    out = []
    for e in launcher.listen:
        proto, _, addr = e.partition("/")
        host = addr.rsplit(":", 1)[0]
        if proto in ("tcp", "udp") and host not in ("127.0.0.1", "localhost", "[::1]"):
            out.append(f"{proto}/{host}:0")
    return tuple(dict.fromkeys(out)) or ("tcp/127.0.0.1:0",)


def _token_names(session: zenoh.Session, key: str, timeout: float) -> set[str]:
    """The last chunk of every liveliness token matching ``key`` anywhere on the network now."""
    names = set()
    for reply in session.liveliness().get(key, timeout=timeout):
        try:
            names.add(str(reply.ok.key_expr).rsplit("/", 1)[-1])
        except Exception:  # an error reply: nothing to add
            continue
    return names


def alive_stages(session: zenoh.Session, stream: str, timeout: float = 1.0) -> set[str]:
    """The stages of ``stream`` that hold a liveliness token anywhere on the network now."""
    return _token_names(session, f"gflow/{stream}/_alive/*", timeout)


def replay_token(stream: str) -> str:
    """The liveliness token a ``gflow replay`` holds while it publishes on ``stream`` (not under
    ``_alive``: a replay is no stage a pipeline's nodes wait for)."""
    return f"gflow/{stream}/_replay/{os.getpid()}"


def replays_on(session: zenoh.Session, stream: str, timeout: float = 1.0) -> set[str]:
    """The process ids of the replays publishing on ``stream`` anywhere on the network now."""
    return _token_names(session, f"gflow/{stream}/_replay/*", timeout)


def stream_in_use(session: zenoh.Session, stream: str, local: set[str], external: bool = False) -> str:
    """A one-line refusal when stages this host would start already run on ``stream`` (another
    run on the same network), or a replay publishes there and the graph takes nothing from
    outside (``external``: a replay may feed it), else ''."""
    clash = sorted(alive_stages(session, stream) & local)
    if clash:
        return (f"stream {stream!r} is in use: stage(s) {', '.join(clash)} already run on it (another run on "
                f"this network); give this run its own --stream")
    replays = [] if external else sorted(replays_on(session, stream))
    if replays:
        return (f"stream {stream!r} is in use: gflow replay (pid {', '.join(replays)}) publishes on it, and this "
                f"graph takes no topic from outside; give this run its own --stream")
    return ""


class HostWatch:
    """The liveliness of the stages placed on other hosts, with one-line reports by host.

    A host's stages lose their tokens one by one (each process has its own session), so a loss
    is reported once every unfinished stage of that host is gone, or ``settle_s`` after the
    first one went (a single stage that died while its host lives)."""

    def __init__(self, session: zenoh.Session, plan: Plan, local: set[str], say: Callable[[str], None],
                 settle_s: float = 3.0) -> None:
        self.plan = plan
        self.settle_s = settle_s
        self._first_gone: float | None = None
        self.remote = [n for n in plan.stages if n not in local]
        self.say = say
        self.alive: set[str] = set()
        self.ever: set[str] = set()
        self.lost: set[str] = set()
        self.lost_report = ""
        self._lock = threading.Lock()
        self._told_wait = 0.0
        self._sub = (session.liveliness().declare_subscriber(f"gflow/{plan.stream}/_alive/*", self._on_alive,
                                                             history=True) if self.remote else None)

    def _on_alive(self, sample) -> None:
        name = str(sample.key_expr).rsplit("/", 1)[-1]
        with self._lock:
            if sample.kind == zenoh.SampleKind.DELETE:
                self.alive.discard(name)
            else:
                self.alive.add(name)
                self.ever.add(name)

    def waiting_for(self, missing: list[str], elapsed: float) -> None:
        """Say which hosts the start waits for (after 2 s, then every 10 s)."""
        remote = [n for n in missing if n in self.remote]
        if remote and elapsed >= 2.0 and elapsed - self._told_wait >= 10.0:
            self._told_wait = elapsed
            self.say(f"waiting for {describe_hosts(self.plan, remote)} to start")

    def unfinished(self, names: list[str], states: dict[str, str]) -> list[str]:
        """Those of ``names`` (stages of other hosts) that have not finished. A stage has when its
        last heartbeat says ``done`` or ``stopped``, or says ``draining`` and its token is gone:
        a draining stage exits once what it sent has arrived (:mod:`pipeline.runtime.drain`), and
        the final heartbeat it sends just before closing its session may never cross a lossy
        link, so waiting for that heartbeat alone could wait for ever."""
        with self._lock:
            exited = {n for n in names if n in self.ever and n not in self.alive}
        return [n for n in names if states.get(n) not in ("done", "stopped")
                and not (states.get(n) == "draining" and n in exited)]

    def check(self, states: dict[str, str]) -> bool:
        """Report hosts lost or back; True when one is lost and the graph says stop. A stage of
        another host is lost when its token is gone before it finished: its host died or was cut
        off for longer than the session lease, or it was stopped there (its last heartbeat says
        ``stopped``: interrupted, or its launcher died)."""
        with self._lock:
            gone = {n for n in self.remote if n in self.ever and n not in self.alive
                    and states.get(n) not in ("done", "draining")}
        new = gone - self.lost
        if new:
            # the rest of a lost host's stages usually follow within milliseconds: name them together
            hosts = {self.plan.stages[n].host for n in new}
            pending = {n for n in self.remote if self.plan.stages[n].host in hosts and n not in gone
                       and states.get(n) not in _FINISHED}
            now = time.monotonic()
            if self._first_gone is None:
                self._first_gone = now
            if pending and now - self._first_gone < self.settle_s:
                return False  # not yet: report the host once its other stages are gone too
        self._first_gone = None
        back = self.lost - gone
        self.lost = gone
        if back:
            self.say(f"host back: {describe_hosts(self.plan, back)}")
        if new:
            stopped = {n for n in new if states.get(n) == "stopped"}
            what = "host lost: " + "; ".join(
                f"{describe_hosts(self.plan, grp)} {why}" for grp, why in
                ((new - stopped, "stopped answering (liveliness token gone)"),
                 (stopped, "stopped before the end of the stream")) if grp)
            self.lost_report = what
            if self.plan.on_host_lost == "stop":
                self.say(what + "; stopping this host's stages (on_host_lost: stop)")
                return True
            self.say(what + "; waiting for it to come back (on_host_lost: wait)")
        return False
