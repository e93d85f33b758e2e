"""The recorder's inbox: bounded in bytes, FIFO, a full one makes the producer wait (never drops)."""

from __future__ import annotations

import queue
import threading
import time

import pytest

from pipeline.runtime.inbox import BoundedInbox


def test_fifo_and_empty():
    q = BoundedInbox(100)
    assert q.empty() and q.qsize() == 0
    for i in range(3):
        q.put(("k", b"x" * 10, i))
    assert q.qsize() == 3 and q.nbytes == 30
    assert [q.get()[2] for _ in range(3)] == [0, 1, 2]
    with pytest.raises(queue.Empty):
        q.get_nowait()
    with pytest.raises(queue.Empty):
        q.get(timeout=0.01)


def test_a_full_inbox_holds_the_producer_back_and_loses_nothing():
    q = BoundedInbox(100)
    q.put(("k", b"a" * 60, 0))
    q.put(("k", b"b" * 40, 1))  # exactly at the bound
    third = threading.Event()

    def producer() -> None:
        q.put(("k", b"c" * 10, 2))  # over the bound: waits for room
        third.set()

    th = threading.Thread(target=producer, daemon=True)
    th.start()
    deadline = time.monotonic() + 30
    while not q.waiting:  # however late the producer thread runs
        assert not third.is_set(), "put went over the bound instead of waiting"
        assert time.monotonic() < deadline, "the producer never reached put"
        time.sleep(0.005)
    assert not third.is_set() and q.nbytes == 100
    assert q.get()[2] == 0  # room for it now
    assert third.wait(10), "the producer was not woken when room was made"
    th.join(10)
    assert [q.get()[2], q.get()[2]] == [1, 2]
    assert q.peak_bytes == 100 and q.waited_s > 0


def test_an_item_larger_than_the_bound_passes_alone():
    q = BoundedInbox(10)
    q.put(("k", b"x" * 50, 0))  # empty queue: it goes in
    assert q.nbytes == 50
    assert q.get()[2] == 0


def test_a_bound_must_be_positive():
    with pytest.raises(ValueError, match="max_bytes"):
        BoundedInbox(0)
