"""The search's best placement refined half a cell about it (``search_refine``): the search scores placements on
its region's lattice of cells, up to half a cell from the target, where the response is lower than a window
centred on the target gives; refined, the placement's response is never lower and lands nearer the target."""

from __future__ import annotations

import dataclasses

import numpy as np

from gflow_core.dcf import model as tm
from gflow_core.dcf.params import DCFParams
from gflow_core.dcf.tracker import TRACKER
from dcf_scene import BG, TARGET, hidden


def _shifted(dx: int, dy: int) -> np.ndarray:
    """(H, W) uint8: the scene with the target centred at (130 + dx, 100 + dy)."""
    img = BG.copy()
    img[82 + dy:118 + dy, 115 + dx:145 + dx] = TARGET
    return np.clip(img, 0, 255).astype(np.uint8)


def _best(p: DCFParams, img: np.ndarray, st) -> tm.Candidate:
    obs = TRACKER.observe(p, img)
    (c,) = tm.search(st.model, obs.image, obs.grey, np.array([130.0, 100.0]), (40.0, 40.0), st.log_s, st.geom, p)
    return c


def test_refined_placements_score_higher_and_lie_nearer_the_target() -> None:
    off = DCFParams(colour_weight=0.0)
    on = dataclasses.replace(off, search_refine=True)
    st = hidden(off)
    gained = nearer = 0
    for d in range(1, 8):  # the target moved d px right and down: every phase of the search's lattice
        img = _shifted(d, d)
        coarse, fine = _best(off, img, st), _best(on, img, st)
        truth = np.array([130.0 + d, 100.0 + d])
        assert fine.r >= coarse.r  # the search's own placement is among the nine
        e0, e1 = float(np.hypot(*(coarse.centre - truth))), float(np.hypot(*(fine.centre - truth)))
        assert e1 <= e0 + 1e-9 or fine.r > coarse.r, (d, e0, e1)
        gained += fine.r > coarse.r + 1e-6
        nearer += e1 < e0 - 1e-6
    assert gained >= 2 and nearer >= 2, (gained, nearer)  # the lattice missed the target somewhere, and refine found it

