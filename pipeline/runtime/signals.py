"""SIGINT / SIGTERM / SIGHUP handled on a thread of their own, never in a Python signal handler
that takes a lock: a Python handler runs on the main thread between two bytecodes, and one that
sets an ``Event`` deadlocks when the signal lands while the main thread holds that Event's lock
(seen: a stage process alive for good after its launcher's SIGKILL). Shared by the stage
processes (``pipeline/runtime/node.py``), the launcher and ``gflow router``.

How: Python's C-level signal handler writes the signal's number to a pipe
(``signal.set_wakeup_fd``) in whichever thread the kernel picked, at once and without a lock; a
``signals`` thread reads the pipe and calls back. The Python-level handler installed meanwhile
does nothing. (A ``sigwait`` thread with the signals blocked in the main thread is not enough:
the threads that numpy's BLAS and OpenCV start at import do not block them, the kernel hands a
process-directed signal to one of those, and then only the main thread's Python handler sees it,
which never runs while the main thread waits on a lock without a timeout.)
"""

from __future__ import annotations

import logging
import os
import signal
import threading
from types import FrameType
from typing import Any, Callable

__all__ = ["STOP_SIGNALS", "StopSignals"]

log = logging.getLogger("gflow.signals")

STOP_SIGNALS = frozenset({signal.SIGINT, signal.SIGTERM, signal.SIGHUP})
_CLOSE = 0  # the byte that tells the ``signals`` thread to end (no signal has number 0)


def _ignore(signum: int, frame) -> None:
    """The Python-level handler: the ``signals`` thread does the work (see the module doc)."""


class StopSignals:
    """Call ``on_signal(signum)`` on a ``signals`` thread for every SIGINT, SIGTERM and SIGHUP
    that reaches this process, from :meth:`start` until :meth:`close` (which puts the handlers
    and the wakeup fd back as they were). Use it as a context manager, or call :meth:`start`
    only when the process keeps it to its end (a stage process). Only the main thread can take
    signals: from another thread :meth:`start` does nothing."""

    def __init__(self, on_signal: Callable[[int], None]) -> None:
        self.on_signal = on_signal
        self._thread: threading.Thread | None = None
        self._fds: tuple[int, int] | None = None
        self._old_fd = -1
        self._old_handlers: dict[int, Callable[[int, FrameType | None], Any] | int | signal.Handlers | None] = {}

    def start(self) -> "StopSignals":
        if threading.current_thread() is not threading.main_thread():
            return self
        r, w = os.pipe()
        os.set_blocking(w, False)  # the C handler must never block
        self._fds = (r, w)
        self._thread = threading.Thread(target=self._read, args=(r,), name="signals", daemon=True)
        self._thread.start()
        self._old_fd = signal.set_wakeup_fd(w, warn_on_full_buffer=False)
        for s in STOP_SIGNALS:
            self._old_handlers[s] = signal.getsignal(s)
            signal.signal(s, _ignore)
        return self

    def _read(self, r: int) -> None:
        while True:
            try:
                data = os.read(r, 64)
            except OSError:
                return
            for signum in data:
                if signum == _CLOSE:
                    return
                if signum not in STOP_SIGNALS:
                    continue
                try:
                    self.on_signal(signum)
                except Exception:  # the next signal must still be taken
                    log.exception("handling signal %d", signum)

    def close(self) -> None:
        """Stop taking the signals: the handlers and the wakeup fd are restored, the thread ends."""
        if self._fds is None:
            return
        for s, h in self._old_handlers.items():
            signal.signal(s, h)
        self._old_handlers = {}
        signal.set_wakeup_fd(self._old_fd)
        r, w = self._fds
        self._fds = None
        os.write(w, bytes([_CLOSE]))
        if self._thread is not None:
            self._thread.join()
            self._thread = None
        os.close(r)
        os.close(w)

    def __enter__(self) -> "StopSignals":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()
