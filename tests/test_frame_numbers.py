"""The camera's frame numbers from a stream's timestamps (pipeline/io/frame_numbers.py): gaps
counted exactly, repeated timestamps, and clocks that restart or jump ahead of the host's."""

from __future__ import annotations

from pipeline.io.frame_numbers import FrameNumbers

RATE = 25.0
T0 = 10**18  # host clock, ns


def feed(numbers: FrameNumbers, frames: list[tuple[float, float]], reopened_at: int = -1) -> list:
    """(pts in frame periods, host seconds) -> Numbered for each."""
    return [numbers.number(pts, T0 + int(t * 1e9), i == reopened_at) for i, (pts, t) in enumerate(frames)]


def test_a_gap_in_the_timestamps_is_counted_and_skipped_in_the_numbers() -> None:
    # 35, 36, 37, then 2.2 s of stream lost; the frame before the gap is handed over late (demuxer)
    frames = [(35, 0.00), (36, 0.04), (37, 2.30), (93, 2.32), (94, 2.36)]
    out = feed(FrameNumbers(RATE), frames)
    assert [n.frame for n in out] == [0, 1, 2, 58, 59]
    assert [n.missed for n in out] == [0, 0, 0, 55, 0] and all(n.exact for n in out)


def test_repeated_timestamp_takes_the_next_number() -> None:
    out = feed(FrameNumbers(RATE), [(10, 0.0), (11, 0.04), (11, 0.08), (13, 0.12)])
    assert [n.frame for n in out] == [0, 1, 2, 3] and out[3].missed == 0


def test_clock_that_restarts_or_runs_ahead_is_numbered_by_the_host_clock() -> None:
    # a reconnect to a sender that started again (its clock back at 35) after 2 s away
    out = feed(FrameNumbers(RATE), [(500, 0.0), (501, 0.04), (35, 2.04), (36, 2.08)], reopened_at=2)
    assert [n.frame for n in out] == [0, 1, 51, 52] and out[2].missed == 49 and not out[2].exact
    assert "went back" in out[2].jump
    # a jump of 1000 frame periods (40 s) in 0.04 s of the host's time is no gap of 999 frames
    out = feed(FrameNumbers(RATE), [(0, 0.0), (1, 0.04), (1001, 0.08), (1002, 0.12)])
    assert [n.frame for n in out] == [0, 1, 2, 3] and "jumped" in out[2].jump


def test_no_timestamps_counts_frames_and_estimates_a_reconnect() -> None:
    out = feed(FrameNumbers(RATE), [(-9.2e18, 0.0), (-9.2e18, 0.04), (-9.2e18, 1.04)], reopened_at=2)
    assert [n.frame for n in out] == [0, 1, 26] and out[2].missed == 24 and not out[2].exact


def spans_add_up(out: list) -> bool:
    """Every number is the last one's plus one plus the frames missed before it: frames numbered +
    frames missed = the camera's span, whatever the host clock's estimate said."""
    return all(b.frame == a.frame + 1 + b.missed for a, b in zip(out, out[1:]))


def test_a_late_first_frame_and_a_burst_after_it_are_no_discontinuity() -> None:
    # the source opened 5 s after the sender began: frame 0 is read late, and the 99 frames buffered
    # behind it (4 s of stream) are read in 0.1 s, so the stream's clock runs 4 s ahead of the host's
    frames = [(7 + i, 5.0 + 0.001 * i) for i in range(100)] + [(107 + i, 5.1 + 0.04 * (i + 1)) for i in range(25)]
    out = feed(FrameNumbers(RATE), frames)
    assert [n.frame for n in out] == list(range(125))
    assert all(n.exact and not n.jump and not n.missed for n in out), [n for n in out if n.jump][:1]


