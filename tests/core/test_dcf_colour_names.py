"""dcf's colour-name cells (``colour_names``; gflow_core.dcf.features.colour_names, the CN tracker's and CSRT's
colour feature by prototypes in CIELab): each name wins on its own colour and the memberships sum to one (so
the centred cells sum to 0); on a colour frame the filter holds 43 channels with the intensity last, on a grey
one the option changes nothing; it is on by default, and a plan recorded before it existed reads it off; the
filter goes into a snapshot and comes back bit for bit."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from gflow_core.dcf import model as tm
from gflow_core.dcf.features import N_NAMES, colour_names, sample
from gflow_core.dcf.params import DCFParams
from gflow_core.params import added_later
from tests.core.test_dcf_tracker import Scene, _resumed, _track

#: the names in the order of gflow_core.dcf.features._NAME_RGB
NAMES = ["black", "blue", "brown", "grey", "green", "orange", "pink", "purple", "red", "white", "yellow"]
#: a plain colour of each name, BGR
PLAIN = {"black": (10, 10, 10), "blue": (190, 60, 30), "green": (50, 150, 30), "red": (40, 30, 210),
         "white": (250, 250, 250), "yellow": (30, 215, 235), "orange": (30, 130, 240), "grey": (125, 125, 125)}


@pytest.mark.parametrize("name", sorted(PLAIN))
def test_each_name_wins_on_its_own_colour(name: str) -> None:
    patch = np.zeros((8, 12, 3), np.uint8)
    patch[:] = PLAIN[name]
    cells = colour_names(patch, 4)
    assert cells.shape == (2, 3, N_NAMES) and cells.dtype == np.float32
    # centred memberships: each cell's sum over the names is 0, its largest the colour's own name
    assert np.allclose(cells.sum(-1), 0.0, atol=1e-5)
    assert all(NAMES[i] == name for i in cells.reshape(-1, N_NAMES).argmax(-1))


def _colour_scene(n: int, seed: int = 4) -> tuple[list[np.ndarray], tuple[float, float, float, float]]:
    """``n`` colour frames: Scene's grey target and background, the target's pixels tinted red and the
    background's green at the same grey level, so that grey features see the texture and only colour tells
    the target's own pixels; the target moves 3 px right and 1 down a frame."""
    sc = Scene(lambda t: (130.0 + 3.0 * t, 100.0 + 1.0 * t), seed=seed)
    frames = []
    for t in range(n):
        g = sc.frame(t).astype(np.float32)
        x, y, w, h = (int(round(v)) for v in sc.truth(t))
        bgr = np.stack([0.6 * g, 1.2 * g, 0.6 * g], axis=-1)
        bgr[y:y + h, x:x + w] = np.stack([0.6 * g[y:y + h, x:x + w], 0.6 * g[y:y + h, x:x + w],
                                          1.2 * g[y:y + h, x:x + w]], axis=-1)
        frames.append(np.clip(bgr, 0, 255).astype(np.uint8))
    return frames, sc.truth(0)


def test_on_by_default_a_colour_frame_holds_43_channels_and_off_32() -> None:
    frames, box = _colour_scene(6)
    _, ref = _track(frames, box)
    assert DCFParams().colour_names is True and added_later(DCFParams)["colour_names"] is False
    st_off, off = _track(frames, box, DCFParams(colour_names=False))
    assert st_off.model.det.shape[-1] == 32
    st_on, on = _track(frames, box, DCFParams(colour_names=True))
    assert st_on.model.det.shape[-1] == 32 + N_NAMES and st_on.model.anchor.shape == st_on.model.det.shape
    assert [e.box for e in on] == [e.box for e in ref] and [e.box for e in off] != [e.box for e in ref]
    # the cells: fHOG, the names, and the intensity last (channel_weights leaves it out by its place)
    grey = cv2.cvtColor(frames[0], cv2.COLOR_BGR2GRAY).astype(np.float32)
    centre, k = (box[0] + 0.5 * (box[2] - 1), box[1] + 0.5 * (box[3] - 1)), (1.0, 1.0)
    plain = tm.window(frames[0], grey, centre, (64, 64), k, 4, "colour")
    named = tm.window(frames[0], grey, centre, (64, 64), k, 4, "colour", names=True)
    patch = sample(frames[0], centre, (64, 64), k)
    assert np.array_equal(named.x[..., :31], plain.x[..., :31]) and np.array_equal(named.x[..., -1], plain.x[..., -1])
    assert np.array_equal(named.x[..., 31:-1], colour_names(patch, 4))


def test_on_a_grey_frame_the_option_changes_nothing() -> None:
    frames, box = _colour_scene(5)
    grey = [cv2.cvtColor(cv2.cvtColor(f, cv2.COLOR_BGR2GRAY), cv2.COLOR_GRAY2BGR) for f in frames]
    _, off = _track(grey, box, DCFParams(colour_names=False))
    st, on = _track(grey, box, DCFParams(colour_names=True))
    assert [e.box for e in on] == [e.box for e in off] and st.model.det.shape[-1] == 32


def test_the_filter_with_names_goes_into_a_snapshot_and_comes_back_bit_for_bit() -> None:
    q = DCFParams(colour_names=True)
    frames, box = _colour_scene(8)
    st, _ = _track(frames[:4], box, q)
    back = _resumed(st, frames, 4, q)
    assert back.model.det.shape[-1] == 32 + N_NAMES and np.array_equal(back.model.det, st.model.det)
