"""The one module that owns zenoh: session configuration, publishers and subscribers.

Defaults: peer mode on loopback, multicast scouting off, explicit endpoints. Stages find
each other through the launcher's listening endpoint (gossip scouting then links every
peer directly, so large payloads take zenoh's shared-memory path on one host).

Quality of service per topic:

* ``reliable`` (default, every recorded topic): reliable delivery, congestion control
  BLOCK. Nothing is dropped; a slow subscriber slows the publisher down.
* ``drop`` (live video that may drop under load): congestion control DROP. Drops are not
  silent: every subscriber counts gaps in the sequence numbers (``SeqJoin.gaps``) and the
  stage status reports them. The end of stream on a drop topic is still sent with BLOCK (a
  publisher of its own on the same key, behind the data in the same queue), so it always
  arrives, and a finished stage can wait for the recorder to have written it
  (:mod:`pipeline.runtime.drain`).

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

from pipeline.runtime.security import Security, Signer, explain_refusal

__all__ = ["ZenohSettings", "SessionError", "open_session", "open_reaching", "reached", "Bus", "topic_key", "free_port", "pack_attachment", "unpack_attachment",
           "sample_source", "check_key_expr"]

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
    security : TLS / mTLS, user/password and run key (see :mod:`pipeline.runtime.security`).
    """

    mode: Mode = "peer"
    listen: tuple[str, ...] = ("tcp/127.0.0.1:0",)
    connect: tuple[str, ...] = ()
    multicast: bool = False
    shm_pool_mb: int = 16
    shm: bool = True
    security: Security | None = None
    #: peer mode: whether opening waits to connect to the peers it heard of (zenoh's default, up to
    #: its 500 ms scouting delay when they are still starting); a stage process's handshake waits
    #: for every peer's heartbeat itself, so it opens at once (pipeline/runtime/node.py)
    connect_scouted: bool = True

    def to_config(self) -> zenoh.Config:
        if self.mode not in ("peer", "client", "router"):
            raise ValueError(f"zenoh mode must be peer, client or router, got {self.mode!r}")
        c = zenoh.Config()
        c.insert_json5("mode", json.dumps(self.mode))
        c.insert_json5("scouting/multicast/enabled", json.dumps(bool(self.multicast)))
        if self.mode != "client":
            c.insert_json5("listen/endpoints", json.dumps(list(self.listen)))
        c.insert_json5("connect/endpoints", json.dumps(list(self.connect)))
        if not self.connect_scouted:
            c.insert_json5("open/return_conditions/connect_scouted", "false")
        c.insert_json5("transport/shared_memory/enabled", json.dumps(bool(self.shm)))
        c.insert_json5("transport/shared_memory/transport_optimization/pool_size",
                       json.dumps(self.shm_pool_mb * 1024 * 1024))
        for path, value in (self.security.zenoh_entries(self.mode != "client") if self.security else {}).items():
            c.insert_json5(path, json.dumps(value))
        return c

    def to_json(self) -> dict:
        return {"mode": self.mode, "listen": list(self.listen), "connect": list(self.connect),
                "multicast": self.multicast, "shm_pool_mb": self.shm_pool_mb, "shm": self.shm,
                "security": self.security.to_json() if self.security else None}

    @classmethod
    def from_json(cls, d: dict) -> "ZenohSettings":
        return cls(mode=d.get("mode", "peer"), listen=tuple(d.get("listen", ("tcp/127.0.0.1:0",))),
                   connect=tuple(d.get("connect", ())), multicast=bool(d.get("multicast", False)),
                   shm_pool_mb=int(d.get("shm_pool_mb", 16)), shm=bool(d.get("shm", True)),
                   security=Security.from_json(d.get("security")))


