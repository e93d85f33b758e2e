"""What a native decoder said: the warnings libjpeg, libpng and OpenCV's own AVI reader print on
standard error while OpenCV decodes an image or opens a video, caught so that a damaged file is
reported by the run, with the decoder's reason, rather than left as a stray line on the terminal.

libjpeg decodes a JPEG whose data is damaged inside (bytes overwritten, a segment cut short) into a
whole image whose lower part is grey or garbage, and says so only by printing "Corrupt JPEG data:
premature end of data segment" (measured with opencv-python-headless 5.1: ``cv2.imdecode`` returns
the image, and ``cv2.utils.logging`` does not hold these lines back). OpenCV's MJPEG AVI reader
prints "Unexpected element. Expected: LIST. Got: ..." (with the file's raw bytes) on a header it
cannot read, before ``VideoCapture`` says only that it did not open. FFmpeg's decoders, reading a
video file, decode a frame whose bytes are damaged inside into a whole image and say so only as
"[mjpeg @ 0x...] overread 8" (measured on an MJPG AVI with 200 bytes of one frame overwritten:
``VideoCapture.read`` returns that frame, its lower part garbage, and succeeds).

:func:`decoder_messages` points file descriptor 2 at a temporary file for one call; lines a decoder
wrote are returned (non-printing bytes shown as ``?``), and anything else written meanwhile (by
another thread) is passed on to the real standard error afterwards, so nothing is lost.
"""

from __future__ import annotations

import os
import re
import sys
import tempfile
import threading
from contextlib import contextmanager, nullcontext
from typing import IO, Iterator

__all__ = ["decoder_messages"]

#: the beginnings of what libjpeg (jerror.h's warnings and errors), libpng and OpenCV's AVI container print
_DECODER = re.compile(r"^(Corrupt JPEG data|Premature end of JPEG file|Invalid JPEG|Bogus |Unsupported JPEG|"
                      r"Not a JPEG file|JPEG datastream|Warning: unknown JFIF|Inconsistent progression|"
                      r"Huffman table|Invalid SOS|libpng (warning|error)|Unexpected element|"
                      r"Can't find|Unexpected end of file|"
                      # FFmpeg's own lines, "[mjpeg @ 0x55d2...] overread 8": OpenCV holds FFmpeg to its error
                      # level (AV_LOG_ERROR) unless OPENCV_FFMPEG_LOGLEVEL says otherwise, so each is an error
                      r"\[[^\]@]+ @ 0x[0-9a-fA-F]+\] )")
_LOCK = threading.Lock()  # one redirection of descriptor 2 at a time in the process


_ADDRESS = re.compile(r" @ 0x[0-9a-fA-F]+\]")


def _printable(line: str) -> str:
    """``line`` with non-printing bytes as ``?`` and FFmpeg's context address left out ("[mjpeg] overread 8"):
    the address changes from run to run, and these lines go into recordings."""
    return "".join(c if c.isprintable() else "?" for c in _ADDRESS.sub("]", line.strip()))


#: OpenCV's AVI reader prints a chunk's four raw bytes ("Got: %s.\n"), read from the file or from past its end: any of
#: them may be a newline, which split its line in two and left the second part on the terminal
_FOURCC = re.compile(rb"(Expected: [^\n]{0,8}\. Got: )(.{0,4}?)(\.\r?\n)", re.S)


def _lines(raw: bytes) -> list[str]:
    """What was written to descriptor 2, a line (with its end) each: the raw bytes an AVI reader quotes made
    printable first, and lines split at newlines only (``str.splitlines`` also splits at form feeds and the like)."""
    raw = _FOURCC.sub(lambda m: m[1] + bytes(b if 32 <= b < 127 else 63 for b in m[2]) + m[3], raw)
    *whole, last = raw.decode("utf-8", "replace").split("\n")
    return [line + "\n" for line in whole] + ([last] if last else [])


@contextmanager
def _redirected(fd: int) -> Iterator[IO[bytes]]:
    """Descriptor ``fd`` pointed at a temporary file for the block (C's buffered output flushed into it before it
    is given back); the file is yielded, to be read (:func:`_written`) before the block ends."""
    from pipeline.io.ffmpeg_messages import _flush_c_stdio

    with tempfile.TemporaryFile() as tmp:
        (sys.stdout if fd == 1 else sys.stderr).flush()
        saved = os.dup(fd)
        os.dup2(tmp.fileno(), fd)
        try:
            yield tmp
        finally:
            _flush_c_stdio()
            os.dup2(saved, fd)
            os.close(saved)


def _written(tmp: IO[bytes]) -> bytes:
    """Everything written to ``tmp`` so far, from its start (its offset, shared with the descriptor, left as is)."""
    return os.pread(tmp.fileno(), os.fstat(tmp.fileno()).st_size, 0)


def _sort(raw: bytes, fd: int, said: list[str]) -> None:
    """The decoders' lines of ``raw`` (what was written to ``fd``) into ``said``; the rest written on to ``fd``.
    On descriptor 1 only FFmpeg's lines as OpenCV prints them when ``OPENCV_FFMPEG_LOGLEVEL`` is set
    ("[OPENCV:FFMPEG:16] overread 8") are a decoder's, and of those only errors and warnings of damage."""
    from pipeline.io.ffmpeg_messages import _PREFIX, is_damage

    passed = []
    for line in _lines(raw):
        routed = _PREFIX.match(line.strip()) if fd == 1 else None
        if routed and is_damage(int(routed.group(1)), line.strip()[routed.end():]):
            said.append("FFmpeg: " + _printable(line.strip()[routed.end():]))
        elif fd == 2 and _DECODER.match(line.strip()):
            said.append(_printable(line))
        elif line.strip():
            passed.append(line)
    if passed:
        os.write(fd, "".join(passed).encode())


@contextmanager
def decoder_messages() -> Iterator[list[str]]:
    """``with decoder_messages() as said: cv2.imdecode(...)``: ``said`` holds, after the block, the
    lines a decoder printed during it (empty for a clean decode). With ``OPENCV_FFMPEG_LOGLEVEL`` set (by the user,
    or by a live source earlier in the process), OpenCV prints FFmpeg's lines on standard output instead of
    standard error, so descriptor 1 is caught too."""
    said: list[str] = []
    routed = "OPENCV_FFMPEG_LOGLEVEL" in os.environ
    from pipeline.io.ffmpeg_messages import _flush_c_stdio

    with _LOCK:
        captured: list[tuple[int, bytes]] = []
        try:
            with _redirected(2) as err, (_redirected(1) if routed else nullcontext()) as out:
                try:
                    yield said
                finally:
                    _flush_c_stdio()
                    captured = [(2, _written(err))] + ([(1, _written(out))] if out is not None else [])
        finally:
            for fd, raw in captured:
                _sort(raw, fd, said)
