"""The scale filter's peak refined between its scales (``scale_refine``): a size between two of the filter's
scales is found between them, the old pick is kept when it is off, and the tracker passes the option on."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from gflow_core.dcf import model as tm
from gflow_core.dcf import sizeprior
from gflow_core.dcf.params import DCFParams
from gflow_core.dcf.scale import detect_scale, init_scale

STEP, CELL, LAM = 1.02, 4, 0.01
CENTRE, SIZE = (150.0, 150.0), (40.0, 60.0)


def _texture(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    small = rng.uniform(0, 255, size=(30, 30)).astype(np.float32)
    return cv2.resize(small, (300, 300), interpolation=cv2.INTER_CUBIC)


def _grown(img: np.ndarray, f: float) -> np.ndarray:
    """``img`` magnified by ``f`` about CENTRE: a target f times its size."""
    m = cv2.getRotationMatrix2D(CENTRE, 0.0, f)
    return cv2.warpAffine(img, m, img.shape[::-1], flags=cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)


@pytest.mark.parametrize("f", [0.99, 1.005, 1.01, 1.015])
def test_a_size_between_two_scales_is_found_between_them_only_when_refined(f: float) -> None:
    """Scales 2 % apart: a target grown by 0.5-1.5 % is one of two whole steps away to the best scale alone,
    and within 0.3 % of its size to the peak refined by the parabola."""
    img = _texture(9)
    sf = init_scale(img, CENTRE, SIZE, 17, STEP, 2048, CELL)
    z = _grown(img, f)
    whole, _ = detect_scale(sf, z, CENTRE, SIZE, STEP, CELL, LAM)
    refined, _ = detect_scale(sf, z, CENTRE, SIZE, STEP, CELL, LAM, refine=True)
    assert whole / math.log(STEP) in (-1.0, 0.0, 1.0), whole  # whole steps only
    assert abs(refined - math.log(f)) < 0.15 * math.log(STEP), (refined, math.log(f))
    assert abs(refined - math.log(f)) < abs(whole - math.log(f)), (refined, whole, math.log(f))


def test_an_unchanged_size_stays_put_refined() -> None:
    img = _texture(4)
    sf = init_scale(img, CENTRE, SIZE, 17, STEP, 2048, CELL)
    refined, _ = detect_scale(sf, img, CENTRE, SIZE, STEP, CELL, LAM, refine=True)
    assert abs(refined) < 0.05 * math.log(STEP)


@pytest.mark.parametrize("prior", [False, True])
def test_the_tracker_refines_the_scale_as_its_parameter_says(prior: bool) -> None:
    """The tracker's scale pick (with and without the size prior) is whole steps with ``scale_refine`` off and
    between them with it on, on the same frames."""
    img = _texture(11)
    z = _grown(img, 1.01)
    picks = []
    for refine in (False, True):
        p = DCFParams(scale_refine=refine, scale_prior=0.5 if prior else 0.0, colour_names=False)
        geom = tm.geometry(SIZE, p)
        rgb = np.repeat(img.astype(np.uint8)[:, :, None], 3, axis=2)
        model = tm.init_model(rgb, img, True, CENTRE, geom, p)
        change = sizeprior.scale_change if prior else tm.scale_change
        picks.append(change(model, z, CENTRE, 0.0, geom, p))
    whole, refined = picks
    assert abs(whole / math.log(STEP) - round(whole / math.log(STEP))) < 1e-9, whole
    assert abs(refined - math.log(1.01)) < abs(whole - math.log(1.01)), picks
