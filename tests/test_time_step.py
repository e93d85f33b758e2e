"""The time step a stage hands its motion model: exactly 1 for files, the real time between
frames (in nominal periods) for a live source; and the models' noise grows with it."""

from __future__ import annotations

import numpy as np

from gflow_core.m2.dynamics import random_walk
from stages.base import StageContext
from stages.particle_proposal import ProposalParams, ProposalStage
from gflow_msgs.messages import Frame, Header, NDArray, Particles
from stages.time_step import MAX_TIME_STEP, time_step

FILE = StageContext("s", "cam0")
LIVE = StageContext("s", "cam0", frame_period_ns=40e6)  # 25 frames/s
T0 = 1_700_000_000_000_000_000  # a host clock stamp


def test_file_stamps_give_exactly_one() -> None:
    # media time at 30 frames/s is rounded to whole ns: 33333333 or 33333334 apart
    for t in range(1, 5):
        assert time_step(FILE, round(t * 1e9 / 30), round((t - 1) * 1e9 / 30)) == 1.0


def test_live_stamps_count_periods_within_bounds() -> None:
    assert time_step(LIVE, T0 + 120_000_000, T0) == 3.0  # two frames skipped
    assert time_step(LIVE, T0 + 1_000_000, T0) == 1.0  # a burst: never below one period
    assert time_step(LIVE, T0 + 60 * 10**9, T0) == MAX_TIME_STEP  # a long reconnect
    assert time_step(LIVE, T0, 0) == 1.0  # a message made without a frame (stamp 0)


def test_random_walk_noise_grows_as_sqrt_of_the_step() -> None:
    dyn = random_walk(2.0, 0.01, 0.02)
    alpha = np.tile([100.0, 50.0, 0.0, 1.0], (400, 1))
    one = dyn.predict(alpha, np.random.default_rng(7))
    same = dyn.predict(alpha, np.random.default_rng(7), 1.0)
    four = dyn.predict(alpha, np.random.default_rng(7), 4.0)
    assert np.array_equal(one, same)  # dt = 1: the bits of the one-step model
    np.testing.assert_allclose(four[:, :2] - alpha[:, :2], 2.0 * (one[:, :2] - alpha[:, :2]),
                               rtol=1e-9, atol=1e-9)


def test_timed_proposal_reads_the_next_frame_time() -> None:
    """Fed the posterior of frame t and frame t + 1 taken 3 periods later, the proposal's spread is
    sqrt(3) times the spread of a proposal for the next period."""
    stage = ProposalStage(ProposalParams(std_xy=2.0, std_theta=0.0, std_log_s=0.0, timed=True), LIVE)
    assert set(stage.inputs) == {"particles", "frames"} and stage.input_offsets["frames"] == -1
    n = 2000
    post = Particles(header=Header("cam0", 5, T0), kind="posterior",
                     alpha=NDArray.of(np.tile([100.0, 50.0, 0.0, 1.0], (n, 1))),
                     k=NDArray.of(np.zeros(n, np.int64)), log_w=NDArray.of(np.zeros(n)))
    img = NDArray.of(np.zeros((4, 4), np.uint8))

    def spread(later_ns: int) -> float:
        out = stage.step(5, {"particles": post, "frames": Frame(header=Header("cam0", 6, T0 + later_ns), image=img)})
        return float(out[0][1].alpha.array()[:, 0].std())

    ratio = spread(120_000_000) / spread(40_000_000)
    assert abs(ratio - np.sqrt(3.0)) < 1e-9, ratio