def test_an_outage_inside_a_backlog_is_counted_by_the_timestamps() -> None:
    # frames 0-49, 2.2 s lost, 105-149: kept from t = 0 (a relay bound before the sender began) and
    # all of it read in a burst when the source opened 5 s in
    frames = [(i, 5.0 + 0.001 * i) for i in range(50)] + [(i, 5.06 + 0.001 * i) for i in range(105, 150)]
    out = feed(FrameNumbers(RATE, since_ns=T0), frames)
    assert [n.frame for n in out] == list(range(50)) + list(range(105, 150)), [n.frame for n in out][48:52]
    assert out[50].missed == 55 and out[50].exact and not out[50].jump and spans_add_up(out)
    # the same read 4.1 s in, the backlog's last frames handed over at the pace of the data after the
    # outage (the decoder holds them until more comes): 105 is read 0.35 s after frame 46, 2.2 s
    # of the stream's time ahead of every frame before it
    frames = ([(i, 4.1 + 0.001 * i) for i in range(47)] + [(47 + i, 4.27 + 0.04 * i) for i in range(3)]
              + [(i, 4.5 + 0.04 * (i - 105)) for i in range(105, 150)])
    out = feed(FrameNumbers(RATE, since_ns=T0), frames)
    assert [n.frame for n in out] == list(range(50)) + list(range(105, 150))
    assert out[50].missed == 55 and not out[50].jump
    # a clock 1000 frame periods (40 s) ahead inside that backlog: more than the 5 s it can have been kept
    frames = [(i, 5.0 + 0.001 * i) for i in range(50)] + [(1050 + i, 5.06 + 0.001 * i) for i in range(10)]
    out = feed(FrameNumbers(RATE, since_ns=T0), frames)
    assert [n.frame for n in out] == list(range(60)) and "jumped" in out[50].jump and spans_add_up(out)


def test_a_clock_that_jumps_ahead_while_frames_come_at_their_pace_is_still_a_discontinuity() -> None:
    # frames at the camera's pace, then its clock 1000 frame periods ahead: the host's 0.04 s hold
    # no 999 frames; after a burst the same jump, live, is judged by the same rule
    frames = [(i, 0.04 * i) for i in range(30)] + [(1030 + i, 1.2 + 0.04 * i) for i in range(5)]
    out = feed(FrameNumbers(RATE), frames)
    assert [n.frame for n in out] == list(range(35)) and "jumped" in out[30].jump and not out[30].exact
    assert spans_add_up(out)


def test_a_sender_restarted_mid_stream_or_ahead_on_a_reconnect_is_numbered_by_the_host_clock() -> None:
    # its clock back at 35 without a reconnect (a UDP sender restarted within the read timeout),
    # 1 s after the last frame
    out = feed(FrameNumbers(RATE), [(500, 0.0), (501, 0.04), (35, 1.04), (36, 1.08)])
    assert [n.frame for n in out] == [0, 1, 26, 27] and out[2].missed == 24 and "went back" in out[2].jump
    # the same when the demuxer hands the last frame before the pause over with the first after it:
    # the gap counts from when that frame came by its timestamp (1.96 s), not from when it was read
    frames = [(500 + i, 0.04 * i) for i in range(49)] + [(549, 3.0), (35, 3.0), (36, 3.04)]
    out = feed(FrameNumbers(RATE), frames)
    assert [n.frame for n in out][48:] == [48, 49, 75, 76] and out[50].missed == 25 and "went back" in out[50].jump
    # a reconnect after 2 s to a sender whose clock is 100 s ahead: no 2500 frames missed
    out = feed(FrameNumbers(RATE), [(500, 0.0), (501, 0.04), (3000, 2.04), (3001, 2.08)], reopened_at=2)
    assert [n.frame for n in out] == [0, 1, 51, 52] and out[2].missed == 49 and "jumped" in out[2].jump
    # a reconnect after 2 s to a sender that went on: its timestamps count the gap
    out = feed(FrameNumbers(RATE), [(500, 0.0), (501, 0.04), (551, 2.04), (552, 2.08)], reopened_at=2)
    assert [n.frame for n in out] == [0, 1, 51, 52] and out[2].missed == 49 and out[2].exact and not out[2].jump
    # a reconnect that drains the sender's backlog (a burst of 20 after its first frame) is no discontinuity
    frames = [(500, 0.0), (501, 0.04)] + [(540 + i, 2.04 + 0.001 * i) for i in range(70)]
    out = feed(FrameNumbers(RATE), frames, reopened_at=2)
    assert [n.frame for n in out] == [0, 1] + list(range(40, 110)) and not any(n.jump for n in out)
    assert spans_add_up(out)
