"""The chamfer tracker's template update with drift correction (gflow_core/contour/template.py):
the alignment of the first template, the template taken at a transform, and the filter stage's
snapshot carrying the updated template, the first one and the anchor bit for bit."""

from __future__ import annotations

import msgspec
import numpy as np
import pytest

from gflow_core import features
from gflow_core.contour.template import align_first, template_at
from stages.base import StageContext
from gflow_msgs.messages import NDArray
from gflow_core.contour import state as wire
from stages.particle_filter import ChamferFilterParams, ChamferFilterStage
from stages.particle_proposal import ChamferProposalParams, ChamferProposalStage

from test_m2_snapshot import N_FRAMES, SNAP_AT, _check_restore, _run, scene_features  # noqa: F401


def _square(size: int = 80, at: tuple[int, int] = (40, 40), half: int = 10) -> np.ndarray:
    img = np.zeros((size, size), np.uint8)
    img[at[1] - half: at[1] + half, at[0] - half: at[0] + half] = 200
    return img


def _edges_and_chamfer(img: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    e, cham = features.edges_and_chamfer(img, (50.0, 150.0), 1.0, 80.0, "truncated", 100.0)
    return e, cham


def test_align_first_finds_the_shifted_outline_and_keeps_a_matching_one() -> None:
    e0, _ = _edges_and_chamfer(_square())
    first = template_at(e0, np.array([39.5, 39.5, 0.0, 1.0]), np.array([30.0, 30.0]), 200)
    assert first is not None and first.shape[1] == 2 and len(first) > 20
    # the same outline 3 px right and 2 px down: the first template aligned again from the old place lands there
    _, cham = _edges_and_chamfer(_square(at=(43, 42)))
    moved, _ = align_first(cham, first, np.array([39.5, 39.5, 0.0, 1.0]), 5)
    assert np.allclose(moved, [42.5, 41.5, 0.0, 1.0])
    # a reach too short to get there stops on the way, nearer than the start
    short, _ = align_first(cham, first, np.array([39.5, 39.5, 0.0, 1.0]), 1)
    assert np.hypot(short[0] - 42.5, short[1] - 41.5) < np.hypot(3, 2)
    # where it already matches it stays
    _, cham0 = _edges_and_chamfer(_square())
    assert np.allclose(align_first(cham0, first, np.array([39.5, 39.5, 0.0, 1.0]), 4)[0], [39.5, 39.5, 0.0, 1.0])


def test_template_at_is_in_the_template_frame() -> None:
    e, _ = _edges_and_chamfer(_square(at=(40, 40), half=10))
    a = template_at(e, np.array([39.5, 39.5, 0.0, 1.0]), np.array([30.0, 30.0]), 500)
    # twice the scale: the same edges fall at half the distances from the centre in the template's frame
    b = template_at(e, np.array([39.5, 39.5, 0.0, 2.0]), np.array([15.0, 15.0]), 500)
    assert a is not None and b is not None
    assert np.isclose(np.abs(a).max(), 2 * np.abs(b).max(), atol=0.5)
    # a box off the frame holds no edges
    assert template_at(e, np.array([500.0, 500.0, 0.0, 1.0]), np.array([30.0, 30.0]), 200) is None


def _stages(box, every: int, gain: float = 1e-3):
    def make_f():
        return ChamferFilterStage(ChamferFilterParams(init=box, particles=200, seed=4, template_every=every,
                                                      template_drift=0.2, template_gain=gain),
                                  StageContext("filter", "s"))

    def make_p():
        return ChamferProposalStage(ChamferProposalParams(seed=4), StageContext("proposal", "s"))
    return make_f, make_p


def test_chamfer_filter_with_template_update_restores_bit_exact(scene_features) -> None:  # noqa: F811
    feats, _, box, _ = scene_features
    make_f, make_p = _stages(box, every=2)
    _check_restore(make_f, make_p, feats)
    f = make_f()
    _run(f, make_p(), feats[: SNAP_AT + 1], 0, None)
    assert f.state is not None and f.state.first is not None and f.state.template is not None
    # the template was taken again (the scene's target turns and the first template stays)
    assert f.state.template_clock > 0
    assert not np.array_equal(f.state.template, f.state.first)
    g = make_f()
    g.restore(f.snapshot())
    assert g.state is not None and g.state.first is not None and g.state.template is not None
    assert np.array_equal(g.state.first, f.state.first) and np.array_equal(g.state.template, f.state.template)
    assert g.state.template_clock == f.state.template_clock
    assert np.array_equal(g.state.anchor.channels, f.state.anchor.channels)
    # a version-4 snapshot (before the update) restores with its template as the first one
    snap = wire.decode(f.snapshot())
    # its bytes are those of the same Struct with message arrays: the field-by-field snapshots before it
    as_msgs = msgspec.structs.replace(snap, **{name: NDArray.of(v) for name in snap.__struct_fields__
                                               if isinstance(v := getattr(snap, name), np.ndarray)})
    assert snap.bank is None and msgspec.msgpack.encode(as_msgs) == f.snapshot()
    old = msgspec.structs.replace(snap, version=4, first=None, template_clock=0, first_anchor=None, first_fit=(0.0, 0))
    h = make_f()
    h.restore(wire.encode(old))
    assert h.state is not None and h.state.first is not None
    assert np.array_equal(h.state.first, f.state.template) and h.state.template_clock == 0
    assert np.array_equal(h.state.first_anchor, f.state.anchor.channels)
    # a malformed first template is refused with a one-line error
    bad = msgspec.structs.replace(snap, first=NDArray.of(np.zeros((3, 3))))
    with pytest.raises(ValueError, match="bad filter snapshot: first template of shape"):
        make_f().restore(wire.encode(bad))


@pytest.mark.parametrize("every, gain", [(0, 1e-3), (2, 1e6)])
def test_first_template_kept_when_off_or_still_fitting(scene_features, every, gain) -> None:  # noqa: F811
    """template_every 0 never updates; a first template that fits as well as on the first frames
    (a gain too large to reach) is kept as well."""
    feats, _, box, _ = scene_features
    make_f, make_p = _stages(box, every=every, gain=gain)
    f = make_f()
    _run(f, make_p(), feats, 0, None)
    assert f.state is not None
    assert np.array_equal(f.state.template, f.state.first)
    assert len(feats) == N_FRAMES
    with pytest.raises(ValueError, match="template_every"):
        ChamferFilterStage(ChamferFilterParams(init=box, template_every=-1), StageContext("filter", "s"))
