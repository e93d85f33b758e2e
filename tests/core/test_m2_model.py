"""M2Model: array round trip, validation of stored content, conversion to tracker exemplars."""

from __future__ import annotations

import io

import numpy as np
import pytest

from gflow_core.m2 import tracking
from gflow_core.m2.curves import Curves
from gflow_core.m2.dynamics import random_walk
from gflow_core.m2.model import FORMAT_VERSION, M2Model


def curve_model(K: int = 3) -> M2Model:
    rng = np.random.default_rng(0)
    curves = Curves.from_list([rng.normal(0, 10, size=(20 + 5 * k, 2)) for k in range(K)])
    return M2Model(metric="chamfer", kernel="moments", exemplars=curves, d=np.linspace(3, 9, K),
                   sigma=np.linspace(0.5, 1.5, K), pi=np.full(K, 1 / K), markov=np.full((K, K), 1 / K),
                   dynamics=random_walk(2.0, 0.01, 0.01), ref_size=np.array([25.0, 66.0]),
                   exemplar_frame=np.arange(K) * 7, profile="truncated", g0=50.0)


def patch_model(K: int = 2) -> M2Model:
    rng = np.random.default_rng(1)
    return M2Model(metric="shuffle", kernel="mle", exemplars=rng.uniform(0, 255, (K, 6, 8)), d=np.full(K, 4.0),
                   sigma=np.full(K, 3.0), pi=np.full(K, 1 / K), markov=np.eye(K) * 0.5 + 0.5 / K,
                   dynamics=random_walk(0.5, 0.005, 0.005), ref_size=np.array([8.0, 6.0]), shuffle_radius=2)


