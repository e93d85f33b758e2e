"""Joining inputs by sequence number (pipeline/runtime/join.py)."""

from pipeline.runtime.join import SeqJoin


def _run(join, required=None):
    req = required or (lambda s: frozenset(join.ports))
    return [(s, {k: v for k, v in ins.items()}) for s, ins in join.ready(req)]


def test_releases_in_seq_order_only_when_complete():
    j = SeqJoin(("a", "b"), frozenset({"a", "b"}))
    j.push("a", 0, "a0")
    j.push("a", 1, "a1")
    assert _run(j) == []
    j.push("b", 1, "b1")  # b moved past 0: seq 0 is released with b missing
    out = _run(j)
    assert out == [(0, {"a": "a0", "b": None}), (1, {"a": "a1", "b": "b1"})]


def test_arrival_order_does_not_change_the_result():
    msgs = [("a", 0), ("b", 0), ("a", 1), ("b", 1), ("a", 2), ("b", 2)]
    results = []
    for order in (msgs, msgs[::2] + msgs[1::2]):
        j = SeqJoin(("a", "b"), frozenset({"a"}))
        got = []
        for port, seq in order:
            j.push(port, seq, f"{port}{seq}")
            got += _run(j)
        j.end("a", 3)
        j.end("b", 3)
        got += _run(j)
        results.append(got)
    assert results[0] == results[1]


def test_driver_end_finishes_even_if_other_ports_continue():
    j = SeqJoin(("features", "proposals"), frozenset({"features"}))
    j.push("features", 0, "f0")
    assert _run(j, lambda s: frozenset({"features"})) == [(0, {"features": "f0", "proposals": None})]
    j.push("proposals", 1, "p1")
    j.end("features", 1)
    assert _run(j) == [] and j.finished


def test_late_and_duplicate_messages_are_counted_and_dropped():
    j = SeqJoin(("a",), frozenset({"a"}))
    j.push("a", 0, 0)
    _run(j)
    j.push("a", 0, 0)
    j.push("a", 2, 2)  # gap of one
    assert j.stale == 1 and j.gaps == {"a": 1}
