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
