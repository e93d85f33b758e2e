"""The one module that owns zenoh: session configuration, publishers and subscribers.

Defaults: peer mode on loopback, multicast scouting off, explicit endpoints. Stages find
each other through the launcher's listening endpoint (gossip scouting then links every
peer directly, so large payloads take zenoh's shared-memory path on one host).

Quality of service per topic:

* ``reliable`` (default, every recorded topic): reliable delivery, congestion control
  BLOCK. Nothing is dropped; a slow subscriber slows the publisher down.
* ``drop`` (live video that may drop under load): congestion control DROP. Drops are not
  silent: every subscriber counts gaps in the sequence numbers (``SeqJoin.gaps``) and the
  stage status reports them.

Facts measured with eclipse-zenoh 1.10 (see GUIDE.md): ``transport/unicast/lowlatency``
loses messages over ~60 KB without error, so it is never enabled here; sessions do not
survive ``fork``, so stage processes are started with ``subprocess`` and open their own.
"""

from __future__ import annotations

import json
import socket
import struct
import time
from dataclasses import dataclass, field
from typing import Callable, Literal

import zenoh

__all__ = ["ZenohSettings", "SessionError", "open_session", "open_reaching", "reached", "Bus", "topic_key", "free_port", "pack_attachment", "unpack_attachment"]

Mode = Literal["peer", "client", "router"]


@dataclass(frozen=True)
class ZenohSettings:
    """How a process joins the zenoh network.

    mode : peer (default), client or router.
    listen : endpoints to listen on, e.g. ``["tcp/127.0.0.1:7447"]``.
    connect : endpoints to connect to.
    multicast : enable multicast scouting (off by default: explicit endpoints only).
    shm : use zenoh's shared-memory transport between processes of one host (default on).
    shm_pool_mb : shared-memory pool size in MiB (zenoh's default, 16). Every receiver maps each
        sender's pool, which counts in its RSS; flow control bounds the frames in flight, so
        16 MiB holds them (the guide saw large colour frames slow with 16 MiB under no flow control).
    """

    mode: Mode = "peer"
    listen: tuple[str, ...] = ("tcp/127.0.0.1:0",)
    connect: tuple[str, ...] = ()
    multicast: bool = False
    shm_pool_mb: int = 16
    shm: bool = True

    def to_config(self) -> zenoh.Config:
        if self.mode not in ("peer", "client", "router"):
            raise ValueError(f"zenoh mode must be peer, client or router, got {self.mode!r}")
        c = zenoh.Config()
        c.insert_json5("mode", json.dumps(self.mode))
        c.insert_json5("scouting/multicast/enabled", json.dumps(bool(self.multicast)))
        if self.mode != "client":
            c.insert_json5("listen/endpoints", json.dumps(list(self.listen)))
        c.insert_json5("connect/endpoints", json.dumps(list(self.connect)))
        c.insert_json5("transport/shared_memory/enabled", json.dumps(bool(self.shm)))
        c.insert_json5("transport/shared_memory/transport_optimization/pool_size",
                       json.dumps(self.shm_pool_mb * 1024 * 1024))
        return c

    def to_json(self) -> dict:
        return {"mode": self.mode, "listen": list(self.listen), "connect": list(self.connect),
                "multicast": self.multicast, "shm_pool_mb": self.shm_pool_mb, "shm": self.shm}

    @classmethod
    def from_json(cls, d: dict) -> "ZenohSettings":
        return cls(mode=d.get("mode", "peer"), listen=tuple(d.get("listen", ("tcp/127.0.0.1:0",))),
                   connect=tuple(d.get("connect", ())), multicast=bool(d.get("multicast", False)),
                   shm_pool_mb=int(d.get("shm_pool_mb", 16)), shm=bool(d.get("shm", True)))


