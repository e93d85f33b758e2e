"""A sender of an MPEG-TS file at its own pace, over TCP (it listens and serves one client) or
UDP (it sends datagrams to a port whether anyone listens or not), for the live-input tests.

The file is made constant-rate (``encode_cbr``: x264 CBR in a TS padded to ``-muxrate``), so
sending its bytes at that rate sends its frames in real time. What a network does to a stream
is done to the bytes: ``--outage T:D`` sends nothing of the stream's seconds T to T + D (the
camera goes on, the packets are lost), ``--stall T:D`` stops sending at T for D seconds and goes
on where it stopped (nothing lost). Run as a process::

    python tests/ts_sender.py FILE.ts udp PORT --rate 125000 [--outage 3:2.2] [--stall 3:1]
        [--when-bound [--watch-pid PID]] [--hold-at-frame N]

It prints ``sending`` when it sends its first byte (for UDP: at once; for TCP: when the client
connected), ``outage`` / ``back`` around a gap, and ``done`` at the end, each with the time.
With ``--when-bound`` a UDP sender first waits until something has bound the port (polling
``/proc/net/udp`` and ``/proc/net/udp6``, for at most ``--deadline`` seconds) and prints
``bound TIME after N polls``; with ``--watch-pid`` the line goes on with ``loaded: ...``, which
of zenoh, msgspec and cv2 that process had loaded then (``none`` shows the port was bound before
they loaded; with N = 0 it was bound before the first poll, so a module loaded then shows nothing).
With ``--hold-at-frame N`` the sender stops before the first byte of the stream's frame N (the TS
packet that starts its PES), prints ``held TIME`` and waits for a line on its standard input (or its
end), then prints ``released TIME`` and goes on at the stream's pace from there (nothing lost): the
receiver has every frame before N and nothing after, for as long as the test needs.
"""

from __future__ import annotations

import argparse
import socket
import subprocess
import sys
import time
from pathlib import Path

__all__ = ["encode_cbr", "corrupt", "frame_offset", "udp_port_bound", "loaded_modules", "MUXRATE", "HEAVY_MODULES"]

#: the TS's constant rate in bits/s (x264 at 800 kbit/s padded to 1 Mbit/s)
MUXRATE = 1_000_000
DATAGRAM = 7 * 188
#: the modules whose load a command's early UDP bind comes before (pipeline/io/udp_relay.py)
HEAVY_MODULES = ("zenoh", "msgspec", "cv2")


def encode_cbr(ffmpeg: str, frames_dir: Path, out: Path, count: int, fps: float = 25.0, gop: int = 25) -> Path:
    """``count`` frames of ``frames_dir/%06d.jpg`` as constant-rate H.264 in MPEG-TS (a keyframe
    every ``gop`` frames, as cameras send)."""
    subprocess.run([ffmpeg, "-hide_banner", "-loglevel", "error", "-y", "-framerate", f"{fps:g}",
                    "-i", str(frames_dir / "%06d.jpg"), "-frames:v", str(count), "-c:v", "libx264",
                    "-preset", "ultrafast", "-tune", "zerolatency", "-g", str(gop), "-b:v", "800k",
                    "-maxrate", "800k", "-bufsize", "200k", "-x264-params", "nal-hrd=cbr",
                    "-muxrate", str(MUXRATE), "-f", "mpegts", str(out)], check=True)
    return out


def corrupt(src: Path, dst: Path, offset: int, n: int) -> Path:
    """A copy of ``src`` with ``n`` bytes of video inverted from ``offset`` on (what a bad link does
    to the picture): payload bytes of the video's TS packets (PID 0x100, FFmpeg's), not the packet
    headers nor the packets that start a frame (its timestamps), nor the padding a constant-rate
    stream carries (which would damage nothing)."""
    data = bytearray(src.read_bytes())
    pos = offset - offset % 188
    while n > 0 and pos + 188 <= len(data):
        pid = ((data[pos + 1] & 0x1F) << 8) | data[pos + 2]
        starts = bool(data[pos + 1] & 0x40)
        if data[pos] == 0x47 and pid == 0x100 and not starts and not data[pos + 3] & 0x20:  # no adaptation field
            for i in range(pos + 4, min(pos + 188, pos + 4 + n)):
                data[i] ^= 0xFF
            n -= 184
        pos += 188
    dst.write_bytes(bytes(data))
    return dst


def frame_offset(data: bytes, n: int) -> int:
    """The byte offset of the TS packet that starts video frame ``n`` (0-based) of ``data``: the
    (n+1)-th packet of the video PID (0x100, FFmpeg's) with payload_unit_start set (FFmpeg's muxer
    puts one frame in each video PES)."""
    seen = 0
    for pos in range(0, len(data) - 187, 188):
        pid = ((data[pos + 1] & 0x1F) << 8) | data[pos + 2]
        if data[pos] == 0x47 and pid == 0x100 and data[pos + 1] & 0x40:
            if seen == n:
                return pos
            seen += 1
    raise ValueError(f"the stream has {seen} video frames, not {n + 1}")


