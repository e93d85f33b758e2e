"""fit_to_box: a learned contour model stretched to the user's box shape, area kept."""

from __future__ import annotations

import numpy as np
import pytest

from gflow_core.m2.target_shape import aspect_factors, fit_to_box
from test_m2_model import curve_model, patch_model


def test_aspect_factors_keep_area_and_match_the_box() -> None:
    a = aspect_factors(np.array([28.0, 73.0]), (10.0, 20.0, 46.0, 60.0))
    assert a[0] * a[1] == pytest.approx(1.0)
    w, h = np.array([28.0, 73.0]) * a
    assert w / h == pytest.approx(46.0 / 60.0)
    # a box of the reference's own shape changes nothing
    assert aspect_factors(np.array([28.0, 73.0]), (0, 0, 14.0, 36.5)) == pytest.approx([1.0, 1.0])
    with pytest.raises(ValueError, match="positive"):
        aspect_factors(np.array([28.0, 73.0]), (0, 0, 0.0, 10.0))


def test_fit_to_box_stretches_exemplars_and_reference_box() -> None:
    m = curve_model()
    box = (5.0, 5.0, 40.0, 40.0)
    f = fit_to_box(m, box)
    a = aspect_factors(m.ref_size, box)
    assert f.ref_size[0] == pytest.approx(f.ref_size[1])
    assert np.prod(f.ref_size) == pytest.approx(np.prod(m.ref_size))
    np.testing.assert_allclose(f.exemplars.points, m.exemplars.points * a)
    # the scale of a box is unchanged (so are the dynamics on log s and the kernels)
    assert f.alpha_from_box(box)[3] == pytest.approx(m.alpha_from_box(box)[3])
    assert f.sigma is m.sigma or np.array_equal(f.sigma, m.sigma)
    # patch models have no item frame
    p = patch_model()
    assert fit_to_box(p, box) is p
