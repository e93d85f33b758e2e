"""dcf's spatial reliability map (``segment``; gflow_core.dcf.reliability, CSR-DCF): on a red target with a blue
hole on a blue background the map is 0 in the hole and 1 on the target, and the filter learnt under it has no
weight in the hole (the box's has); a target whose colours say nothing, or a map that covers too little of
the box, gives the box; off (0, the default) the tracker is the box's, and bad values are refused in one line."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from gflow_core.dcf import filter as cf
from gflow_core.dcf import model as tm
from gflow_core.dcf.constrained import box_mask
from gflow_core.dcf.features import N_COLOUR_BINS, N_GREY_BINS, colour_bins
from gflow_core.dcf.histogram import histograms
from gflow_core.dcf.params import DCFParams
from gflow_core.dcf.reliability import reliability
from gflow_core.params import added_later, make
from tests.core.test_dcf_tracker import _resumed, _texture, _track

CELL = 4
#: the window (37 cells a side), the box (14 cells) and the hole in it (6 cells), all centred
WIN, BOX, HOLE = 37, 14, 6
RED, BLUE = (40, 30, 200), (200, 60, 30)
#: the filter's window of a box of BOX cells: WIN cells at one template pixel an image pixel
WINDOW = {"padding": (WIN - BOX) / BOX, "template": WIN * CELL}


def _lo(n: int) -> int:
    """The first cell of a centred run of ``n`` cells in the window."""
    return (WIN - n) // 2


def _patch(hole: bool = True) -> np.ndarray:
    """(148, 148, 3) uint8 BGR: a red box of BOX cells, a blue hole of HOLE cells in it, on blue, with a little
    noise so that the colours fill neighbouring bins."""
    img = np.empty((WIN * CELL, WIN * CELL, 3), np.float64)
    img[:] = BLUE
    b, h = _lo(BOX) * CELL, _lo(HOLE) * CELL
    img[b:b + BOX * CELL, b:b + BOX * CELL] = RED
    if hole:
        img[h:h + HOLE * CELL, h:h + HOLE * CELL] = BLUE
    img += np.random.default_rng(3).normal(0.0, 4.0, img.shape)
    return np.clip(img, 0, 255).astype(np.uint8)


def _map(patch: np.ndarray, grey: bool = False, threshold: float = 0.5, cover: float = 0.05) -> np.ndarray | None:
    bins = colour_bins(patch[..., 0] if grey else patch, grey=grey)
    valid = np.ones(bins.shape, bool)
    box = (float(BOX * CELL), float(BOX * CELL))
    colour = histograms(bins, valid, box, N_GREY_BINS if grey else N_COLOUR_BINS)
    return reliability(colour, bins, valid, box, CELL, box_mask((WIN, WIN), (BOX, BOX), 1.0), threshold, cover)


def test_the_map_is_zero_in_a_background_coloured_hole_and_one_on_the_target() -> None:
    m = _map(_patch())
    assert m is not None and m.shape == (WIN, WIN)
    b, h = _lo(BOX), _lo(HOLE)
    # the hole's cells, but for the ring of one cell the dilation adds to the target
    assert np.all(m[h + 1:h + HOLE - 1, h + 1:h + HOLE - 1] == 0.0)
    # every red cell is reliable
    red = np.zeros((WIN, WIN), bool)
    red[b:b + BOX, b:b + BOX] = True
    red[h:h + HOLE, h:h + HOLE] = False
    assert np.all(m[red] == 1.0)
    # beyond the box by at most the one cell of the dilation
    assert m[:b - 1].sum() == 0 and m[b + BOX + 1:].sum() == 0 and m[:, :b - 1].sum() == 0


def test_a_map_that_says_nothing_or_covers_too_little_gives_the_box() -> None:
    # grey levels of the target's and the background's alike: the colour is flat over the box
    flat = np.random.default_rng(5).integers(0, 256, (WIN * CELL, WIN * CELL, 3)).astype(np.uint8)
    assert _map(flat, grey=True) is None
    # a target of one colour throughout: the colour is flat too (the map would be the box)
    assert _map(_patch(hole=False)) is None
    # the map of the target with a hole, asked to cover all the box
    assert _map(_patch()) is not None and _map(_patch(), cover=1.0) is None


def _model(p: DCFParams) -> tuple[tm.TargetModel, tm.Geometry]:
    patch = _patch()
    grey = patch.mean(axis=2).astype(np.float32)
    c = ((WIN * CELL - 1) / 2.0, (WIN * CELL - 1) / 2.0)
    # a box of the target's size whose window is the patch's, at one template pixel an image pixel
    geom = tm.geometry((BOX * CELL, BOX * CELL), p)
    assert geom.cells == (WIN, WIN) and geom.k0 == (1.0, 1.0)
    return tm.init_model(patch, grey, False, c, geom, p), geom


def test_the_filter_learnt_under_the_map_has_no_weight_in_the_hole() -> None:
    """The first filter (and the anchor), and the filter after a frame is learnt, are nought in the hole's cells
    with the map; the box's filter is not (so the test would fail without the map)."""
    seg = DCFParams(segment=0.5, **WINDOW)
    on, geom = _model(seg)
    off, _ = _model(DCFParams(**WINDOW))
    wc, hc = geom.cells
    hole = slice(_lo(HOLE) + 1, _lo(HOLE) + HOLE - 1), slice(_lo(HOLE) + 1, _lo(HOLE) + HOLE - 1)
    for det in (on.det, on.anchor):
        h = cf.spatial(det, (hc, wc))
        assert np.abs(h[hole]).max() <= 1e-9 * np.abs(h).max()
    h_off = cf.spatial(off.det, (hc, wc))
    assert np.abs(h_off[hole]).max() > 0.01 * np.abs(h_off).max()
    patch = _patch()
    c = ((WIN * CELL - 1) / 2.0, (WIN * CELL - 1) / 2.0)
    after = tm.learn(on, patch, patch.mean(axis=2).astype(np.float32), c, 0.0, geom, seg, 0.02)
    h = cf.spatial(after.det, (hc, wc))
    assert np.abs(h[hole]).max() <= 1e-9 * np.abs(h).max()


