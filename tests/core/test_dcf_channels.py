"""dcf's channel reliability (``channel_weights``; gflow_core.dcf.channels, CSR-DCF sec. 3.2-3.3): a channel that
holds the target outweighs a channel of noise and a channel with a look-alike; equal weights leave the filter as
it is; off (the default) the track is today's bit for bit, on it differs; the running weights go into a
snapshot and come back bit for bit; bad values are refused in one line."""

from __future__ import annotations

import numpy as np
import pytest

from gflow_core.dcf import channels as ch
from gflow_core.dcf import filter as cf
from gflow_core.dcf import model as tm
from gflow_core.dcf.features import cosine_window
from gflow_core.dcf.params import DCFParams
from gflow_core.params import added_later, make
from tests.core.test_dcf_tracker import Scene, _track

#: cells a side of the synthetic window
N = 31


def _blob(cx: float, cy: float, sigma: float = 2.0) -> np.ndarray:
    """(N, N) a Gaussian blob at cell (cx, cy)."""
    y, x = np.mgrid[0:N, 0:N].astype(np.float64)
    return np.exp(-((x - cx) ** 2 + (y - cy) ** 2) / (2.0 * sigma * sigma))


def _sample(shift: float, seed: int) -> np.ndarray:
    """(N, N, 3) cells: 0 the target (a blob at the centre moved ``shift`` cells right), 1 noise, 2 the target
    and a look-alike 8 cells left of it."""
    c = (N - 1) / 2.0
    noise = np.random.default_rng(seed).normal(0.0, 0.5, (N, N))
    return np.stack([_blob(c + shift, c), noise, _blob(c + shift, c) + _blob(c + shift - 8.0, c)], axis=-1)


def test_a_channel_that_holds_the_target_outweighs_noise_and_a_look_alike() -> None:
    """The filter learnt on a sample (closed form, DSST eq. 3): the target's channel has the largest learning
    reliability and the look-alike's (the same target in training) well above noise's; on the next frame (the target moved, the noise drawn again) the target's
    channel's response has only its sidelobes beside its peak, noise's and the look-alike's have rivals of half
    the peak or more (a detection reliability at or near the floor of 1/2); the
    frame's weights sum to 1, the target's channel's the largest."""
    win = cosine_window(N, N)
    g_hat = np.fft.rfft2(cf.gaussian_label(N, N, 2.0))
    x_hat = cf.spectrum(_sample(0.0, 1), win)
    det = cf.detector(cf.train(x_hat, g_hat), 1e-4)
    lrn = ch.learning(ch.responses(det, x_hat, (N, N)))
    assert lrn[0] > 2.0 * lrn[1] and lrn[2] > 2.0 * lrn[1] and lrn[1] >= 0.0
    dtc = ch.detection(ch.responses(det, cf.spectrum(_sample(2.0, 2), win), (N, N)))
    assert dtc[0] > 0.7 and 0.5 <= dtc[1] < 0.6 and 0.5 <= dtc[2] < 0.6
    w = ch.combine(lrn, dtc)
    assert w.sum() == pytest.approx(1.0) and np.argmax(w) == 0 and w[0] > 2.0 * w[1]
    # averaged in at a rate, normalised again
    run = ch.blend(np.full(3, 1.0 / 3.0), w, 0.1)
    assert run.sum() == pytest.approx(1.0) and np.allclose(run, 0.9 / 3.0 + 0.1 * w)


def test_equal_weights_leave_the_filter_as_it_is_and_a_flat_response_is_reliable() -> None:
    det = np.random.default_rng(0).normal(size=(5, 3, 4)) + 1j * np.random.default_rng(1).normal(size=(5, 3, 4))
    for intensity in (True, False):
        assert np.array_equal(ch.scaled(det, np.full(4, 0.25), intensity), det)
    assert np.allclose(ch.scaled(det, np.array([0.5, 0.5, 0.0, 0.0]), True)[..., 0], 2.0 * det[..., 0])
    # without the intensity channel (the last) weighted: it keeps 1, the others share a mean of 1
    w = np.array([0.1, 0.2, 0.1, 0.6])
    assert np.allclose(ch.scaled(det, w, True), det * np.array([0.4, 0.8, 0.4, 2.4]))
    assert np.allclose(ch.scaled(det, w, False), det * np.array([0.75, 1.5, 0.75, 1.0]))
    assert np.array_equal(ch.detection(np.zeros((7, 7, 2))), np.ones(2))
    assert np.allclose(ch.combine(np.zeros(4), np.ones(4)), 0.25)


def _frames(n: int) -> tuple[list[np.ndarray], tuple[float, float, float, float]]:
    """``n`` grey frames of a textured target moving 3 px right and 1 down a frame, and its first box."""
    sc = Scene(lambda t: (130.0 + 3.0 * t, 100.0 + 1.0 * t), seed=4)
    return [sc.frame(t) for t in range(n)], sc.truth(0)


