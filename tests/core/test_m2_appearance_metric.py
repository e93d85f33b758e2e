"""The appearance metric beside chamfer, the online exemplar bank and kernel calibration."""

from __future__ import annotations

import numpy as np
import pytest

from gflow_core.m2.appearance_metric import (AppearanceKernels, appearance_log_lik, bank_update,
                                             correlation_distances, frame_features, new_bank, patch_resolution,
                                             sample_patches, sample_patches_near)
from gflow_core.m2.kernel import calibrate_sigma, log_kernel


def _scene(seed: int = 0, h: int = 90, w: int = 120) -> np.ndarray:
    rng = np.random.default_rng(seed)
    img = np.full((h, w), 90.0)
    img[30:70, 50:66] = 30.0  # a dark figure
    img[30:40, 54:62] = 170.0  # with a light head
    return np.clip(img + rng.normal(0, 3, img.shape), 0, 255).astype(np.uint8)


def test_correlation_distance_ignores_gain_and_bias_and_sees_a_shift() -> None:
    g = _scene()
    ref = np.array([16.0, 40.0])
    res = patch_resolution(ref, 120)
    alpha = np.array([57.5, 49.5, 0.0, 1.0])
    a = sample_patches(frame_features(g), alpha, ref, res)
    brighter = np.clip(g.astype(np.float64) * 1.3 + 20, 0, 255).astype(np.uint8)
    b = sample_patches(frame_features(brighter), alpha, ref, res)
    shifted = sample_patches(frame_features(g), alpha + [25, 0, 0, 0], ref, res)
    same, light, off = (correlation_distances(a, x)[0, 0] for x in (a, b, shifted))
    assert same == pytest.approx(0.0, abs=1e-5)
    assert light < 0.05 < 0.3 < off  # a change of light is not a change of place
    assert 0.0 <= off <= 2.0


def test_patches_near_equal_whole_frame_patches() -> None:
    g = _scene(1)
    ref = np.array([16.0, 40.0])
    res = patch_resolution(ref, 120)
    alpha = np.array([[57.5, 49.5, 0.0, 1.0], [60.0, 45.0, 0.1, 1.2], [40.0, 50.0, 0.0, 0.8]])
    near = sample_patches_near(g, alpha, ref, res)
    full = sample_patches(frame_features(g), alpha, ref, res)
    assert near.shape == full.shape == (3, res[1], res[0], 4)
    assert np.abs(near - full).max() < 1e-2 * np.abs(full).max()


def test_bank_is_bounded_keeps_slot_0_and_replaces_the_least_used() -> None:
    p = lambda v: np.full((5, 4, 4), float(v), dtype=np.float32)  # noqa: E731
    bank = new_bank(p(0), frame=0)
    bank = bank_update(bank, p(1), 0, confident=True, frame=2, bound=3, every=5)
    assert bank.n == 1  # too soon after frame 0
    bank = bank_update(bank, p(1), 0, confident=False, frame=5, bound=3, every=5)
    assert bank.n == 1  # not confident
    bank = bank_update(bank, p(1), 0, confident=True, frame=6, bound=3, every=5)
    bank = bank_update(bank, p(2), 1, confident=True, frame=11, bound=3, every=5)
    assert bank.n == 3 and list(bank.frame) == [0, 6, 11]
    # slot 2 used for a while, slot 1 not: slot 1 is replaced; slot 0 is never replaced
    for t in range(12, 20):
        bank = bank_update(bank, p(9), 2, confident=False, frame=t, bound=3, every=5)
    bank = bank_update(bank, p(3), 2, confident=True, frame=20, bound=3, every=5)
    assert bank.n == 3 and list(bank.frame) == [0, 20, 11] and bank.patches[1, 0, 0, 0] == 3
    assert bank.patches[0, 0, 0, 0] == 0


def test_online_bank_lifts_the_appearance_term_of_a_new_target() -> None:
    rng = np.random.default_rng(2)
    learned = rng.normal(size=(2, 6, 4, 4)).astype(np.float32)
    target = rng.normal(size=(6, 4, 4)).astype(np.float32)
    kern = AppearanceKernels(patches=learned, sigma=np.array([0.2, 0.2]), d=np.array([4.0, 4.0]))
    z = np.stack([target, learned[0]])
    k = np.array([1, 1])
    ll0, r0, near0 = appearance_log_lik(z, k, kern, None)
    ll1, r1, near1 = appearance_log_lik(z, k, kern, new_bank(target, 0))
    assert (near0 == -1).all() and (near1 == 0).all()
    assert ll1[0] > ll0[0] + 5 and r1[0] == pytest.approx(1.0, abs=1e-5)
    assert ll1[1] >= ll0[1]  # the larger of the two kernels, never less


def test_calibrate_sigma_widens_only_when_the_start_box_is_atypical() -> None:
    sigma, d = np.array([0.5, 1.0]), np.array([4.0, 2.0])
    assert np.array_equal(calibrate_sigma(sigma, d, 0.1), sigma)
    wide = calibrate_sigma(sigma, d, 100.0)
    assert wide == pytest.approx(np.sqrt(100.0 / d))
    assert np.array_equal(calibrate_sigma(sigma, d, float("nan")), sigma)
    # the known match at rho0 is now typical: rho0 = d sigma^2
    assert (d * wide**2) == pytest.approx([100.0, 100.0])
    assert log_kernel(100.0, wide, d).shape == (2,)
