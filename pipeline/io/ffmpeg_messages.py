"""What FFmpeg said: the messages OpenCV's FFmpeg backend prints, kept to explain a failure.

OpenCV's FFmpeg backend reads ``OPENCV_FFMPEG_LOGLEVEL`` once, at the first FFmpeg capture of
the process. When it is set, FFmpeg's messages up to that level go through OpenCV's callback,
which ``printf``\\ s them to standard output as ``[OPENCV:FFMPEG:16] Connection to
tcp://127.0.0.1:9 failed: Connection refused`` (measured with opencv-python-headless 5.0; when
the variable is unset they go to standard error with FFmpeg's own prefixes instead).

:class:`FfmpegMessages` sets the level to warnings before the first live capture opens, points
file descriptor 1 at a temporary file for as long as it is active, and reads the file on
demand (:meth:`FfmpegMessages.collect`: FFmpeg's lines since the last call); anything else written to descriptor 1 is
passed on to the real standard output, so nothing printed by the program is lost.
"""

from __future__ import annotations

import ctypes
import os
import re
import sys
import tempfile
import threading
from typing import IO

__all__ = ["FfmpegMessages", "ffmpeg_messages", "is_damage"]

#: FFmpeg's warning level (AV_LOG_WARNING): at the error level an HTTP 404 says nothing
LOG_LEVEL = "24"
#: FFmpeg's error level (AV_LOG_ERROR): a decoder says so when a frame could not be decoded whole
ERROR_LEVEL = 16
_PREFIX = re.compile(r"^\[OPENCV:FFMPEG:(\d+)\]\s*")
#: warnings that mean the stream's bytes were damaged (the demuxer's corrupt-packet and continuity
#: checks, the decoder's concealment), not the many that do not (a deprecated pixel format)
_DAMAGE = re.compile(r"corrupt|concealing|error while decoding|missing picture|invalid|out of range|mismatch|"
                     r"continuity|decode_slice", re.IGNORECASE)


def is_damage(level: int, text: str) -> bool:
    """Whether an FFmpeg message read while decoding a live stream says a frame was damaged: any
    error (a decoder that could not decode a slice says so at the error level, then conceals it)
    or a warning about corrupt or missing data."""
    return level <= ERROR_LEVEL or bool(_DAMAGE.search(text))


class FfmpegMessages:
    """FFmpeg's messages in this process, captured from file descriptor 1 (see the module docstring)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._file: IO[bytes] | None = None
        self._saved_fd = -1
        self._pos = 0
        self._users = 0
        self._partial = ""

    def start(self) -> "FfmpegMessages":
        """Begin capturing (nested calls are counted; :meth:`stop` undoes the last)."""
        with self._lock:
            self._users += 1
            if self._users > 1:
                return self
            os.environ["OPENCV_FFMPEG_LOGLEVEL"] = LOG_LEVEL  # read at the first FFmpeg capture only
            try:
                import cv2

                cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)  # OpenCV's own warnings
            except (ImportError, AttributeError):
                pass
            _flush_c_stdio()
            sys.stdout.flush()
            self._file = tempfile.TemporaryFile()
            self._saved_fd = os.dup(1)
            os.dup2(self._file.fileno(), 1)
            self._pos = 0
        return self

    def stop(self) -> None:
        with self._lock:
            self._users -= 1
            if self._users > 0 or self._file is None:
                return
            self._collect_locked()
            os.dup2(self._saved_fd, 1)
            os.close(self._saved_fd)
            self._file.close()
            self._file, self._saved_fd = None, -1

    def collect(self) -> list[str]:
        """Read what was written since the last call; returns FFmpeg's new lines."""
        return [text for _, text in self.collect_levels()]

    def collect_levels(self) -> list[tuple[int, str]]:
        """:meth:`collect`, each line with FFmpeg's level (16 error, 24 warning)."""
        with self._lock:
            return self._collect_locked()

    def _collect_locked(self) -> list[tuple[int, str]]:
        if self._file is None:
            return []
        _flush_c_stdio()
        data = os.pread(self._file.fileno(), 1 << 20, self._pos)
        self._pos += len(data)
        text = self._partial + data.decode("utf-8", "replace")
        *complete, self._partial = text.split("\n")
        new = []
        passthrough = []
        for line in complete:
            m = _PREFIX.match(line)
            if m is None:
                passthrough.append(line + "\n")
            elif line[m.end():].strip() and "Immediate exit requested" not in line:
                new.append((int(m.group(1)), line[m.end():].strip()))  # (that one is FFmpeg obeying our own timeout)
        if passthrough and self._saved_fd >= 0:
            os.write(self._saved_fd, "".join(passthrough).encode())
        return new


def _flush_c_stdio() -> None:
    """Flush C's stdio buffers: OpenCV's callback writes with printf, buffered on a file."""
    try:
        ctypes.CDLL(None).fflush(None)
    except (OSError, AttributeError):
        pass


_SHARED = FfmpegMessages()


def ffmpeg_messages() -> FfmpegMessages:
    """The process's one capture of FFmpeg's messages."""
    return _SHARED
