"""The motion model's gain learnt from the track (``motion_fit``; gflow_core.dcf.motion_fit): the regression's
posterior mean is the prior's 1 with no data, follows the displacements' agreement with the velocity and stays
within [0, 1]; on a target that keeps its heading the gain stays near 1, on one that jolts back and forth it
falls to 0 and the box is nearer the target than with the constant-velocity prediction; off, nothing is
learnt; the sums go into a snapshot and come back bit for bit."""

from __future__ import annotations

import numpy as np

from gflow_core.dcf import motion_fit
from gflow_core.dcf.params import DCFParams
from gflow_core.evaluation.metrics import centre_error
from tests.core.test_dcf_tracker import Scene, _resumed, _track


def test_the_gain_is_the_priors_without_data_and_follows_the_displacements() -> None:
    assert motion_fit.gain((0.0, 0.0)) == 1.0
    u = np.array([6.0, 2.0])
    ahead, back, across = (0.0, 0.0), (0.0, 0.0), (0.0, 0.0)
    for _ in range(30):
        ahead = motion_fit.update(ahead, u.copy(), u, 25.0, 0.1)  # it carries on: d = u
        back = motion_fit.update(back, -u, u, 25.0, 0.1)  # it turns back: d = -u
        across = motion_fit.update(across, np.array([-2.0, 6.0]), u, 25.0, 0.1)  # at right angles: d . u = 0
    assert motion_fit.gain(ahead) == 1.0 and motion_fit.gain(back) == 0.0
    # (0 + 1) / (B + 1): the prior's pull towards 1 over the evidence of ~10 frames of |u|^2 / sigma^2 = 1.6
    b_sum = across[1]
    assert abs(motion_fit.gain(across) - 1.0 / (b_sum + 1.0)) < 1e-12 and motion_fit.gain(across) < 0.1


def _jolting(seed: int) -> Scene:
    """A target jolting right and back every frame by 6 px growing to 24 px, drifting 1 px down a frame."""
    return Scene(lambda t: (120.0 + min(6.0 + 1.5 * t, 24.0) * (t % 2), 100.0 + 1.0 * t), seed=seed)


def test_a_jolting_target_teaches_a_gain_of_0_and_is_followed_closer() -> None:
    sc = _jolting(3)
    frames = [sc.frame(t) for t in range(40)]
    truth = np.array([sc.truth(t) for t in range(40)])
    st_cv, cv = _track(frames, sc.truth(0))
    st_mf, mf = _track(frames, sc.truth(0), DCFParams(motion_fit=0.1))
    assert st_cv.motion_fit == (0.0, 0.0)  # off (the default): nothing learnt
    assert motion_fit.gain(st_mf.motion_fit) == 0.0
    err_cv = centre_error(truth, np.array([e.box for e in cv]))
    err_mf = centre_error(truth, np.array([e.box for e in mf]))
    # the constant-velocity prediction lands a jolt beyond the target on every reversal
    assert err_mf.mean() < 0.8 * err_cv.mean(), (err_mf.mean(), err_cv.mean())


def test_a_target_that_keeps_its_heading_keeps_a_gain_near_1() -> None:
    sc = Scene(lambda t: (80.0 + 4.0 * t, 100.0 + 1.0 * t), seed=3)
    st, _ = _track([sc.frame(t) for t in range(30)], sc.truth(0), DCFParams(motion_fit=0.1))
    assert motion_fit.gain(st.motion_fit) > 0.95


def test_the_sums_go_into_the_snapshot_and_back() -> None:
    p = DCFParams(motion_fit=0.1)
    sc = _jolting(4)
    frames = [sc.frame(t) for t in range(24)]
    st, _ = _track(frames[:16], sc.truth(0), p)
    assert st.motion_fit != (0.0, 0.0)
    back = _resumed(st, frames, 16, p)
    assert back.motion_fit == st.motion_fit
