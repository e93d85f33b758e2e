"""SIGINT / SIGTERM / SIGHUP taken on a thread of their own (``sigwait``), never in a Python
signal handler: a handler runs on the main thread between two bytecodes, and one that sets an
``Event`` deadlocks when the signal lands while the main thread holds that Event's lock
(seen: a stage process alive for good after its launcher's SIGKILL). Shared by the stage
processes (``pipeline/runtime/node.py``), the launcher and ``gflow router``.

The signals are blocked in the thread that calls :meth:`StopSignals.start` (the main thread),
so every thread started after it, zenoh's runtime threads too, inherits the mask and only the
``sigwait`` thread takes them. A thread started before may still be picked by the kernel for a
process-directed signal; the Python handler installed meanwhile then only forwards the signal
to the ``sigwait`` thread (``pthread_kill``: no lock taken), so the callback still runs there.
"""

from __future__ import annotations

import logging
import signal
import threading
from typing import Callable

__all__ = ["STOP_SIGNALS", "StopSignals"]

log = logging.getLogger("gflow.signals")

STOP_SIGNALS = frozenset({signal.SIGINT, signal.SIGTERM, signal.SIGHUP})


class StopSignals:
    """Call ``on_signal(signum)`` on a ``signals`` thread for every SIGINT, SIGTERM and SIGHUP
    that reaches this process, from :meth:`start` until :meth:`close` (which restores the
    signal mask and the Python handlers as they were). Use it as a context manager, or call
    :meth:`start` only when the process keeps it to its end (a stage process)."""

    def __init__(self, on_signal: Callable[[int], None]) -> None:
        self.on_signal = on_signal
        self._thread: threading.Thread | None = None
        self._closing = False
        self._old_mask: set[int] | None = None
        self._old_handlers: dict[int, object] = {}

    def start(self) -> "StopSignals":
        self._old_mask = set(signal.pthread_sigmask(signal.SIG_BLOCK, STOP_SIGNALS))
        self._thread = threading.Thread(target=self._wait, name="signals", daemon=True)
        self._thread.start()
        if threading.current_thread() is threading.main_thread():
            for s in STOP_SIGNALS:
                self._old_handlers[s] = signal.getsignal(s)
                signal.signal(s, self._forward)
        return self

    def _forward(self, signum: int, frame) -> None:
        """A thread that does not block the signals took one: hand it to the ``sigwait`` thread."""
        t = self._thread
        if t is not None and t.ident is not None and t.is_alive():
            signal.pthread_kill(t.ident, signum)

    def _wait(self) -> None:
        while True:
            signum = signal.sigwait(STOP_SIGNALS)
            if self._closing:
                return
            try:
                self.on_signal(signum)
            except Exception:  # the next signal must still be taken
                log.exception("handling signal %d", signum)

    def close(self) -> None:
        """Stop taking the signals: the ``sigwait`` thread ends, the mask and handlers are restored."""
        t = self._thread
        if t is None:
            return
        self._closing = True
        if t.is_alive() and t.ident is not None:
            signal.pthread_kill(t.ident, signal.SIGHUP)  # wakes the sigwait; taken as the closing signal
            t.join()
        self._thread = None
        for s, h in self._old_handlers.items():
            signal.signal(s, h)  # type: ignore[arg-type]
        self._old_handlers = {}
        if self._old_mask is not None:
            signal.pthread_sigmask(signal.SIG_SETMASK, self._old_mask)

    def __enter__(self) -> "StopSignals":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()
