"""``gflow run`` of a tracker's built-in graph and ``gflow track`` with the same tracker, source and
seed give the same boxes: the graph files run the trackers' own defaults."""

from __future__ import annotations

import sys

import pytest

from pipeline.io.mcap_io import iter_records
from gflow_msgs.messages import decode
import cli_fork

FRAMES = 40


def estimates(args: list[str], rec) -> dict[int, tuple]:
    out = cli_fork.run_command([sys.executable, "-m", "pipeline.cli.main", *args, "--inline", "--record", str(rec)],
                               capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr
    return {r.seq: (tuple((m := decode(r.data)).box), m.confidence, m.target_state)
            for r in iter_records(rec) if r.type in ("Estimate", "PoseEstimate")}


def box_of(values) -> str:
    return "[" + ", ".join(str(v) for v in values) + "]"


#: tracker -> the stage parameters `gflow track --init BOX --seed SEED` fills in, for `gflow run --set`
FILLED = {
    "appearance": lambda box, seed: {"proposal.init": box, "filter.init": box, "proposal.seed": seed,
                                     "filter.seed": seed},
    "gflow": lambda box, seed: {"proposal.init": box, "filter.init": box, "proposal.seed": seed, "filter.seed": seed},
    "chamfer": lambda box, seed: {"filter.init": box, "filter.seed": seed, "proposal.seed": seed,
                                  "preprocess.calibrate_box": box},
    "dcf": lambda box, seed: {"proposal.init": box, "filter.init": box, "proposal.seed": seed, "filter.seed": seed},
    # a model learned with `gflow learn m2`'s default preprocessing, which the graph's is
    "m2": lambda box, seed: {"filter.init": box, "filter.seed": seed, "proposal.init": box, "proposal.seed": seed},
}


@pytest.mark.data
@pytest.mark.parametrize("tracker", sorted(FILLED))
def test_gflow_run_of_the_built_in_graph_equals_gflow_track(caviar1, tmp_path, tracker, request) -> None:
    box, seed = (129.0, 71.0, 30.0, 79.0), 1
    model = []
    sets = {"source.path": str(caviar1 / "frames"), "source.stop": FRAMES, **FILLED[tracker](box_of(box), seed)}
    if tracker == "m2":
        path = request.getfixturevalue("caviar1_m2_model").resolve()
        model = ["--model", str(path)]
        sets.update({"filter.model": path, "proposal.model": path})
    track = estimates(["track", str(caviar1), "--tracker", tracker, "--init", ",".join(map(str, box)), "--seed",
                       str(seed), "--stop", str(FRAMES), "--out", str(tmp_path / "b.csv"), "-q", *model],
                      tmp_path / "t.mcap")
    run = estimates(["run", tracker, *[a for k, v in sets.items() for a in ("--set", f"{k}={v}")]],
                    tmp_path / "r.mcap")
    assert len(track) == FRAMES and run == track
