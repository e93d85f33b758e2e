"""Hostile and missing input at the stage host (pipeline/runtime/stage_host.py, pipeline/runtime/join.py), without
processes: every bad message is rejected and counted before it is joined, and the
proposal -> filter cycle never waits for ever."""

from __future__ import annotations

import time

import numpy as np
import pytest

from pipeline.runtime.stage_host import StageHost
from pipeline.runtime.join import SeqJoin
from stages.base import StageContext
from gflow_msgs.messages import Features, Frame, Header, NDArray, Particles, encode
from stages.particle_filter import FilterParams, FilterStage
from stages.particle_proposal import ProposalParams, ProposalStage
from stages.preprocess import PreprocessParams, PreprocessStage

H, W = 48, 64


def _frame(seq: int, shape=(H, W, 3), rng=None) -> Frame:
    rng = rng or np.random.default_rng(seq)
    img = np.zeros(shape, np.uint8)
    img[10:30, 20:40] = 200
    img = np.clip(img + rng.integers(0, 20, shape), 0, 255).astype(np.uint8)
    return Frame(header=Header("s", seq, 0), image=NDArray.of(img))


def _particles(seq: int, n: int = 20, value: float = 10.0) -> Particles:
    alpha = np.tile([30.0, 20.0, 0.0, 1.0], (n, 1))
    alpha[0, 0] = value
    return Particles(header=Header("s", seq, 0), kind="posterior", alpha=NDArray.of(alpha),
                     k=NDArray.of(np.zeros(n, np.int64)), log_w=NDArray.of(np.zeros(n)))


class Sink:
    def __init__(self) -> None:
        self.out: list[tuple[str, int, str]] = []

    def __call__(self, topic: str, payload: bytes, seq: int, type_name: str = "") -> None:
        self.out.append((topic, seq, type_name))

    def seqs(self, topic: str, type_name: str) -> list[int]:
        return [s for t, s, n in self.out if t == topic and n == type_name]

    def errors(self) -> int:
        return sum(1 for t, _, _ in self.out if t == "errors")


def _preprocess(sink: Sink, window: int = 8) -> StageHost:
    st = PreprocessStage(PreprocessParams(canny_low=20, canny_high=60), StageContext("preprocess", "s"))
    h = StageHost(st, {"frames": "frames"}, {"features": "features"}, "errors", sink, window=window)
    h.frame_shape = (H, W)
    return h


def test_bad_messages_are_rejected_counted_and_never_joined():
    sink = Sink()
    h = _preprocess(sink)
    h.source_seq = 3
    for s in range(3):
        h.deliver("frames", encode(_frame(s)))
    assert sink.seqs("features", "Features") == [0, 1, 2]
    bad = {
        "future_seq": encode(_frame(3 + 9 + 1000)),
        # another message of a frame already consumed (a byte-identical copy is a restarted
        # producer's repeat, counted and ignored: test_faults_restart.py)
        "old_seq": encode(_frame(1, rng=np.random.default_rng(101))),
        "duplicate_seq": encode(_frame(2, rng=np.random.default_rng(102))),
        "malformed_message": b"\x93\x01\x02 garbage",
        "wrong_type": encode(_particles(3)),
    }
    huge = Frame(header=Header("s", 3, 0), image=NDArray("uint8", (10**6, 10**6, 3), b"\x00" * 12))
    overflow = Frame(header=Header("s", 3, 0), image=NDArray("uint8", (2**32, 2**32, 2**8), b""))
    other_size = _frame(3, shape=(H + 2, W, 3))
    for payload in bad.values():
        h.deliver("frames", payload)
    for msg in (huge, overflow, other_size):
        h.deliver("frames", encode(msg))
    assert sink.seqs("features", "Features") == [0, 1, 2]  # nothing bad produced anything
    rej = h.stats.rejected
    for kind in bad:
        assert rej.get(kind) == 1, (kind, rej)
    assert rej.get("bad_array") == 3, rej
    assert sum(rej.values()) == len(bad) + 3 == sink.errors()
    # the real frame 3 still goes through
    h.deliver("frames", encode(_frame(3)))
    assert sink.seqs("features", "Features") == [0, 1, 2, 3]


def test_nan_and_inf_particles_are_rejected():
    sink = Sink()
    st = ProposalStage(ProposalParams(), StageContext("proposal", "s"))
    h = StageHost(st, {"particles": "particles"}, {"proposals": "proposals"}, "errors", sink)
    for v in (np.nan, np.inf, -np.inf):
        h.deliver("particles", encode(_particles(0, value=v)))
    assert h.stats.rejected == {"bad_values": 3} and sink.seqs("proposals", "Particles") == []
    h.deliver("particles", encode(_particles(0)))
    assert sink.seqs("proposals", "Particles") == [1]


def test_an_input_just_ahead_of_the_source_announcement_is_held_until_the_announcement_comes():
    """The source's position and the inputs travel on different links: an input up to one more
    window past the limit is held (not rejected) and joined once an announcement covers it;
    one further ahead, or one the source never covers before the end, is rejected."""
    sink = Sink()
    h = _preprocess(sink)  # window 8: the limit is source + 9
    h.source_seq = 3
    for s in range(4):
        h.deliver("frames", encode(_frame(s)))
    h.deliver("frames", encode(_frame(13)))  # 1 past the limit: held
    h.deliver("frames", encode(_frame(22)))  # past the limit by more than a window: rejected
    assert h.stats.rejected == {"future_seq": 1} and sink.errors() == 1
    assert [seq for _, seq, _ in h.early["frames"]] == [13]
    h.source_seq = 12  # the announcement arrives
    h.tick(60.0)
    assert 13 in sink.seqs("features", "Features") and not h.early["frames"]
    h.deliver("frames", encode(_frame(24)))  # held again, and never covered
    assert h.stats.rejected == {"future_seq": 1}
    h.close()
    assert h.stats.rejected == {"future_seq": 2} and sink.errors() == 2
    assert 24 not in sink.seqs("features", "Features")


