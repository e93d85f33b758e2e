"""Morphable model validation, the generic head, box fitting and the model array format."""

from __future__ import annotations

import io

import numpy as np
import pytest

from gflow_core.gflow.geometry import project, rotation_matrices, shape_vertices
from gflow_core.gflow.head_model import (
    MODEL_FORMAT_VERSION,
    EllipsoidHead,
    MorphableModel,
    bounding_box,
    fit_head_model_to_box,
    fit_head_to_box,
    model_from_arrays,
    model_to_arrays,
    pose_for_box,
    validate_box,
)


@pytest.mark.parametrize("box", [(10.0, 20.0, 40.0, 50.0), (-0.5, -0.5, 320.0, 240.0), (100.25, 7.5, 33.0, 21.0)])
def test_fitted_head_projects_onto_the_box(box) -> None:
    model, pose0 = fit_head_model_to_box(np.array(box), (240, 320))
    assert model.n_bases == 1 and pose0.shape == (6,)
    np.testing.assert_allclose(rotation_matrices(pose0), np.eye(3), atol=0)
    np.testing.assert_allclose(bounding_box(project(model.bases, pose0)), box, atol=1e-9)


def test_generic_head_faces_the_camera_and_has_a_mesh() -> None:
    head, pose0 = fit_head_to_box(np.array([0.0, 0.0, 30.0, 40.0]), (50, 50), n_lon=9, n_lat=7, depth_ratio=0.8)
    model = head.model()
    assert model.n_vertices == 63
    q = head.directions()
    assert np.all(q[:, 2] < 0)  # the front part: -z faces the camera
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0)
    assert head.semi_axes[2] == pytest.approx(0.8 * head.semi_axes[0])
    assert model.triangles is not None and model.triangles.max() < model.n_vertices


def test_stretch_bases_give_an_ellipsoid_with_stretched_axes() -> None:
    stretch = np.array([[1.0, 0.5], [1.0, 0.0], [1.0, 0.0]])
    head = EllipsoidHead(np.array([0.4, 0.5, 0.3]), 5, 5, 50.0, 50.0, stretch)
    c = np.array([60.0, 10.0])
    s = shape_vertices(head.model().bases, c)
    np.testing.assert_allclose(s, head.effective_semi_axes(c) * head.directions(), atol=1e-12)


@pytest.mark.parametrize(
    ("box", "match"),
    [
        ((0, 0, 0, 10), "width and height"),
        ((0, 0, 10, -1), "width and height"),
        ((-5, 0, 10, 10), "not inside"),
        ((60, 0, 10, 10), "not inside"),
        ((0, 45, 10, 10), "not inside"),
        ((0, np.nan, 10, 10), "NaN"),
        ((0, 0, 10), r"\(x, y, w, h\)"),
    ],
)
def test_bad_boxes_raise(box, match) -> None:
    with pytest.raises(ValueError, match=match):
        validate_box(np.array(box, dtype=float), (50, 64))
    with pytest.raises(ValueError, match=match):
        fit_head_model_to_box(np.array(box, dtype=float), (50, 64))


@pytest.mark.parametrize(
    ("bases", "match"),
    [
        (np.zeros((5, 2, 1)), r"shape \(n, 3, k\)"),
        (np.zeros((5, 3)), r"shape \(n, 3, k\)"),
        (np.zeros((2, 3, 1)), "at least 3 vertices"),
        (np.zeros((5, 3, 0)), "at least one morph basis"),
        (np.full((5, 3, 1), np.nan), "NaN"),
        (np.array([["a"] * 3] * 3).reshape(3, 3, 1), "numeric"),
    ],
)
def test_model_validation(bases, match) -> None:
    with pytest.raises(ValueError, match=match):
        MorphableModel(bases)


