"""The stress benchmark's state figures with the undisturbed frames split by the box: on a small
case list with known boxes and states, whose fractions are known by construction."""

from __future__ import annotations

import json

import numpy as np
import pytest

from gflow_core.evaluation.metrics import overlaps, state_score
from gflow_core.evaluation.stress import StressCase
from pipeline.evaluation.stress_benchmark import StressRow, format_stress, stress_json

ON = (10.0, 10.0, 20.0, 20.0)  # the truth on every frame
OFF = (100.0, 100.0, 20.0, 20.0)  # a box that misses it (IoU 0)
NEAR = (14.0, 10.0, 20.0, 20.0)  # a box 4 px to the side: IoU 16/24 = 0.67, on the target


def _row(case: StressCase, boxes: list, states: list, visible: list, perturbed: list) -> StressRow:
    n = len(boxes)
    ov = overlaps({f: ON for f in range(n)}, dict(enumerate(boxes)))
    st = state_score(states, np.array(visible, dtype=float), np.array(perturbed, dtype=bool), overlap=ov)
    return StressRow("seq", case.name, "dcf", "tracker", frames=n, state=st,
                     extra={"case_kind": case.kind, "case_length": case.length, "case_amount": case.amount})


@pytest.fixture
def rows() -> list[StressRow]:
    occ = StressCase("occlude-6", "occlude", 6)
    none = StressCase("none", "none", 6)
    # occlude-6: frames 0-3 undisturbed (3 said occluded with the box on the target: a wrong state),
    # 4-9 hidden, 10 back on the target and tracked, 11 off the target and said lost (an honest state)
    a = _row(occ, [ON, NEAR, ON, ON] + [OFF] * 6 + [ON, OFF],
             ["tracked"] * 3 + ["occluded"] * 7 + ["tracked", "lost"],
             [1.0] * 4 + [0.0] * 6 + [1.0] * 2, [0] * 4 + [1] * 6 + [0] * 2)
    # none: every frame undisturbed; 0-2 on and tracked, 3 off yet tracked, 4 lost and 5 occluded off
    # the target, 6 off the target with no state (counted as neither)
    b = _row(none, [ON] * 3 + [OFF] * 4, ["tracked"] * 4 + ["lost", "occluded", None], [1.0] * 7, [0] * 7)
    return [a, b]


def test_state_score_splits_the_undisturbed_frames_by_the_box(rows):
    a, b = (r.state for r in rows)
    assert a is not None and b is not None
    assert (a.shown, a.shown_right) == (6, 4)
    assert (a.shown_on, a.shown_on_tracked, a.shown_off, a.shown_off_hidden) == (5, 4, 1, 1)
    assert (b.shown, b.shown_right) == (7, 4)
    assert (b.shown_on, b.shown_on_tracked, b.shown_off, b.shown_off_hidden) == (3, 3, 4, 2)
    assert b.shown_on_rate == 1.0 and b.shown_off_rate == 0.5
    assert a.to_json()["undisturbed_on_target_reported_tracked"] == 0.8
    assert a.to_json()["undisturbed_off_target_frames"] == 1
    # without the overlaps every undisturbed frame counts as on the target
    plain = state_score(["tracked", "lost"], np.ones(2), np.zeros(2, dtype=bool))
    assert (plain.shown_on, plain.shown_on_tracked, plain.shown_off, plain.shown_off_hidden) == (2, 1, 0, 0)


def test_summary_pools_the_split_beside_the_figures_of_before(rows):
    s = stress_json(rows, {}, [])["summary"]["dcf"]
    assert s["undisturbed_reported_tracked"] == [8, 13]
    assert s["undisturbed_on_target_reported_tracked"] == [7, 8]
    assert s["undisturbed_off_target_reported_occluded_or_lost"] == [3, 5]
    assert s["off_target_reported_tracked"] == [1, 5]  # frame 3 of none; the hidden frames are not scored
    json.dumps(s)


@pytest.mark.parametrize("markdown", [False, True])
def test_tables_print_the_split_with_its_counts(rows, markdown):
    text = format_stress(rows, markdown=markdown)
    line = next(x for x in text.splitlines() if x.startswith("- undisturbed frames split by the box"))
    assert "reported tracked 0.88 (7 / 8)" in line and "reported occluded/lost 0.60 (3 / 5)" in line
    assert "undisturbed frames reported tracked 0.62 (8/13)" in text  # the figure of before, unchanged
    on = next(x for x in text.splitlines() if "undisturbed, box on the target: reported tracked" in x)
    off = next(x for x in text.splitlines() if "undisturbed, box off the target: reported occluded/lost" in x)
    assert "0.88 (7 / 8)" in on and "0.60 (3 / 5)" in off
    assert on.startswith("|") == markdown


def test_counts_take_thousands_separators():
    from pipeline.evaluation.stress_benchmark import _rate_of
    assert _rate_of(8900, 8990) == "0.99 (8,900 / 8,990)" and _rate_of(0, 0) == "-"


class _Plan:
    """What :func:`stress_scores` reads of a :class:`StressPlan`: its window, length, visibility and perturbation."""

    def __init__(self, n: int, window: tuple[int, int]) -> None:
        self.window, self.visible, self.perturbed = window, np.ones(n), np.zeros(n, dtype=bool)

    def __len__(self) -> int:
        return len(self.visible)


def test_stress_scores_read_a_row_of_no_box_as_gflow_eval_does(tmp_path):
    """A NaN row in a tracker's CSV stopped the stress scoring ("box has NaN") though `gflow eval` scores it as a
    miss; now both score it overlap 0, and its state is still read."""
    from types import SimpleNamespace

    from pipeline.evaluation.scored_boxes import read_scored_boxes
    from pipeline.evaluation.sequence_benchmark import Sequence
    from pipeline.evaluation.stress_benchmark import AFTER_GAP, stress_scores

    n = AFTER_GAP + 6
    gt = {f: ON for f in range(n)}
    rows = [f"{f},10,10,20,20,0.9,tracked" for f in range(n)]
    rows[AFTER_GAP + 2] = f"{AFTER_GAP + 2},nan,nan,nan,nan,nan,lost"
    csv = tmp_path / "boxes.csv"
    csv.write_text("frame,x,y,w,h,confidence,state\n" + "\n".join(rows) + "\n")
    d = SimpleNamespace(seq=Sequence("s", tmp_path, gt, ()), plan=_Plan(n, (0, 0)))
    row = stress_scores(StressRow("s", "none", "dcf", "tracker"), d, csv)
    assert row.overlap is not None
    np.testing.assert_array_equal(row.overlap, overlaps(gt, read_scored_boxes(csv).boxes))
    assert row.overlap[AFTER_GAP + 2] == 0.0 and row.after == 5 / 6
    assert row.state is not None and row.state.shown_off == 1 and row.state.shown_off_hidden == 1
