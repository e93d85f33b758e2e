"""The correlation filter's mathematics (gflow_core.dcf) against closed-form answers: a filter trained on
one sample peaks at zero displacement and follows a shift of it, the masked filter keeps to its mask
and meets the closed form when the mask is everything, the sliding correlation equals the direct sum,
upsampling keeps the values on the cells, and the features, the scale filter and the colour model do
what their papers say."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from gflow_core.dcf import filter as cf
from gflow_core.dcf.constrained import box_mask, solve_masked
from gflow_core.dcf.features import colour_bins, cosine_window, hog, is_grey, sample
from gflow_core.dcf.histogram import colour_score, histograms
from gflow_core.dcf.model import geometry, init_model, respond
from gflow_core.dcf.params import DCFParams
from gflow_core.dcf.scale import detect_scale, init_scale


def _texture(seed: int, h: int, w: int, cell: float = 8.0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    small = rng.uniform(0, 255, size=(max(2, int(h / cell)), max(2, int(w / cell)))).astype(np.float32)
    return cv2.resize(small, (w, h), interpolation=cv2.INTER_CUBIC)


def _response(det: np.ndarray, z: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    return np.fft.irfft2(cf.respond(det, np.fft.rfft2(z, axes=(0, 1))), s=shape)


def test_a_filter_trained_on_one_sample_peaks_at_zero_and_follows_a_cyclic_shift() -> None:
    """H = conj(G) F / (|F|^2 + lambda) (DSST eq. 3): on its own sample the response is the label g
    (peak 1 at displacement 0) up to lambda; on the sample shifted cyclically by d the response is g
    shifted by d, exactly."""
    rng = np.random.default_rng(0)
    h, w, c = 21, 25, 6
    x = rng.normal(size=(h, w, c))
    g = cf.gaussian_label(h, w, 1.5)
    det = cf.detector(cf.train(np.fft.rfft2(x, axes=(0, 1)), np.fft.rfft2(g)), 1e-6)
    y0 = _response(det, x, (h, w))
    np.testing.assert_allclose(y0, g, atol=1e-4)
    assert cf.peak(y0)[:2] == (0, 0)
    for d in ((3, -4), (-7, 5), (10, 12)):
        y = _response(det, np.roll(x, d, axis=(0, 1)), (h, w))
        np.testing.assert_allclose(y, np.roll(g, d, axis=(0, 1)), atol=1e-4)
        assert cf.peak(y)[:2] == (d[0] % h, d[1] % w)


def test_the_running_average_is_the_convex_blend_of_numerators_and_denominators() -> None:
    rng = np.random.default_rng(1)
    a = cf.train(np.fft.rfft2(rng.normal(size=(9, 11, 3)), axes=(0, 1)), np.fft.rfft2(cf.gaussian_label(9, 11, 1.0)))
    b = cf.train(np.fft.rfft2(rng.normal(size=(9, 11, 3)), axes=(0, 1)), np.fft.rfft2(cf.gaussian_label(9, 11, 1.0)))
    m = cf.blend(a, b, 0.25)
    np.testing.assert_allclose(m.num, 0.75 * a.num + 0.25 * b.num)
    np.testing.assert_allclose(m.den, 0.75 * a.den + 0.25 * b.den)


def test_upsampling_a_response_keeps_its_values_on_the_cells() -> None:
    """Zero-padding the spectrum of an odd-sized map is band-limited interpolation: every factor-th
    sample is the map itself."""
    rng = np.random.default_rng(2)
    y = rng.normal(size=(13, 17))
    up = cf.upsample(np.fft.rfft2(y), y.shape, 4)
    assert up.shape == (52, 68)
    np.testing.assert_allclose(up[::4, ::4], y, atol=1e-12)


def test_the_sliding_correlation_equals_the_direct_sum() -> None:
    rng = np.random.default_rng(3)
    h = rng.normal(size=(5, 7, 3))
    x = rng.normal(size=(20, 30, 3))
    y = cf.correlate_valid(h, x)
    ref = np.array([[(h * x[i:i + 5, j:j + 7]).sum() for j in range(24)] for i in range(16)])
    assert y.shape == (16, 24)
    np.testing.assert_allclose(y, ref, atol=1e-10)
    with pytest.raises(ValueError, match="smaller than the filter"):
        cf.correlate_valid(h, x[:4])


def test_the_sliding_correlation_gives_scipy_ffts_bits_and_its_fast_lengths() -> None:
    """The transforms are numpy's, inverted in scipy.fft's order, so that the search's scores are the bits
    scipy.fft gave (the recorded runs and the docs' figures were made with them) without importing scipy."""
    sfft = pytest.importorskip("scipy.fft")
    assert [cf.fast_length(n) for n in range(1, 3000)] == [sfft.next_fast_len(n, real=True) for n in range(1, 3000)]
    rng = np.random.default_rng(4)
    for _ in range(60):
        hh, ww = (int(v) for v in rng.integers(8, 120, size=2))
        c = int(rng.choice([1, 13, 42]))
        h = rng.normal(size=(int(rng.integers(2, min(hh, 30) + 1)), int(rng.integers(2, min(ww, 30) + 1)), c))
        x = rng.normal(size=(hh, ww, c)).astype(np.float32)
        sh, sw = sfft.next_fast_len(hh, real=True), sfft.next_fast_len(ww, real=True)
        prod = (sfft.rfft2(x.astype(np.float64), s=(sh, sw), axes=(0, 1))
                * np.conj(sfft.rfft2(h, s=(sh, sw), axes=(0, 1)))).sum(axis=-1)
        ref = sfft.irfft2(prod, s=(sh, sw))[: hh - h.shape[0] + 1, : ww - h.shape[1] + 1]
        np.testing.assert_allclose(cf.correlate_valid(h, x), ref, rtol=0, atol=1e-9)
        # the inverse alone, on the same spectrum: the same bits
        rows = np.fft.ifft(prod, axis=0, norm="forward")
        inv = np.fft.irfft(rows, n=sw, axis=1, norm="forward") * (1.0 / (sh * sw))
        assert np.array_equal(inv, sfft.irfft2(prod, s=(sh, sw)))


def test_the_spatial_filter_scores_a_window_as_the_fourier_response_does() -> None:
    """sum_x h(x) z(x + d) by the spatial filter (:func:`filter.spatial`) equals the Fourier response at d."""
    rng = np.random.default_rng(4)
    x = rng.normal(size=(11, 13, 4))
    det = cf.detector(cf.train(np.fft.rfft2(x, axes=(0, 1)), np.fft.rfft2(cf.gaussian_label(11, 13, 1.0))), 1e-3)
    z = rng.normal(size=(11, 13, 4))
    y = _response(det, z, (11, 13))
    h = cf.spatial(det, (11, 13))
    for d in ((0, 0), (2, 5), (10, 1)):
        direct = sum((h * np.roll(z, (-d[0], -d[1]), axis=(0, 1)))[..., c].sum() for c in range(4))
        assert direct == pytest.approx(y[d], abs=1e-9)


def test_the_masked_filter_keeps_to_its_mask_and_meets_the_closed_form_without_one() -> None:
    """BACF's ADMM: the spatial filter is zero outside the mask and still peaks at the sample's
    shift; with a mask of every cell and enough iterations it is the closed-form filter."""
    rng = np.random.default_rng(5)
    h, w = 21, 21
    x = cv2.GaussianBlur(rng.normal(size=(h, w, 4)).astype(np.float32), (0, 0), 1.0).astype(np.float64)
    win = cosine_window(h, w)
    xh = cf.spectrum(x, win)
    gh = np.fft.rfft2(cf.gaussian_label(h, w, 1.2))
    mask = box_mask((w, h), (7.0, 9.0), 1.0)
    det = solve_masked(xh, gh, mask, 1e-3, 0.03, 4)
    hs = cf.spatial(det, (h, w))
    assert np.abs(hs[mask == 0]).max() < 1e-12 * np.abs(hs).max() + 1e-15
    assert np.abs(hs[mask == 1]).max() > 0
    y = np.fft.fftshift(_response(det, x * win[..., None], (h, w)))
    assert cf.peak(y)[:2] == (h // 2, w // 2)
    full = solve_masked(xh, gh, np.ones((h, w)), 1e-3, 1e-4, 60, beta=1.5)
    closed = cf.detector(cf.train(xh, gh), 1e-3)
    z = np.fft.rfft2(x * win[..., None], axes=(0, 1))
    np.testing.assert_allclose(np.fft.irfft2(cf.respond(full, z), s=(h, w)),
                               np.fft.irfft2(cf.respond(closed, z), s=(h, w)), atol=2e-3)


def test_a_model_trained_on_a_frame_finds_the_target_moved_by_a_real_shift() -> None:
    """The whole path on a textured frame: the target's model of frame 0, the response over a window
    centred 7 px right and 5 px below the target: its peak is the target's true centre, within a pixel."""
    img = np.clip(_texture(6, 240, 320), 0, 255).astype(np.uint8)
    p = DCFParams()
    geom = geometry((40.0, 50.0), p)
    model = init_model(img, img.astype(np.float32), True, (160.0, 120.0), geom, p)
    for off in ((7.0, 5.0), (-9.0, 3.0)):
        r = respond(model, img, img.astype(np.float32), (160.0 + off[0], 120.0 + off[1]), 0.0, geom, p)
        xy, v = r.peak()
        assert abs(xy[0] - 160.0) <= 1.0 and abs(xy[1] - 120.0) <= 1.0, (off, xy)
        assert v > 0.3


def test_hog_has_31_channels_ignores_a_gain_and_sees_an_edges_orientation() -> None:
    img = _texture(7, 64, 96)
    f = hog(img, 4)
    assert f.shape == (16, 24, 31) and f.dtype == np.float32
    # block normalisation: a gain on the image changes the cells but little (eps = 1e-4 on the energy)
    np.testing.assert_allclose(hog(0.5 * img, 4), f, atol=2e-2)
    # a vertical edge, dark to bright left to right: its gradient points along +x, sensitive bin 0
    edge = np.zeros((32, 32), np.float32)
    edge[:, 16:] = 200.0
    e = hog(edge, 4)[4, 4 - 1:4 + 1].sum(axis=0)
    assert np.argmax(e[:18]) in (0, 17) and np.argmax(e[18:27]) in (0, 8)
    with pytest.raises(ValueError, match="multiples of 4"):
        hog(np.zeros((30, 32), np.float32), 4)


def test_the_sample_is_centred_on_the_point_asked_for() -> None:
    img = np.zeros((60, 80), np.float32)
    img[30, 40] = 1.0
    out = sample(img, (40.0, 30.0), (9, 7), 1.0)
    assert np.unravel_index(np.argmax(out), out.shape) == (3, 4)
    # at 2 output pixels an image pixel, the point lies half-way between output pixels (6, 8) and (7, 9)
    out2 = sample(img, (40.0, 30.0), (18, 14), 2.0)
    rows, cols = np.indices(out2.shape)
    assert (rows * out2).sum() / out2.sum() == pytest.approx(6.5)
    assert (cols * out2).sum() / out2.sum() == pytest.approx(8.5)


def test_grey_frames_are_told_from_colour_ones() -> None:
    grey = _texture(8, 40, 60).astype(np.uint8)
    three = np.dstack([grey, grey, np.clip(grey.astype(int) + 1, 0, 255).astype(np.uint8)])
    assert is_grey(grey) and is_grey(three)
    colour = three.copy()
    colour[..., 2] = 255 - colour[..., 2]
    assert not is_grey(colour)
    assert colour_bins(grey, grey=True).max() < 32
    assert colour_bins(colour, grey=False).max() < 32 ** 3


def test_the_scale_filter_finds_a_zoom_of_the_target() -> None:
    """DSST: trained at the box's scale, the response over 17 scales 2 % apart peaks at the zoom."""
    img = _texture(9, 300, 300, cell=10.0)
    sf = init_scale(img, (150.0, 150.0), (40.0, 60.0), 17, 1.02, 2048, 4)
    for zoom in (0.94, 1.0, 1.06):
        z = cv2.warpAffine(img, cv2.getRotationMatrix2D((150.0, 150.0), 0.0, zoom), (300, 300))
        d, y = detect_scale(sf, z, (150.0, 150.0), (40.0, 60.0), 1.02, 4, 0.01)
        assert abs(d - np.log(zoom)) <= 0.5 * np.log(1.02) + 1e-9, (zoom, np.exp(d))
        assert y.shape == (17,)


def test_the_colour_model_scores_the_targets_colours() -> None:
    """Staple's beta = rho_O / (rho_O + rho_B): a red box on a grey background scores 1 on the box's
    cells and 0 away from it."""
    img = np.full((80, 80, 3), 120, np.uint8)
    img[30:50, 30:50] = (0, 0, 250)
    bins = colour_bins(img, grey=False)
    model = histograms(bins, np.ones(bins.shape, bool), (20.0, 20.0), 32 ** 3)
    assert model.fg.sum() == pytest.approx(1.0) and model.bg.sum() == pytest.approx(1.0)
    sc = colour_score(model, bins, 4, (3.0, 3.0))
    assert sc[10, 10] == pytest.approx(1.0) and sc[1, 1] == pytest.approx(0.0)