def via_npz(arrays: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    buf.seek(0)
    with np.load(buf, allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


@pytest.mark.parametrize("make", [curve_model, patch_model])
def test_round_trip_through_arrays_and_npz(make) -> None:  # type: ignore[no-untyped-def]
    m = make()
    arrays = m.to_arrays()
    assert int(arrays["format_version"]) == FORMAT_VERSION
    assert all(a.dtype != object for a in arrays.values())
    back = M2Model.from_arrays(via_npz(arrays))
    for k, v in arrays.items():
        assert np.array_equal(back.to_arrays()[k], v), k
    assert back.metric == m.metric and back.kernel == m.kernel and back.K == m.K
    assert back.make_metric().params() == m.make_metric().params()


def test_to_contour_exemplars_drives_the_tracker() -> None:
    m = curve_model()
    ex = m.to_contour_exemplars()
    assert isinstance(ex, tracking.ContourExemplars) and ex.K == 3
    assert ex.n_points.tolist() == [20, 25, 30]
    frame = np.zeros((120, 120), dtype=np.uint8)
    pts = np.round(ex.curves[1, :25] + [60, 60]).astype(int)
    frame[np.clip(pts[:, 1], 0, 119), np.clip(pts[:, 0], 0, 119)] = 255
    from gflow_core.features import chamfer_image

    cloud = tracking.ParticleCloud(alpha=np.array([[60.0, 60.0, 0.0, 1.0]] * 3), k=np.array([0, 1, 2]),
                                   log_w=np.zeros(3))
    ll, rho = tracking.weigh(cloud, ex, chamfer_image(frame, "quadratic"))
    assert np.argmin(rho) == 1 and np.argmax(ll) == 1
    with pytest.raises(ValueError, match="patch exemplars"):
        patch_model().to_contour_exemplars()
    with pytest.raises(ValueError, match="contour exemplars"):
        m.to_patch_exemplars()
    pe = patch_model().to_patch_exemplars()
    assert pe.metric.name == "shuffle" and pe.metric.radius == 2  # type: ignore[attr-defined]


def test_alpha_from_box() -> None:
    m = curve_model()
    a = m.alpha_from_box((10.0, 20.0, 50.0, 132.0))
    assert a == pytest.approx([10 + 24.5, 20 + 65.5, 0.0, 2.0])


def test_from_arrays_rejects_wrong_version() -> None:
    arrays = curve_model().to_arrays()
    arrays["format_version"] = np.array(FORMAT_VERSION + 1)
    with pytest.raises(ValueError, match=f"version {FORMAT_VERSION + 1} is not supported"):
        M2Model.from_arrays(arrays)
    arrays["format_version"] = np.array("1")
    with pytest.raises(ValueError, match="scalar integer"):
        M2Model.from_arrays(arrays)
    del arrays["format_version"]
    with pytest.raises(ValueError, match="format_version"):
        M2Model.from_arrays(arrays)


@pytest.mark.parametrize("key", ["sigma", "markov", "exemplar_curves", "ar_B", "metric", "g0"])
def test_from_arrays_rejects_missing_key(key: str) -> None:
    arrays = curve_model().to_arrays()
    del arrays[key]
    with pytest.raises(ValueError, match=key):
        M2Model.from_arrays(arrays)


@pytest.mark.parametrize("key,value,msg", [
    ("sigma", np.ones(4), "sigma"),
    ("markov", np.full((3, 2), 0.5), "markov"),
    ("exemplar_curves", np.zeros((3, 30, 3)), "exemplar_curves"),
    ("exemplar_n_points", np.array([20, 25, 31]), "between 1 and P"),
    ("ar_A", np.eye(3), "ar_A"),
    ("ref_size", np.array([1.0]), "ref_size"),
    ("d", np.ones((3, 1)), "'d'"),
    ("sigma", np.array([1.0, np.nan, 1.0]), "NaN"),
    ("sigma", np.array([1.0, -1.0, 1.0]), "positive"),
    ("markov", np.full((3, 3), 0.5), "rows summing to 1"),
    ("pi", np.array([0.5, 0.5, 0.5]), "sum to 1"),
    ("metric", np.array("hausdorff"), "unknown metric"),
    ("kernel", np.array(3), "kernel"),
    ("d", np.array([1, 2, 3], dtype=object), "object"),
])
def test_from_arrays_rejects_corrupt_content(key: str, value: np.ndarray, msg: str) -> None:
    arrays = curve_model().to_arrays()
    arrays[key] = value
    with pytest.raises(ValueError, match=msg):
        M2Model.from_arrays(arrays)


def test_from_arrays_rejects_unexpected_keys() -> None:
    arrays = curve_model().to_arrays()
    arrays["exemplar_patches"] = np.zeros((3, 4, 4))
    with pytest.raises(ValueError, match="unexpected"):
        M2Model.from_arrays(arrays)
    arrays = patch_model().to_arrays()
    arrays["exemplar_curves"] = np.zeros((2, 4, 2))
    with pytest.raises(ValueError, match="unexpected"):
        M2Model.from_arrays(arrays)


def test_appearance_round_trip_and_version_1_files_still_read() -> None:
    from dataclasses import replace

    from gflow_core.m2.appearance_metric import AppearanceKernels

    rng = np.random.default_rng(3)
    app = AppearanceKernels(patches=rng.normal(size=(3, 8, 5, 4)).astype(np.float32), sigma=np.array([0.2, 0.3, 0.4]),
                            d=np.array([3.0, 4.0, 5.0]))
    m = replace(curve_model(), appearance=app)
    arrays = m.to_arrays()
    assert int(arrays["format_version"]) == FORMAT_VERSION == 3
    back = M2Model.from_arrays(arrays)
    assert np.array_equal(back.appearance.patches, app.patches) and np.array_equal(back.appearance.d, app.d)
    # a version-1 file (written before appearance exemplars existed) reads as a chamfer-only model
    v1 = curve_model().to_arrays()
    v1["format_version"] = np.array(1)
    del v1["train_scale"]
    old = M2Model.from_arrays(v1)
    assert old.appearance is None and old.K == 3
    # appearance arrays are all or nothing, and only in version 2
    bad = dict(arrays)
    del bad["app_d"]
    with pytest.raises(ValueError, match="app_d"):
        M2Model.from_arrays(bad)
    bad = dict(arrays)
    bad["format_version"] = np.array(1)
    with pytest.raises(ValueError, match="unexpected array"):
        M2Model.from_arrays(bad)
    with pytest.raises(ValueError, match="appearance patches"):
        replace(curve_model(), appearance=replace(app, patches=app.patches[:2]))


def test_train_scale_round_trips_and_older_files_use_their_dynamics_as_learned() -> None:
    from dataclasses import replace

    m = replace(curve_model(), train_scale=1.25)
    arrays = m.to_arrays()
    assert float(arrays["train_scale"]) == 1.25 and M2Model.from_arrays(via_npz(arrays)).train_scale == 1.25
    # a version-2 file has no train_scale: inf, so no target is larger than its training ones
    v2 = dict(arrays)
    v2["format_version"] = np.array(2)
    del v2["train_scale"]
    assert M2Model.from_arrays(v2).train_scale == float("inf")
    with pytest.raises(ValueError, match="train_scale"):
        M2Model.from_arrays(dict(arrays, format_version=np.array(3), train_scale=np.array(-1.0)))
    with pytest.raises(ValueError, match="unexpected"):
        M2Model.from_arrays(dict(v2, train_scale=np.array(1.0)))
    with pytest.raises(ValueError, match="missing"):
        M2Model.from_arrays({k: v for k, v in arrays.items() if k != "train_scale"})
