"""Answers a user can trust: a frame the tracker never saw is not reported ``tracked``; no command
writes over an existing picture or video; a recording damaged inside is said once by a
multi-process ``gflow track`` too.

The runs are real (``main([...])`` in this process, and one multi-process ``gflow track`` in a
process of its own) on tiny textured image folders and a short recording of the synthetic scene,
written into tmp folders.
"""

from __future__ import annotations

import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from pipeline.cli.main import main
import cli_fork


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> Path:
    """frames/ (six 64x48 frames of one still textured scene: the target is there to be tracked),
    broken/ (the same, frame 3 not an image) and demo.mcap (10 frames of the synthetic scene, inline)."""
    d = tmp_path_factory.mktemp("trust3")
    rng = np.random.default_rng(0)
    for name in ("frames", "broken"):
        (d / name).mkdir()
    img = rng.integers(0, 255, (48, 64, 3), dtype=np.uint8)
    for i in range(6):
        for name in ("frames", "broken"):
            cv2.imwrite(str(d / name / f"{i:04d}.png"), img)
    (d / "broken" / "0003.png").write_bytes(b"not a png")
    assert main(["demo", "--frames", "10", "--inline", "--record", str(d / "demo.mcap")]) == 0
    return d


def rows(path: Path) -> list[list[str]]:
    return [ln.split(",") for ln in path.read_text().splitlines()[1:]]


@pytest.mark.parametrize("tracker,folder,extra", [
    ("dcf", "broken", []), ("gflow", "broken", []),
    ("dcf", "frames", ["--set", "source.blank_every=4", "--set", "source.blank_count=1"]),  # frame 3 uniform
])
def test_a_frame_never_seen_is_not_reported_tracked(files: Path, tmp_path: Path, tracker: str, folder: str,
                                                    extra: list[str]) -> None:
    """Frame 3 cannot be read (or is blank): the filter coasts over it. Its row said ``tracked``
    (``confidence 0.000`` for dcf); now the target is ``occluded`` (hidden from the tracker, the box
    where it is expected), and the frames before it are as in the run of the whole folder."""
    out = {}
    for name, more in (("whole", []), ("hit", extra)):
        out[name] = tmp_path / f"{name}.csv"
        src = files / ("frames" if name == "whole" else folder)
        assert main(["track", str(src), "--init", "10,10,20,20", "--tracker", tracker, "--inline", "-q",
                     "--no-record", "--out", str(out[name]), *more]) == 0
    whole, hit = rows(out["whole"]), rows(out["hit"])
    assert [r[0] for r in hit] == ["0", "1", "2", "3", "4", "5"]
    assert hit[:3] == whole[:3]
    assert hit[3][6] == "occluded" and whole[3][6] == "tracked", (hit[3], whole[3])


def test_the_stage_relabels_only_the_frame_it_did_not_see() -> None:
    """``unseen`` turns ``tracked`` into ``occluded`` and keeps the tracker's own ``occluded``/``lost``."""
    from gflow_core.tracker import Estimate
    from gflow_core.tracker import unseen

    for said, then in (("tracked", "occluded"), ("occluded", "occluded"), ("lost", "lost")):
        est = Estimate(frame=3, box=(1.0, 2.0, 3.0, 4.0), confidence=0.0, target_state=said, phase="coast")
        assert unseen(est).target_state == then and unseen(est).box == est.box


@pytest.mark.parametrize("argv,existing", [
    (["render", "{d}/demo.mcap", "{x}", "-q"], "o.mp4"),
    (["render", "{d}/demo.mcap", "{p}", "-q"], "pngs/000002.png"),  # a folder of PNGs holding one of them
    (["frame", "{d}/frames", "0", "{x}"], "f.png"),
    (["plot", "{d}/demo.mcap", "{x}"], "p.png"),
])
def test_no_command_writes_over_a_picture_or_video(files: Path, tmp_path: Path, monkeypatch, capsys,
                                                   argv: list[str], existing: str) -> None:
    """An existing video or picture was written over without a word; now refused in one line, the
    file left as it was."""
    monkeypatch.chdir(tmp_path)
    x = tmp_path / existing
    x.parent.mkdir(parents=True, exist_ok=True)
    x.write_bytes(b"someone's picture")
    capsys.readouterr()
    rc = main([a.replace("{d}", str(files)).replace("{x}", str(x)).replace("{p}", str(x.parent))
               for a in argv])
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert rc == 2 and len(err) == 1 and "never writes over a picture" in err[0], err
    assert x.read_bytes() == b"someone's picture"


def test_a_new_picture_is_still_written(files: Path, tmp_path: Path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    assert main(["frame", str(files / "frames"), "0", "f.png"]) == 0
    assert cv2.imread(str(tmp_path / "f.png")) is not None


def test_damage_inside_a_recording_is_said_once_by_a_multi_process_track(files: Path, tmp_path: Path) -> None:
    """A chunk that fails its CRC in the middle of the recording tracked: ``--inline`` said it, the
    multi-process run (the source in a process of its own) tracked the frames before it in silence."""
    from conftest import damaged_copy

    bad = damaged_copy(files / "demo.mcap", tmp_path / "bad.mcap")
    r = cli_fork.run_command([sys.executable, "-m", "pipeline.cli.main", "track", str(bad), "--init", "100,80,40,40",
                              "--out", str(tmp_path / "b.csv"), "--no-record"], capture_output=True, text=True,
                             timeout=120, cwd=tmp_path)
    said = [ln for ln in (r.stdout + r.stderr).splitlines() if "recording is damaged at byte" in ln]
    assert r.returncode == 0 and len(said) == 1 and "bad.mcap" in said[0], r.stdout + r.stderr
    assert 0 < len(rows(tmp_path / "b.csv")) < 10  # the frames before the damage were tracked


@pytest.mark.parametrize("setting,words", [
    ("filter.particles=abc", ("particles must be a whole number", "'abc'")),
    ("filter.lost_guard=maybe", ("lost_guard must be true or false",)),
    ("filter.nonexist=3", ("no parameter 'nonexist'", "known parameters: seed")),
])
def test_a_stage_setting_of_the_wrong_kind_is_said_plainly(tmp_path: Path, monkeypatch, capsys, setting: str,
                                                           words: tuple[str, ...]) -> None:
    """``gflow run --set STAGE.PARAM=V`` gave msgspec's ``Expected `int`, got `str` - at `$.particles```;
    it now says what the parameter takes, in the words the tracker block's ``--set`` uses."""
    monkeypatch.chdir(tmp_path)
    graph = Path(__file__).resolve().parents[1] / "pipeline" / "graphs" / "demo.yaml"
    capsys.readouterr()
    rc = main(["run", str(graph), "--set", setting])
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert rc == 2 and len(err) == 1, err
    assert "Expected `" not in err[0] and all(w in err[0] for w in words), err
    assert not list(tmp_path.iterdir()), "nothing may be written before the graph is checked"