def _frames(n: int) -> tuple[list[np.ndarray], tuple[float, float, float, float]]:
    """``n`` frames of a red textured 30 x 36 target with a blue 14 x 16 hole moving 3 px right and 1 down a
    frame over a blue textured background, and its first box."""
    rng = np.random.default_rng(2)
    bg = np.clip(np.array(BLUE, np.float64) + 40.0 * _texture(rng, 200, 260, 10.0)[..., None] / 255.0, 0, 255)
    target = np.clip(np.array(RED, np.float64) + 60.0 * _texture(rng, 36, 30, 5.0)[..., None] / 255.0, 0, 255)
    target[10:26, 8:22] = bg[10:26, 8:22]
    out = []
    for t in range(n):
        img = bg.copy()
        img[60 + t:96 + t, 80 + 3 * t:110 + 3 * t] = target
        img += np.random.default_rng([2, t]).normal(0.0, 3.0, img.shape)
        out.append(np.clip(img, 0, 255).astype(np.uint8))
    return out, (80.0, 60.0, 30.0, 36.0)


def test_off_it_tracks_as_the_box_does_and_on_it_tracks_otherwise() -> None:
    """segment = 0 (the default, so not a parameter added later) gives the box's track bit for bit; on, a track
    of the same frames differs (the map is used)."""
    frames, box = _frames(8)
    _, ref = _track(frames, box)
    _, off = _track(frames, box, DCFParams(segment=0.0))
    _, on = _track(frames, box, DCFParams(segment=0.5))
    assert DCFParams().segment == 0.0 and "segment" not in added_later(DCFParams)
    assert [e.box for e in off] == [e.box for e in ref]
    assert [e.box for e in on] != [e.box for e in ref]


@pytest.mark.parametrize("kw, message", [
    ({"segment": 1.5}, "segment, segment_cover and segment_rate must be in [0, 1], got 1.5, 0.5, 0.02"),
    ({"segment": float("nan")}, "segment, segment_cover and segment_rate must be in [0, 1], got nan, 0.5, 0.02"),
    ({"segment_cover": -0.1}, "segment, segment_cover and segment_rate must be in [0, 1], got 0.0, -0.1, 0.02"),
    ({"segment": 0.5, "mask": 0.0}, "segment needs the masked filter and the colour model (mask and colour_weight "
                                    "> 0), got mask 0.0, colour_weight 0.3"),
    ({"segment": 0.5, "colour_weight": 0.0}, "segment needs the masked filter and the colour model"),
])
def test_bad_values_are_refused_in_one_line(kw, message) -> None:
    with pytest.raises(ValueError) as e:
        make(DCFParams, kw)
    assert message in str(e.value) and "\n" not in str(e.value)


def test_with_a_rate_the_support_is_the_running_maps_majority_and_goes_into_a_snapshot() -> None:
    """With ``segment_rate`` the first support is the first map; a frame whose map is the box moves the running
    average by the rate only (the hole stays out of the support, so the filter has no weight there); the
    running average goes into the state's arrays and comes back bit for bit."""
    p = DCFParams(segment=0.5, segment_rate=0.1, **WINDOW)
    on, geom = _model(p)
    first = _map(_patch())
    assert on.support is not None and np.array_equal(on.support, first)
    # a frame of the target without its hole: its map is the box (one colour throughout)
    plain = _patch(hole=False)
    c = ((WIN * CELL - 1) / 2.0, (WIN * CELL - 1) / 2.0)
    after = tm.learn(on, plain, plain.mean(axis=2).astype(np.float32), c, 0.0, geom, p, 0.02)
    assert after.support is not None
    assert np.allclose(after.support, 0.9 * first + 0.1 * geom.mask)
    hole = slice(_lo(HOLE) + 1, _lo(HOLE) + HOLE - 1), slice(_lo(HOLE) + 1, _lo(HOLE) + HOLE - 1)
    h = cf.spatial(after.det, geom.cells[::-1])
    assert np.abs(h[hole]).max() <= 1e-9 * np.abs(h).max()
    # the snapshot
    frames, box = _frames(10)
    q = DCFParams(segment=0.5, segment_rate=0.1)
    st, _ = _track(frames[:5], box, q)
    assert st.model.support is not None
    back = _resumed(st, frames, 5, q)
    assert back.model.support is not None and np.array_equal(back.model.support, st.model.support)


def test_grey_footage_keeps_the_box_unless_asked() -> None:
    """On grey frames the map is used only with ``segment_grey``: without it the track is the box's bit for bit."""
    frames, box = _frames(8)
    grey = [np.repeat(cv2.cvtColor(f, cv2.COLOR_BGR2GRAY)[..., None], 3, axis=2) for f in frames]
    _, ref = _track(grey, box)
    _, off = _track(grey, box, DCFParams(segment=0.5))
    _, on = _track(grey, box, DCFParams(segment=0.5, segment_grey=True))
    assert [e.box for e in off] == [e.box for e in ref]
    assert [e.box for e in on] != [e.box for e in ref]
