"""A UDP stream's port, bound before the pipeline starts, so a sender that starts first loses nothing.

A UDP sender does not wait for its receiver: a datagram sent to a port nobody has bound yet is
dropped. The source stage opens its stream while the pipeline starts, seconds after ``gflow
track`` began (its process, zenoh, the handshake), so a sender started together with it lost
its first frames, and ``--init``, the box in the first frame received, fell on a later frame
of the video than the user meant.

:class:`UdpRelay` binds the port at once, in the launching process, and keeps every datagram
from then on; the source stage reads them as an MPEG-TS byte stream over a TCP connection on
loopback (``relay_url``), which FFmpeg opens as it would the UDP port. The URL also says since
when the relay has kept the stream (:data:`KEPT_SINCE`, removed before FFmpeg sees it): the
first frames read may have waited that long, which the frame numbers allow for
(:mod:`pipeline.io.frame_numbers`). ``gflow track udp://...``
binds it first thing (:func:`bind_early`, called by ``pipeline/cli/main.py`` before its imports). The datagrams are kept
in memory while no reader is connected (at most ``max_bytes``: beyond that the oldest are
dropped and counted), and passed on as they come while one is. A reader that reconnects (the
source's reconnect after a read timeout) gets what arrived meanwhile.

Only streams that are plain bytes over UDP are relayed (``udp://`` with a unicast or wildcard
address: MPEG-TS, as cameras and FFmpeg send it); a multicast group, and RTP (``rtp://``, whose
datagram boundaries matter), are opened by FFmpeg itself as before. Like FFmpeg's own UDP input,
the relay binds the port on every address unless the URL names ``localaddr``.
"""

from __future__ import annotations

import collections
import ipaddress
import selectors
import socket
import threading
import time
from urllib.parse import parse_qs, urlsplit

__all__ = ["UdpRelay", "relayed_udp", "bind_early", "relay_for", "joined_midway", "kept_since", "KEPT_SINCE"]

#: the receive buffer asked of the kernel for the bound port
RCVBUF = 8 * 2**20
#: bytes kept while no reader is connected
MAX_BYTES = 256 * 2**20
#: the relay URL's parameter that says since when (host clock, ns) the relay has kept the stream:
#: its first frames may have waited that long (pipeline/io/frame_numbers.py); the reader removes it
KEPT_SINCE = "gflow_kept_since_ns"


def relayed_udp(url: str) -> tuple[str, int] | None:
    """``(address, port)`` to bind for a ``udp://`` URL the relay serves, else None."""
    parts = urlsplit(url)
    if parts.scheme.lower() != "udp":
        return None
    host = (parts.hostname or "").strip("@")
    try:
        port = parts.port
    except ValueError:
        return None
    query = parse_qs(parts.query)
    port = int(query.get("localport", [port or 0])[0])
    if not port:
        return None
    if host:
        try:
            if ipaddress.ip_address(host).is_multicast:
                return None
        except ValueError:  # a host name: FFmpeg binds every address for it too
            pass
    return query.get("localaddr", ["0.0.0.0"])[0], port


#: MPEG-TS: a packet's size and sync byte; the PIDs of the tables a muxer writes first (PAT, SDT)
TS_PACKET, TS_SYNC, TS_FIRST_PIDS = 188, 0x47, (0x0000, 0x0011)


def joined_midway(data: bytes) -> str | None:
    """What says that ``data``, the first datagram received, is not the start of its MPEG-TS stream.

    A muxer begins a stream with its tables (the PAT, or FFmpeg's SDT before it), each PID's
    4-bit continuity counter at 0; a first packet of another PID or a later count means the
    sender was sending before the port was bound and what it sent before is lost. None when the
    datagram begins a stream, or is not MPEG-TS (nothing can be said).
    """
    if len(data) < 4 or data[0] != TS_SYNC:
        return None
    pid = ((data[1] & 0x1F) << 8) | data[2]
    cc = data[3] & 0x0F
    if pid in TS_FIRST_PIDS and cc == 0:
        return None
    return f"its first packet is PID 0x{pid:x} at continuity {cc}, not a stream's first table"


