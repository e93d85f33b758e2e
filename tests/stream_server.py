"""Live streams of real video on loopback, served by an FFmpeg process, for the live-source
tests and ``bench/bench_live.py``.

FFmpeg is the binary the ``imageio-ffmpeg`` package ships (a test extra), else the system's.
``tcp``: H.264 (libx264, zerolatency) in MPEG-TS, ``ffmpeg ... -f mpegts tcp://HOST:PORT?listen=1``;
``mjpeg``: MJPEG over HTTP as IP cameras serve it (``-f mpjpeg -listen 1 http://...``). Both
serve one client, paced at the frame rate (``-re``) from when the client connects.
"""

from __future__ import annotations

import shutil
import socket
import subprocess
import time
from pathlib import Path

__all__ = ["ffmpeg_exe", "StreamServer", "free_port"]


def ffmpeg_exe() -> str | None:
    """The FFmpeg binary: imageio-ffmpeg's, else the system's; None when there is neither."""
    try:
        import imageio_ffmpeg

        return imageio_ffmpeg.get_ffmpeg_exe()
    except (ImportError, RuntimeError):
        return shutil.which("ffmpeg")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _listening(port: int) -> bool:
    """Whether something listens on 127.0.0.1:PORT, read from /proc (connecting would take the
    server's one client)."""
    want = f"0100007F:{port:04X}"
    try:
        rows = Path("/proc/net/tcp").read_text().splitlines()[1:]
    except OSError:
        return True  # cannot tell: the client's open timeout covers it
    return any(r.split()[1] == want and r.split()[3] == "0A" for r in rows)


class StreamServer:
    """Serve ``frames_dir/%06d.jpg`` from frame ``start`` (``count`` frames, or to the end) at ``fps``.

    ``kind``: ``tcp`` (H.264 MPEG-TS over TCP) or ``mjpeg`` (MJPEG over HTTP).
    """

    def __init__(self, frames_dir: Path, kind: str = "tcp", fps: float = 25.0, start: int = 0,
                 count: int | None = None, port: int | None = None) -> None:
        exe = ffmpeg_exe()
        if exe is None:
            raise RuntimeError("no FFmpeg: pip install imageio-ffmpeg (a test extra), or install ffmpeg")
        self.exe, self.frames_dir, self.kind, self.fps = exe, Path(frames_dir), kind, fps
        self.start_frame, self.count = start, count
        self.port = port or free_port()
        self.proc: subprocess.Popen | None = None

    @property
    def url(self) -> str:
        return (f"tcp://127.0.0.1:{self.port}" if self.kind == "tcp"
                else f"http://127.0.0.1:{self.port}/cam.mjpg")

    def command(self) -> list[str]:
        cmd = [self.exe, "-hide_banner", "-loglevel", "error", "-re", "-framerate", f"{self.fps:g}",
               "-start_number", str(self.start_frame), "-i", str(self.frames_dir / "%06d.jpg")]
        if self.count is not None:
            cmd += ["-frames:v", str(self.count)]
        if self.kind == "tcp":
            return cmd + ["-c:v", "libx264", "-tune", "zerolatency", "-preset", "ultrafast", "-f", "mpegts",
                          f"tcp://127.0.0.1:{self.port}?listen=1"]
        return cmd + ["-c:v", "mjpeg", "-q:v", "3", "-f", "mpjpeg", "-listen", "1", self.url]

    def start(self, timeout: float = 10.0) -> "StreamServer":
        """Start FFmpeg and wait until it listens."""
        self.proc = subprocess.Popen(self.command(), stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                     stderr=subprocess.PIPE, start_new_session=True)
        end = time.monotonic() + timeout
        while not _listening(self.port):
            if self.proc.poll() is not None:
                raise RuntimeError(f"ffmpeg exited at once: {self.proc.stderr.read().decode()[-300:]}")
            if time.monotonic() > end:
                self.stop()
                raise RuntimeError(f"ffmpeg did not listen on port {self.port} within {timeout:g} s")
            time.sleep(0.02)
        return self

    def stop(self) -> None:
        """Kill the server (as a camera that goes away does) and reap it."""
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()
        if self.proc is not None:
            self.proc.wait(timeout=10)
            if self.proc.stderr is not None:
                self.proc.stderr.close()

    def wait(self, timeout: float) -> int | None:
        """Wait for the server to finish serving; its exit status (None: still serving)."""
        assert self.proc is not None
        try:
            return self.proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            return None

    def __enter__(self) -> "StreamServer":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()