def free_port() -> int:
    """A TCP port on 127.0.0.1 that was free a moment ago."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class SessionError(RuntimeError):
    """A zenoh session could not be opened (a bad or busy endpoint); the message is one line."""


def open_session(settings: ZenohSettings) -> zenoh.Session:
    """Open a zenoh session; errors name the endpoints that failed (and why, when it can be told)."""
    try:
        session = zenoh.open(settings.to_config())
        if settings.mode == "peer" and settings.connect and settings.security is not None:
            _check_linked(session, settings)
        return session
    except SessionError:
        raise
    except Exception as e:  # zenoh raises ZError with a terse message
        why = explain_refusal(settings.connect, settings.security) if settings.mode == "client" else ""
        if why:
            raise SessionError(f"could not connect to {', '.join(settings.connect)}: {why}") from None
        raise SessionError(f"could not open a zenoh session ({settings.mode}, listen={list(settings.listen)}, "
                           f"connect={list(settings.connect)}): {str(e).split(' at /')[0]}") from None


def _check_linked(session: zenoh.Session, settings: ZenohSettings, wait: float = 1.0) -> None:
    """In peer mode zenoh opens a session even when every ``connect`` endpoint refused it (a TLS or
    login mismatch): with security settings, that is an error, said in one line. (An endpoint where
    nothing listens yet is not: zenoh keeps trying it, as without security.)"""
    end = time.monotonic() + wait
    while not (list(session.info.peers_zid()) or list(session.info.routers_zid())):
        if time.monotonic() > end:
            why = explain_refusal(settings.connect, settings.security)
            if why and not why.startswith("nothing accepts connections"):
                session.close()
                raise SessionError(f"could not connect to {', '.join(settings.connect)}: {why}")
            return
        time.sleep(0.02)


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


def check_key_expr(key: str) -> str:
    """``key`` when zenoh takes it as a key expression; else a :class:`ValueError` saying why in zenoh's
    words (``empty chunks are forbidden, ...``, ``` `#` and `?` are forbidden characters```), without the
    location in zenoh's source its message ends with. Made before a session opens: a subscriber declared
    on such a key raises only then."""
    try:
        zenoh.KeyExpr(key)
    except zenoh.ZError as e:
        why = str(e).split(" at /")[0].rstrip(".")
        raise ValueError(why.removeprefix(f"Invalid Key Expr `{key}`: ")) from None
    return key


def sample_source(sample: zenoh.Sample) -> str:
    """The zenoh session that published a sample (its id in hex), from the source info every
    :meth:`Bus.publish` attaches; "" for a sample without one (a publisher outside gflow).
    Without a run key nothing is authenticated: this tells the run's own stages from another
    peer that publishes on the same topic, not from one that forges the source info."""
    info = sample.source_info
    return str(info.source_id.zid) if info is not None else ""


_ATT = struct.Struct("<qq")


def pack_attachment(publish_ns: int, seq: int, type_name: str = "", tag: bytes = b"") -> bytes:
    """Attachment carried by every gflow sample: publish time (ns), sequence number and the
    message type name (so a recorder can file JSON payloads, which carry no type tag), then, in
    a signed run, a NUL and the sample's tag (:class:`pipeline.runtime.security.Signer`)."""
    return _ATT.pack(publish_ns, seq) + type_name.encode("utf-8") + (b"\0" + tag if tag else b"")


def unpack_attachment(b: bytes | None) -> tuple[int, int, str]:
    if not b or len(b) < _ATT.size:
        return 0, -1, ""
    ns, seq = _ATT.unpack_from(b)
    return ns, seq, b[_ATT.size:].split(b"\0", 1)[0].decode("utf-8", "replace")


def attachment_tag(b: bytes | None) -> bytes:
    """The signature tag of an attachment (b"" when unsigned)."""
    if not b or len(b) <= _ATT.size:
        return b""
    rest = b[_ATT.size:]
    i = rest.find(b"\0")
    return rest[i + 1:] if i >= 0 else b""


@dataclass
class Bus:
    """Publishers and subscribers of one process on one session.

    ``publish(topic, payload, seq)`` declares publishers lazily, with the QoS of the topic.
    ``subscribe(key, callback)`` delivers ``(key, payload, publish_ns, seq)`` on zenoh's
    thread: callbacks must only hand the data over (to a queue), never block.
    With a ``signer`` (a run key) every sample published is signed and every sample received
    without a valid tag is dropped and counted in ``foreign`` (by key expression).
    """

    session: zenoh.Session
    drop_topics: frozenset[str] = frozenset()
    _pubs: dict[tuple[str, bool], zenoh.Publisher] = field(default_factory=dict)
    _sns: dict[int, tuple[zenoh.EntityGlobalId, list[int]]] = field(default_factory=dict)  # by id(publisher)
    _subs: list = field(default_factory=list)
    sent: int = 0
    signer: Signer | None = None
    foreign: dict[str, int] = field(default_factory=dict)

    def publisher(self, key: str, block: bool = False) -> zenoh.Publisher:
        """The publisher of ``key``: congestion control DROP on a drop topic unless ``block``."""
        drop = key in self.drop_topics and not block
        pub = self._pubs.get((key, drop))
        if pub is None:
            cc = zenoh.CongestionControl.DROP if drop else zenoh.CongestionControl.BLOCK
            pub = self.session.declare_publisher(key, congestion_control=cc, reliability=zenoh.Reliability.RELIABLE)
            self._pubs[(key, drop)] = pub
            self._sns[id(pub)] = (pub.id, [0])
        return pub

    def publish(self, key: str, payload: bytes, seq: int, type_name: str = "") -> None:
        ns = time.time_ns()
        tag = self.signer.tag(key, seq, ns, payload) if self.signer is not None else b""
        # the end of stream is never dropped, even on a drop topic (see the module docstring)
        pub = self.publisher(key, block=type_name == "EndOfStream")
        # the sample names its publisher (session and entity) and counts its samples: a receiver
        # tells the run's own stages from another session on the same topic (sample_source)
        eid, sn = self._sns[id(pub)]
        sn[0] += 1
        pub.put(payload, attachment=pack_attachment(ns, seq, type_name, tag), source_info=zenoh.SourceInfo(eid, sn[0]))
        self.sent += 1

    def subscribe(self, key: str, callback: Callable[..., None], with_type: bool = False,
                  with_source: bool = False) -> None:
        """``callback(key, payload, publish_ns, seq)``, plus ``type_name`` with ``with_type``, plus
        the publisher's session (:func:`sample_source`) with ``with_source``."""
        def _cb(sample: zenoh.Sample) -> None:
            att = sample.attachment
            raw = att.to_bytes() if att is not None else None
            pub_ns, seq, type_name = unpack_attachment(raw)
            payload = sample.payload.to_bytes()
            if self.signer is not None and not self._signed(str(sample.key_expr), seq, pub_ns, payload, raw):
                return
            extra: tuple = (type_name,) if with_type else ()
            if with_source:
                extra += (sample_source(sample),)
            callback(str(sample.key_expr), payload, pub_ns, seq, *extra)

        self._subs.append(self.session.declare_subscriber(key, _cb))

    def _signed(self, key: str, seq: int, pub_ns: int, payload: bytes, raw: bytes | None) -> bool:
        """Whether a sample carries this run's signature; a foreign one is counted and logged once."""
        assert self.signer is not None
        if self.signer.valid(key, seq, pub_ns, payload, attachment_tag(raw)):
            return True
        n = self.foreign[key] = self.foreign.get(key, 0) + 1
        if n == 1:
            import logging

            logging.getLogger(__name__).warning("ignored a message on %s that is not signed with this run's key "
                                                "(a sender outside the run)", key)
        return False