def free_port() -> int:
    """A TCP port on 127.0.0.1 that was free a moment ago."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class SessionError(RuntimeError):
    """A zenoh session could not be opened (a bad or busy endpoint); the message is one line."""


def open_session(settings: ZenohSettings) -> zenoh.Session:
    """Open a zenoh session; errors name the endpoints that failed."""
    try:
        return zenoh.open(settings.to_config())
    except Exception as e:  # zenoh raises ZError with a terse message
        raise SessionError(f"could not open a zenoh session ({settings.mode}, listen={list(settings.listen)}, "
                           f"connect={list(settings.connect)}): {e}") from None


def reached(session: zenoh.Session, timeout: float = 3.0) -> bool:
    """True once the session is linked to some other zenoh peer or router (within ``timeout`` s).
    A session whose ``connect`` endpoints lead nowhere opens without error in peer mode: this is
    how a tool tells "nothing there" from "nothing said"."""
    end = time.monotonic() + timeout
    while True:
        if any(True for _ in session.info.peers_zid()) or any(True for _ in session.info.routers_zid()):
            return True
        if time.monotonic() >= end:
            return False
        time.sleep(0.02)


def open_reaching(settings: ZenohSettings, timeout: float = 3.0) -> zenoh.Session:
    """:func:`open_session`, then, when it has ``connect`` endpoints, a :class:`SessionError` if it
    reaches nothing there within ``timeout`` s (a one-line message naming them)."""
    s = open_session(settings)
    if settings.connect and not reached(s, timeout):
        s.close()
        raise SessionError(f"reached nothing at {', '.join(settings.connect)} within {timeout:g} s (is a gflow "
                           f"pipeline or a zenoh router listening there, on an address this host can reach?)")
    return s


def topic_key(stream: str, topic: str) -> str:
    """Key expression ``gflow/<stream>/<topic>``."""
    if not stream or "/" in stream or "*" in stream:
        raise ValueError(f"stream id must be a non-empty name without '/' or '*', got {stream!r}")
    return f"gflow/{stream}/{topic}"


_ATT = struct.Struct("<qq")


def pack_attachment(publish_ns: int, seq: int, type_name: str = "") -> bytes:
    """Attachment carried by every gflow sample: publish time (ns), sequence number and the
    message type name (so a recorder can file JSON payloads, which carry no type tag)."""
    return _ATT.pack(publish_ns, seq) + type_name.encode("utf-8")


def unpack_attachment(b: bytes | None) -> tuple[int, int, str]:
    if not b or len(b) < _ATT.size:
        return 0, -1, ""
    ns, seq = _ATT.unpack_from(b)
    return ns, seq, b[_ATT.size:].decode("utf-8", "replace")


@dataclass
class Bus:
    """Publishers and subscribers of one process on one session.

    ``publish(topic, payload, seq)`` declares publishers lazily, with the QoS of the topic.
    ``subscribe(key, callback)`` delivers ``(key, payload, publish_ns, seq)`` on zenoh's
    thread: callbacks must only hand the data over (to a queue), never block.
    """

    session: zenoh.Session
    drop_topics: frozenset[str] = frozenset()
    _pubs: dict[str, zenoh.Publisher] = field(default_factory=dict)
    _subs: list = field(default_factory=list)
    sent: int = 0

    def publisher(self, key: str) -> zenoh.Publisher:
        pub = self._pubs.get(key)
        if pub is None:
            cc = zenoh.CongestionControl.DROP if key in self.drop_topics else zenoh.CongestionControl.BLOCK
            pub = self.session.declare_publisher(key, congestion_control=cc, reliability=zenoh.Reliability.RELIABLE)
            self._pubs[key] = pub
        return pub

    def publish(self, key: str, payload: bytes, seq: int, type_name: str = "") -> None:
        self.publisher(key).put(payload, attachment=pack_attachment(time.time_ns(), seq, type_name))
        self.sent += 1

    def subscribe(self, key: str, callback: Callable[..., None], with_type: bool = False) -> None:
        """``callback(key, payload, publish_ns, seq)``, plus ``type_name`` with ``with_type``."""
        def _cb(sample: zenoh.Sample) -> None:
            att = sample.attachment
            pub_ns, seq, type_name = unpack_attachment(att.to_bytes() if att is not None else None)
            if with_type:
                callback(str(sample.key_expr), sample.payload.to_bytes(), pub_ns, seq, type_name)
            else:
                callback(str(sample.key_expr), sample.payload.to_bytes(), pub_ns, seq)

        self._subs.append(self.session.declare_subscriber(key, _cb))