def test_without_the_source_position_future_seqs_are_not_judged():
    sink = Sink()
    h = _preprocess(sink)
    h.deliver("frames", encode(_frame(500)))  # no source heard: nothing to compare with
    assert sink.seqs("features", "Features") == [500]


def _filter(sink: Sink, lag: int = 0) -> StageHost:
    st = FilterStage(FilterParams(init=(20, 10, 20, 20), particles=30), StageContext("filter", "s"))
    return StageHost(st, {"features": "features", "proposals": "proposals"},
                     {"particles": "particles", "estimate": "estimate"}, "errors", sink, lag=lag)


def _features(seq: int) -> Features:
    e = np.zeros((H, W), np.uint8)
    e[10:30, 20] = 255
    e[10, 20:40] = 255
    from gflow_core.features import chamfer_image

    return Features(Header("s", seq, 0), NDArray.of(e), NDArray.of(e),
                    NDArray.of(chamfer_image(e).astype(np.float32)), "truncated", 100.0)


def test_a_lost_proposal_is_given_up_when_the_stream_is_lag_frames_ahead():
    sink = Sink()
    h = _filter(sink, lag=4)
    h.deliver("features", encode(_features(0)))  # initialises
    for s in range(1, 5):
        h.deliver("features", encode(_features(s)))
    assert sink.seqs("estimate", "Estimate") == [0]  # waits for the proposals of frame 1
    assert "waiting for proposals" in h.waiting()
    h.deliver("features", encode(_features(5)))  # 4 frames further on: frame 1 goes on without
    assert sink.seqs("estimate", "Estimate") == [0, 1]
    assert h.join.timed_out == 1


def test_the_wall_time_rule_releases_a_frame_when_the_source_is_ahead():
    sink = Sink()
    h = _filter(sink)
    h.deliver("features", encode(_features(0)))
    h.deliver("features", encode(_features(1)))
    h.tick(0.05)  # the source is not known to be ahead: keep waiting
    assert sink.seqs("estimate", "Estimate") == [0]
    h.source_seq = 2
    deadline = time.monotonic() + 5
    while sink.seqs("estimate", "Estimate") == [0]:
        assert time.monotonic() < deadline
        h.tick(0.05)
        time.sleep(0.01)
    assert sink.seqs("estimate", "Estimate") == [0, 1]


def test_the_wall_time_rule_counts_from_when_a_frame_became_next_not_from_its_first_input():
    """Inputs that run ahead (a cycle-bound stage's frames, a whole window early) must not
    make a healthy cycle give up its next frame at once."""
    sink = Sink()
    h = _filter(sink)
    h.source_seq = 3
    for s in range(3):
        h.deliver("features", encode(_features(s)))
    h.tick(0.2)  # frame 1 becomes the next frame now
    t_first = time.monotonic()
    while time.monotonic() - t_first < 0.3:  # frame 2's features have waited 0.3 s ...
        time.sleep(0.05)
    h.deliver("proposals", encode(_particles(1)))  # ... and frame 1 is done: frame 2 is next
    assert sink.seqs("estimate", "Estimate") == [0, 1]
    h.tick(0.2)
    assert sink.seqs("estimate", "Estimate") == [0, 1], "frame 2 was given up the moment it became next"
    deadline = time.monotonic() + 5
    while sink.seqs("estimate", "Estimate") == [0, 1]:  # its own wait then releases it
        assert time.monotonic() < deadline
        h.tick(0.2)
        time.sleep(0.01)
    assert sink.seqs("estimate", "Estimate") == [0, 1, 2]


def test_a_resumed_filter_fills_the_frames_it_missed_and_reseeds_on_the_first_one_it_has():
    sink = Sink()
    a = _filter(sink)
    a.deliver("features", encode(_features(0)))
    snap = a.stage.snapshot()
    sink2 = Sink()
    b = _filter(sink2)
    b.stage.restore(snap)
    b.join.done_below = 0
    b.join.resumed = True
    b.deliver("features", encode(_features(4)))  # frames 1-3 were lost while it was down
    assert sink2.seqs("estimate", "Estimate") == [1, 2, 3, 4]
    assert b.stats.lost == 3
    b.deliver("proposals", encode(_particles(5)))
    b.deliver("features", encode(_features(5)))
    assert sink2.seqs("estimate", "Estimate") == [1, 2, 3, 4, 5]


@pytest.mark.parametrize("lag", [0, 3])
def test_join_gives_up_a_silent_port_only_lag_frames_behind(lag):
    j = SeqJoin(("a", "b"), frozenset({"a"}), lag=lag, fill_gaps=True)
    out = []
    for s in range(8):
        j.push("a", s, s)
        if s < 2:
            j.push("b", s, s)  # then b falls silent
        out += [q for q, _ in j.ready(lambda q: frozenset({"a", "b"}))]
    assert out == sorted(out) and len(set(out)) == len(out)
    # without a lag the join waits for b; with one, it goes on to lag frames behind a
    assert out == ([0, 1] if lag == 0 else list(range(8 - lag)))
    assert j.timed_out == len(out) - 2