def udp_port_bound(port: int) -> bool:
    """Whether some socket on this host has bound UDP ``port`` (IPv4 or IPv6), as ``/proc/net`` lists them."""
    suffix = f":{port:04X}"
    for table in ("/proc/net/udp", "/proc/net/udp6"):
        try:
            with open(table) as f:
                lines = f.readlines()[1:]
        except FileNotFoundError:  # no IPv6 here
            continue
        if any(line.split()[1].endswith(suffix) for line in lines if len(line.split()) > 1):
            return True
    return False


def loaded_modules(pid: int) -> list[str]:
    """Which of :data:`HEAVY_MODULES` process ``pid`` has loaded: their shared libraries in its memory map."""
    try:
        with open(f"/proc/{pid}/maps") as f:
            paths = {line.split()[-1] for line in f if "/" in line}
    except OSError:
        return []
    # each is a package directory with a compiled extension (zenoh/, msgspec/, cv2/)
    return [m for m in HEAVY_MODULES if any(f"/{m}/" in p and ".so" in p for p in paths)]


def wait_bound(port: int, deadline_s: float, pid: int | None) -> str | None:
    """Poll until UDP ``port`` is bound (every 2 ms, for ``deadline_s``); the line to print, or None."""
    end = time.monotonic() + deadline_s
    polls = 0
    while not udp_port_bound(port):
        if time.monotonic() > end:
            return None
        polls += 1
        time.sleep(0.002)
    line = f"bound {time.time():.3f} after {polls} polls"
    if pid is not None:
        line += f"; loaded: {','.join(loaded_modules(pid)) or 'none'}"
    return line


def _window(text: str | None) -> tuple[float, float] | None:
    if not text:
        return None
    t, d = text.split(":")
    return float(t), float(d)


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("file")
    ap.add_argument("proto", choices=["tcp", "udp"])
    ap.add_argument("port", type=int)
    ap.add_argument("--rate", type=float, default=MUXRATE / 8, help="bytes per second")
    ap.add_argument("--outage", help="T:D: the stream's seconds T to T + D are lost")
    ap.add_argument("--stall", help="T:D: at T, stop sending for D seconds, then go on")
    ap.add_argument("--when-bound", action="store_true", help="UDP: send once something has bound the port")
    ap.add_argument("--deadline", type=float, default=60.0, help="seconds --when-bound waits at most")
    ap.add_argument("--watch-pid", type=int, help="with --when-bound: say what this process had loaded then")
    ap.add_argument("--hold-at-frame", type=int, help="stop before frame N until a line on standard input")
    a = ap.parse_args(argv)
    if a.when_bound and a.proto != "udp":
        ap.error("--when-bound is for UDP (a TCP sender is the server)")
    data = Path(a.file).read_bytes()
    outage, stall = _window(a.outage), _window(a.stall)
    hold = None if a.hold_at_frame is None else frame_offset(data, a.hold_at_frame)
    if a.proto == "tcp":
        srv = socket.socket()
        srv.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        srv.bind(("127.0.0.1", a.port))
        srv.listen(1)
        print("listening", flush=True)
        conn, _ = srv.accept()
        send = conn.sendall
    else:
        if a.when_bound:
            said = wait_bound(a.port, a.deadline, a.watch_pid)
            if said is None:
                print(f"ts_sender: nothing bound UDP port {a.port} within {a.deadline:g} s", file=sys.stderr)
                return 1
            print(said, flush=True)
        udp = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)

        def send(b: bytes) -> None:
            try:
                udp.sendto(b, ("127.0.0.1", a.port))
            except ConnectionRefusedError:  # an ICMP port-unreachable from an earlier datagram
                pass

    print(f"sending {time.time():.3f}", flush=True)
    t0 = time.monotonic()
    paused = 0.0
    held = 0.0  # seconds the sender waited at --hold-at-frame
    in_outage = False
    for off in range(0, len(data), DATAGRAM):
        at = off / a.rate  # the stream's second of this datagram
        if stall is not None and at >= stall[0] and not paused:
            print(f"stall {time.time():.3f}", flush=True)
            time.sleep(stall[1])
            paused = stall[1]
            print(f"back {time.time():.3f}", flush=True)
        due = t0 + paused + held + at
        delay = due - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        if outage is not None and outage[0] <= at < outage[0] + outage[1]:
            if not in_outage:
                in_outage = True
                print(f"outage {time.time():.3f}", flush=True)
            continue
        if in_outage:
            in_outage = False
            print(f"back {time.time():.3f}", flush=True)
        chunk = data[off:off + DATAGRAM]
        try:
            if hold is not None and off <= hold < off + DATAGRAM:
                send(chunk[:hold - off])  # every byte before frame N
                print(f"held {time.time():.3f}", flush=True)
                t_held = time.monotonic()
                sys.stdin.readline()
                held = time.monotonic() - t_held  # the rest goes at the stream's pace from here
                print(f"released {time.time():.3f}", flush=True)
                chunk = chunk[hold - off:]
            send(chunk)
        except (BrokenPipeError, ConnectionResetError):
            break
    print(f"done {time.time():.3f}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
