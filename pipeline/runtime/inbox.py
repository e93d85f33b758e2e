"""A hand-over queue between zenoh's callback thread and a stage's main thread, bounded in bytes.

The recorder is outside the source's flow control: when messages come faster than it can
write them (a burst of large frames, a slow disk), an unbounded queue grows without limit
(measured: 862 MB of recorder RSS on G-flow with 100 experts). With a bound, the callback
thread waits for room instead; zenoh's reliable, BLOCK-congestion topics then hold the
publishers back, so nothing is dropped and memory stays bounded
(``bench/bench_recorder.py`` prints the recorder's peak RSS under a burst).
"""

from __future__ import annotations

import threading
import time
from collections import deque
from typing import Any

__all__ = ["BoundedInbox"]


class BoundedInbox:
    """FIFO of ``(key, payload, ...)`` tuples holding at most ``max_bytes`` of payload.

    ``put`` blocks while the queue is non-empty and the new item would go over the bound (a
    single item larger than the bound still passes, alone). ``get``, ``get_nowait``,
    ``qsize`` and ``empty`` behave as ``queue.SimpleQueue``'s (``queue.Empty`` on timeout).
    """

    def __init__(self, max_bytes: int) -> None:
        if max_bytes <= 0:
            raise ValueError(f"max_bytes must be positive, got {max_bytes}")
        self.max_bytes = int(max_bytes)
        self._items: deque[tuple[Any, int]] = deque()
        self._bytes = 0
        self._cv = threading.Condition()
        self.waited_s = 0.0  # total time producers spent waiting for room (backpressure)
        self.waiting = 0  # producers waiting for room now
        self.peak_bytes = 0

    @staticmethod
    def _size(item: Any) -> int:
        payload = item[1] if isinstance(item, tuple) and len(item) > 1 else item
        try:
            return len(payload)
        except TypeError:
            return 0

    def put(self, item: Any) -> None:
        n = self._size(item)
        with self._cv:
            if self._items and self._bytes + n > self.max_bytes:
                t0 = time.monotonic()
                self.waiting += 1
                while self._items and self._bytes + n > self.max_bytes:
                    self._cv.wait()
                self.waiting -= 1
                self.waited_s += time.monotonic() - t0
            self._items.append((item, n))
            self._bytes += n
            self.peak_bytes = max(self.peak_bytes, self._bytes)
            self._cv.notify_all()

    def get(self, block: bool = True, timeout: float | None = None) -> Any:
        import queue

        with self._cv:
            if not self._items:
                if not block:
                    raise queue.Empty
                end = None if timeout is None else time.monotonic() + timeout
                while not self._items:
                    left = None if end is None else end - time.monotonic()
                    if left is not None and left <= 0:
                        raise queue.Empty
                    self._cv.wait(left)
            item, n = self._items.popleft()
            self._bytes -= n
            self._cv.notify_all()
            return item

    def get_nowait(self) -> Any:
        return self.get(block=False)

    def qsize(self) -> int:
        return len(self._items)

    def empty(self) -> bool:
        return not self._items

    @property
    def nbytes(self) -> int:
        return self._bytes