def test_off_it_tracks_as_before_and_on_it_tracks_otherwise() -> None:
    """channel_weights false (the default, so not a parameter added later) gives today's track bit for bit, and
    no weights in the model; on, a track of the same frames differs, and the model holds weights summing to 1,
    the anchor the first filter times the first frame's weights."""
    frames, box = _frames(8)
    _, ref = _track(frames, box)
    st_off, off = _track(frames, box, DCFParams(channel_weights=False))
    st_on, on = _track(frames, box, DCFParams(channel_weights=True))
    assert DCFParams().channel_weights is False and "channel_weights" not in added_later(DCFParams)
    assert [e.box for e in off] == [e.box for e in ref] and st_off.model.channels is None
    assert [e.box for e in on] != [e.box for e in ref]
    w = st_on.model.channels
    assert w is not None and w.shape == (32,) and w.sum() == pytest.approx(1.0) and np.all(w >= 0)
    # the anchor keeps the first frame's weights: its channels are the first filter's times C w0
    first, _ = _track(frames[:1], box, DCFParams(channel_weights=True))
    assert np.array_equal(st_on.model.anchor, first.model.anchor)
    assert first.model.channels is not None and not np.allclose(first.model.channels, w)
    assert np.allclose(first.model.anchor, ch.scaled(first.model.det, first.model.channels, False))


def test_the_weights_go_into_a_snapshot_and_come_back_bit_for_bit() -> None:
    from gflow_core.dcf.state import from_arrays, to_arrays
    from gflow_core.dcf.tracker import TRACKER
    from gflow_core.tracker import FrameRng, step

    q = DCFParams(channel_weights=True)
    frames, box = _frames(10)
    st, _ = _track(frames[:5], box, q)
    arrays, values = to_arrays(st)
    assert "channels" in arrays
    back = from_arrays({k: v.copy() for k, v in arrays.items()}, dict(values), q)
    assert back.model.channels is not None and np.array_equal(back.model.channels, st.model.channels)
    for t in range(5, 10):
        obs = TRACKER.observe(q, frames[t])
        st, e1 = step(TRACKER, q, st, obs, FrameRng(1, 7, t))
        back, e2 = step(TRACKER, q, back, obs, FrameRng(1, 7, t))
        assert e1 == e2
    bad = dict(arrays, channels=arrays["channels"][:5])
    with pytest.raises(ValueError, match="channel weights of shape"):
        from_arrays(bad, dict(values), q)


@pytest.mark.parametrize("name", ["channel_weights", "channel_intensity"])
@pytest.mark.parametrize("value", [2, "yes", None, 1.0])
def test_bad_values_are_refused_in_one_line(name, value) -> None:
    with pytest.raises(ValueError) as e:
        make(DCFParams, {name: value})
    assert f"{name} must be true or false, got {value!r}" in str(e.value) and "\n" not in str(e.value)


def test_the_long_term_filter_is_not_weighted() -> None:
    from gflow_core.dcf.longterm import LongTerm, view
    from gflow_core.visibility import ChiSquare

    frames, box = _frames(3)
    st, _ = _track(frames, box, DCFParams(channel_weights=True))
    lt = LongTerm(st.model.train, st.model.det, ChiSquare(), ChiSquare())
    assert view(st.model, lt).channels is None
    assert np.allclose(tm.detection_filter(view(st.model, lt), 0.2, False), st.model.det, rtol=1e-12, atol=0.0)


def test_detection_weights_the_running_filter_by_the_running_weights() -> None:
    """The filter detection uses is the running filter's channels times C w_d (one weight of 1: that channel
    alone, C times), plus the anchor, which holds its own weights, at anchor_weight; without the intensity
    weighted, the fHOG channels share C - 1 and the intensity keeps its own."""
    from dataclasses import replace

    frames, box = _frames(3)
    st, _ = _track(frames, box, DCFParams(channel_weights=True))
    one = np.zeros(32)
    one[5] = 1.0
    m = replace(st.model, channels=one)
    d = tm.detection_filter(m, 0.0, True)
    assert np.array_equal(d[..., 5], 32.0 * st.model.det[..., 5]) and not d[..., :5].any() and not d[..., 6:].any()
    assert np.allclose(tm.detection_filter(m, 0.2, True), 0.8 * d + 0.2 * st.model.anchor, rtol=1e-12, atol=0.0)
    # without channel_intensity the intensity channel (the last) keeps its weight of 1
    d = tm.detection_filter(m, 0.0, False)
    assert np.array_equal(d[..., 5], 31.0 * st.model.det[..., 5]) and np.array_equal(d[..., 31], st.model.det[..., 31])
    assert not d[..., :5].any() and not d[..., 6:31].any()


def test_the_local_maxima_are_scipys_cyclic_3x3_maximum() -> None:
    ndimage = pytest.importorskip("scipy.ndimage")
    rng = np.random.default_rng(5)
    for _ in range(50):
        n = rng.normal(size=(int(rng.integers(1, 30)), int(rng.integers(1, 30)), int(rng.integers(1, 6))))
        n[rng.random(n.shape) < 0.2] = 0.5  # ties
        assert np.array_equal(ch._cyclic_max3(n), ndimage.maximum_filter(n, size=(3, 3, 1), mode="wrap"))