def test_model_triangle_validation_and_readonly() -> None:
    with pytest.raises(ValueError, match="indices"):
        MorphableModel(np.zeros((4, 3, 1)), np.array([[0, 1, 4]]))
    with pytest.raises(ValueError, match="integers"):
        MorphableModel(np.zeros((4, 3, 1)), np.array([[0.0, 1.0, 2.0]]))
    m = MorphableModel(np.ones((4, 3, 2)))
    assert m.pose_size == 7 and not m.bases.flags.writeable
    with pytest.raises(ValueError, match="P = 5 \\+ k = 7"):
        m.check_poses(np.zeros(6))


def test_model_arrays_round_trip_through_npz() -> None:
    model, _ = fit_head_model_to_box(np.array([5.0, 5.0, 20.0, 30.0]), (40, 40))
    arrays = model_to_arrays(model)
    assert int(arrays["format_version"]) == MODEL_FORMAT_VERSION
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    buf.seek(0)
    with np.load(buf, allow_pickle=False) as z:
        back = model_from_arrays({k: z[k] for k in z.files})
    np.testing.assert_array_equal(back.bases, model.bases)
    np.testing.assert_array_equal(back.triangles, model.triangles)
    no_mesh = model_from_arrays({"format_version": np.array(1), "bases": np.ones((3, 3, 1))})
    assert no_mesh.triangles is None


@pytest.mark.parametrize(
    ("d", "match"),
    [
        ({"bases": np.ones((3, 3, 1))}, "missing"),
        ({"format_version": np.array(1), "bases": np.ones((3, 3, 1)), "colour": np.ones(3)}, "unknown key"),
        ({"format_version": np.array(3), "bases": np.ones((3, 3, 1))}, "unsupported model format_version 3"),
        ({"format_version": np.array(1), "bases": np.ones((3, 3, 1)), "landmarks": np.arange(3)}, "version 2 does"),
        ({"format_version": np.array(2), "bases": np.ones((3, 3, 1)), "landmarks": np.array([0, 1, 1])}, "distinct"),
        ({"format_version": np.array(2), "bases": np.ones((3, 3, 1)), "landmarks": np.arange(4)}, "one per vertex"),
        ({"format_version": np.array(2), "bases": np.ones((3, 3, 1)), "reference_box": np.array([0, 0, 1.0, -1])},
         "w, h > 0"),
        ({"format_version": np.array(2), "bases": np.ones((3, 3, 2)), "morph_std": np.array([0.0, np.nan])},
         "morph_std"),
        ({"format_version": np.array([1]), "bases": np.ones((3, 3, 1))}, "integer scalar"),
        ({"format_version": np.array(1), "bases": np.ones((3, 3, 1), dtype=int)}, "floating point"),
        ({"format_version": np.array(1), "bases": np.ones((3, 4, 1))}, r"shape \(n, 3, k\)"),
        ({"format_version": np.array(1), "bases": np.ones((3, 3, 1)), "triangles": np.ones((2, 2), int)}, r"\(T, 3\)"),
    ],
)
def test_model_arrays_validation(d, match) -> None:
    with pytest.raises(ValueError, match=match):
        model_from_arrays(d)


def test_pose_for_box_places_any_model_in_the_box() -> None:
    head, _ = fit_head_to_box(np.array([0.0, 0.0, 30.0, 40.0]), (50, 50))
    model = head.model()
    box = np.array([12.0, 20.0, 45.0, 60.0])  # same aspect ratio as the head: exact
    u = pose_for_box(model, box, (100, 100))
    np.testing.assert_allclose(bounding_box(project(model.bases, u)), box, atol=1e-9)
    morph = MorphableModel(np.concatenate([model.bases, 0.1 * model.bases[:, ::-1]], axis=2))
    u2 = pose_for_box(morph, box, (100, 100), coefficients=np.array([1.0, 0.5]))
    assert u2.shape == (7,) and u2[6] == pytest.approx(0.5 * u2[5])
    with pytest.raises(ValueError, match="2 finite numbers"):
        pose_for_box(morph, box, (100, 100), coefficients=np.array([1.0]))
    with pytest.raises(ValueError, match="not inside"):
        pose_for_box(model, box, (50, 50))