class UdpRelay:
    """Bind ``url``'s UDP port now and serve what arrives on ``relay_url`` (module docstring).

    Raises OSError (as from ``bind``) when the port cannot be bound.
    """

    def __init__(self, url: str, max_bytes: int = MAX_BYTES) -> None:
        where = relayed_udp(url)
        if where is None:
            raise ValueError(f"{url} is not a UDP stream the relay serves")
        self.url = url
        self.max_bytes = max_bytes
        self._on_first = None  # told (on the relay's thread) when the first datagram comes
        self._lock = threading.Lock()
        self.bound_at = time.time()
        bound_ns = time.time_ns()
        self.first_at = 0.0  # when the first datagram came (0: none yet)
        self.midway: str | None = None  # why the first datagram is not its stream's start (None: it is)
        self.datagrams = 0
        self.bytes = 0
        self.dropped_bytes = 0  # kept too long without a reader: the oldest went
        self._udp = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self._udp.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RCVBUF)
            self._udp.bind(where)
            self._tcp = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            self._tcp.bind(("127.0.0.1", 0))
            self._tcp.listen(2)
        except OSError:
            self._udp.close()
            raise
        self._udp.setblocking(False)
        self._tcp.setblocking(False)
        self.relay_url = f"tcp://127.0.0.1:{self._tcp.getsockname()[1]}?{KEPT_SINCE}={bound_ns}"
        self._pending: collections.deque[bytes] = collections.deque()
        self._pending_bytes = 0
        self._client: socket.socket | None = None
        self._closing = threading.Event()
        self._thread = threading.Thread(target=self._serve, name="udp-relay", daemon=True)
        self._thread.start()

    def _keep(self, data: bytes) -> None:
        self._pending.append(data)
        self._pending_bytes += len(data)
        while self._pending_bytes > self.max_bytes and self._client is None:
            old = self._pending.popleft()
            self._pending_bytes -= len(old)
            self.dropped_bytes += len(old)

    def _serve(self) -> None:
        sel = selectors.DefaultSelector()
        sel.register(self._udp, selectors.EVENT_READ, "udp")
        sel.register(self._tcp, selectors.EVENT_READ, "accept")
        while not self._closing.is_set():
            for key, events in sel.select(timeout=0.1):
                if key.data == "udp":
                    while True:
                        try:
                            data = self._udp.recv(65536)
                        except (BlockingIOError, InterruptedError):
                            break
                        except OSError:
                            break
                        if not self.first_at:
                            with self._lock:
                                self.midway = joined_midway(data)
                                self.first_at = time.time()
                                tell = self._on_first
                            if tell is not None:
                                tell(self.first_line())
                        self.datagrams += 1
                        self.bytes += len(data)
                        self._keep(data)
                elif key.data == "accept":
                    try:
                        conn, _ = self._tcp.accept()
                    except OSError:
                        continue
                    if self._client is not None:  # a reader that reconnects: the new connection reads on
                        sel.unregister(self._client)
                        self._client.close()
                    conn.setblocking(False)
                    self._client = conn
                    sel.register(conn, selectors.EVENT_READ, "client")
                elif key.data == "client" and events & selectors.EVENT_READ and self._client is not None:
                    try:
                        gone = not self._client.recv(4096)  # FFmpeg sends nothing: b"" is the reader gone
                    except (BlockingIOError, InterruptedError):
                        gone = False
                    except OSError:
                        gone = True
                    if gone:
                        sel.unregister(self._client)
                        self._client.close()
                        self._client = None
            self._flush()
            if self._client is not None:  # wake when the reader can take more, while something waits
                sel.modify(self._client, selectors.EVENT_READ | (selectors.EVENT_WRITE if self._pending else 0),
                           "client")
        sel.close()

    def _flush(self) -> None:
        """Pass on what is kept while the reader takes it (a full socket buffer: later)."""
        c = self._client
        while c is not None and self._pending:
            data = self._pending[0]
            try:
                n = c.send(data)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:  # the reader went: keep the rest for the next one
                return
            self._pending_bytes -= n
            if n < len(data):
                self._pending[0] = data[n:]
                return
            self._pending.popleft()

    def first_line(self) -> str:
        return (f"{self.url}: the first data arrived {self.first_at - self.bound_at:.2f} s after the port was bound"
                + self.midway_note())

    def midway_note(self) -> str:
        """The warning, for a stream joined after it began (else '')."""
        if self.midway is None:
            return ""
        return (f"; the stream had begun before the port was bound ({self.midway}): what the sender sent before "
                "is lost, and frame 0 of the results (where --init goes) is the first frame received, not the "
                "sender's first")

    def tell_first(self, on_first) -> None:
        """Have ``on_first(line)`` told when the first datagram comes (now, if it came already)."""
        with self._lock:
            self._on_first = on_first
            came = self.first_at
        if came and on_first is not None:
            on_first(self.first_line())

    def lines(self) -> list[str]:
        """What to tell the user at the end: when the first data came, how much was relayed."""
        if not self.first_at:
            return [f"{self.url}: listened from before the pipeline started; no data arrived"]
        out = [f"{self.url}: listened from before the pipeline started; the first data arrived "
               f"{self.first_at - self.bound_at:.2f} s after the port was bound ({self.datagrams} datagrams, "
               f"{self.bytes / 2**20:.1f} MiB)" + self.midway_note()]
        if self.dropped_bytes:
            out.append(f"{self.url}: {self.dropped_bytes / 2**20:.1f} MiB dropped while no reader took them "
                       f"(more than {self.max_bytes / 2**20:.0f} MiB waited)")
        return out

    def close(self) -> None:
        self._closing.set()
        self._thread.join(timeout=2.0)
        for s in (self._client, self._tcp, self._udp):
            if s is not None:
                s.close()
        self._client = None


#: relays bound by :func:`bind_early`, by URL, until the run takes them (:func:`relay_for`)
_EARLY: dict[str, UdpRelay] = {}


def kept_since(url: str) -> tuple[str, int]:
    """``url`` without the relay's :data:`KEPT_SINCE` parameter, and its time (``url`` and 0 when it has none)."""
    head, _, query = url.partition("?")
    params = query.split("&") if query else []
    since = [q.split("=", 1)[1] for q in params if q.startswith(KEPT_SINCE + "=")]
    if not since:
        return url, 0
    rest = [q for q in params if not q.startswith(KEPT_SINCE + "=")]
    return head + ("?" + "&".join(rest) if rest else ""), int(since[-1]) if since[-1].isdigit() else 0


def bind_early(argv: list[str]) -> None:
    """``gflow track udp://...``: bind the port first thing, before the command's imports (which take
    a second or more on a busy machine), so a sender started with the command loses nothing."""
    if not argv or argv[0] != "track":
        return
    for a in argv[1:]:
        if a not in _EARLY and relayed_udp(a) is not None:
            try:
                _EARLY[a] = UdpRelay(a)
            except (OSError, ValueError):  # the source will open it and say why it cannot
                pass


def relay_for(url: str) -> UdpRelay:
    """The relay of ``url``: the one :func:`bind_early` made, else a new one (OSError if the port
    cannot be bound)."""
    return _EARLY.pop(url, None) or UdpRelay(url)
