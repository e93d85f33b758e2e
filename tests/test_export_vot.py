"""``gflow export vot DATA OUT``: a sequence folder (``frames/``, ``groundtruth.csv``) as a VOT toolkit
workspace: the frames as they are, one ground-truth line a frame (``nan`` rows where there is none),
the metadata, the list, a stack, ``trackers.ini`` and ``config.yaml``. Where the toolkit is
installed, it evaluates the export and its overlap is gflow's IoU under its stated conventions."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from gflow_core.evaluation.metrics import iou
from gflow_core.synthetic import SyntheticScene
from pipeline.recording.results import read_boxes
import cli_fork

ROOT = Path(__file__).resolve().parent.parent


def gflow(*args: str, cwd: Path = ROOT) -> subprocess.CompletedProcess:
    return cli_fork.run_command([sys.executable, "-m", "pipeline.cli", *args], capture_output=True, text=True, timeout=300,
                                cwd=cwd, stdin=subprocess.DEVNULL)


def make_sequence(folder: Path, n: int = 12, labelled=lambda t: t >= 2 and t % 2 == 0, ext: str = ".png") -> dict:
    """A synthetic sequence folder; ground truth (2 decimals) on the frames ``labelled`` picks."""
    scene = SyntheticScene()
    (folder / "frames").mkdir(parents=True)
    gt = {}
    for t in range(n):
        cv2.imwrite(str(folder / "frames" / f"{t:06d}{ext}"), scene.render(t))
        if labelled(t):
            gt[t] = tuple(round(v, 2) for v in scene.truth_box(t))
    rows = ["frame,x,y,w,h"] + [f"{t},{','.join(f'{v:.2f}' for v in b)}" for t, b in gt.items()]
    (folder / "groundtruth.csv").write_text("\n".join(rows) + "\n")
    return gt


def test_a_sparsely_labelled_sequence_becomes_a_vot_workspace(tmp_path):
    gt = make_sequence(tmp_path / "data" / "syn")
    make_sequence(tmp_path / "data" / "other", n=4, labelled=lambda t: True)
    out = tmp_path / "ws"
    r = gflow("export", "vot", str(tmp_path / "data"), str(out), "--sequences", "syn")
    assert r.returncode == 0, r.stderr
    seq = out / "sequences" / "syn"
    # VOT frame 1 is the first frame with ground truth (2); the frames are the files, byte for byte
    colour = sorted((seq / "color").iterdir())
    assert [p.name for p in colour] == [f"{k:08d}.png" for k in range(1, 11)]
    for k, p in enumerate(colour):
        assert p.read_bytes() == (tmp_path / "data" / "syn" / "frames" / f"{k + 2:06d}.png").read_bytes()
    lines = (seq / "groundtruth.txt").read_text().splitlines()
    assert len(lines) == 10
    for k, line in enumerate(lines):
        want = gt.get(k + 2)
        assert line == ("nan,nan,nan,nan" if want is None else ",".join(f"{v:.2f}".rstrip("0").rstrip(".")
                                                                         for v in want))
    meta = dict(line.split("=", 1) for line in (seq / "sequence").read_text().splitlines())
    assert meta == {"channels.color": "color/%08d.png", "format": "default", "name": "syn", "width": "320",
                    "height": "240", "length": "10", "gflow.first_frame": "2"}
    assert (out / "sequences" / "list.txt").read_text() == "syn\n"
    # frames without ground truth: no supervised (re-initialising) experiment, and the user is told
    stack = yaml.safe_load((out / "stack.yaml").read_text())
    assert list(stack["experiments"]) == ["baseline"]
    assert stack["experiments"]["baseline"]["type"] == "unsupervised"
    assert "syn has frames without ground truth" in r.stdout and "no reinit experiment" in r.stdout
    ini = (out / "trackers.ini").read_text()
    for name in ("dcf", "appearance", "chamfer", "gflow"):
        assert f"[gflow-{name}]\nlabel = gflow {name}\nprotocol = trax\ncommand = {sys.executable} -m gflow.trax " \
               f"--tracker {name}\n" in ini
    assert "gflow-m2" not in ini
    assert yaml.safe_load((out / "config.yaml").read_text()) == {"registry": ["./trackers.ini"],
                                                                 "stack": "./stack.yaml"}


def test_a_densely_labelled_sequence_gets_the_reinit_experiment_and_m2(tmp_path, caviar1_m2_model):
    make_sequence(tmp_path / "data" / "dense", n=6, labelled=lambda t: True, ext=".jpg")
    r = gflow("export", "vot", str(tmp_path / "data" / "dense"), str(tmp_path / "ws"), "--m2-model",
              str(caviar1_m2_model))
    assert r.returncode == 0, r.stderr
    stack = yaml.safe_load((tmp_path / "ws" / "stack.yaml").read_text())
    assert stack["experiments"]["reinit"]["type"] == "supervised"
    assert stack["experiments"]["reinit"]["skip_initialize"] == 5
    assert f"--tracker m2 --model {caviar1_m2_model.resolve()}" in (tmp_path / "ws" / "trackers.ini").read_text()
    assert sorted(p.name for p in (tmp_path / "ws" / "sequences" / "dense" / "color").iterdir())[0] == "00000001.jpg"


@pytest.mark.data
def test_the_shared_sequences_are_exported_as_they_are(crossing, tmp_path):
    r = gflow("export", "vot", str(crossing.parent), str(tmp_path / "ws"), "--sequences", "crossing")
    assert r.returncode == 0, r.stderr
    seq = tmp_path / "ws" / "sequences" / "crossing"
    src = sorted((crossing / "frames").iterdir())
    dst = sorted((seq / "color").iterdir())
    assert len(dst) == len(src) == 120
    assert all(a.read_bytes() == b.read_bytes() for a, b in zip(src, dst))
    gt = read_boxes(crossing / "groundtruth.csv")
    lines = (seq / "groundtruth.txt").read_text().splitlines()
    assert [tuple(float(v) for v in line.split(",")) for line in lines] == [gt[t] for t in range(120)]
    assert "reinit" in yaml.safe_load((tmp_path / "ws" / "stack.yaml").read_text())["experiments"]


def test_mixed_image_formats_are_written_as_png(tmp_path):
    make_sequence(tmp_path / "mixed", n=4, labelled=lambda t: True)
    img = cv2.imread(str(tmp_path / "mixed" / "frames" / "000002.png"))
    (tmp_path / "mixed" / "frames" / "000002.png").unlink()
    cv2.imwrite(str(tmp_path / "mixed" / "frames" / "000002.bmp"), img)
    r = gflow("export", "vot", str(tmp_path / "mixed"), str(tmp_path / "ws"))
    assert r.returncode == 0 and "re-encoded as PNG" in r.stdout, r.stderr
    back = cv2.imread(str(tmp_path / "ws" / "sequences" / "mixed" / "color" / "00000003.png"))
    assert np.array_equal(back, img)


def test_a_jpeg_damaged_inside_is_exported_with_a_warning(crossing, tmp_path):
    """A JPEG whose data is damaged inside decodes whole (libjpeg said so only on standard error, a stray line):
    the export names the frame and libjpeg's words in a warning, and copies it as it is, as gflow track tracks it."""
    seq = tmp_path / "data" / "crossing"
    (seq / "frames").mkdir(parents=True)
    for t in range(6):
        shutil.copy(crossing / "frames" / f"{t:06d}.jpg", seq / "frames" / f"{t:06d}.jpg")
    rows = (crossing / "groundtruth.csv").read_text().splitlines()[:7]
    (seq / "groundtruth.csv").write_text("\n".join(rows) + "\n")
    jpeg = seq / "frames" / "000003.jpg"
    data = bytearray(jpeg.read_bytes())
    mid = len(data) // 2
    data[mid:mid + 200] = np.random.default_rng(1).integers(0, 256, 200, dtype=np.uint8).tobytes()
    jpeg.write_bytes(bytes(data))
    r = gflow("export", "vot", str(seq), str(tmp_path / "ws"))
    assert r.returncode == 0, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("warning: crossing: frame 3 (000003.jpg) decoded from damaged data "
                                                   "(Corrupt JPEG data"), r.stderr
    assert (tmp_path / "ws" / "sequences" / "crossing" / "color" / "00000004.jpg").read_bytes() == bytes(data)


def test_bad_input_is_a_one_line_error(tmp_path):
    def check(args: list[str], says: str) -> None:
        r = gflow("export", "vot", *args)
        assert r.returncode == 2, (args, r.stdout, r.stderr)
        lines = r.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("gflow export vot: error: ") and says in lines[0], r.stderr

    make_sequence(tmp_path / "ok")
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "x").write_text("")
    check([str(tmp_path / "ok"), str(tmp_path / "full")], "is not empty")
    check([str(tmp_path / "nothing"), str(tmp_path / "ws1")], "dataset folder not found")
    check([str(tmp_path / "ok"), str(tmp_path / "ws2"), "--sequences", "nope"], "unknown sequence nope")
    check([str(tmp_path / "ok"), str(tmp_path / "ws3"), "--m2-model", str(tmp_path / "none.npz")], "model file not found")
    make_sequence(tmp_path / "gap")
    (tmp_path / "gap" / "frames" / "000005.png").unlink()
    check([str(tmp_path / "gap"), str(tmp_path / "ws4")], "frame 5 is missing")
    make_sequence(tmp_path / "late", n=4)
    with open(tmp_path / "late" / "groundtruth.csv", "a") as f:
        f.write("9,1,1,5,5\n")
    check([str(tmp_path / "late"), str(tmp_path / "ws5")], "ground truth for frame 9, after the last frame")
    make_sequence(tmp_path / "broken", n=4)
    (tmp_path / "broken" / "frames" / "000003.png").write_bytes(b"not a png")
    check([str(tmp_path / "broken"), str(tmp_path / "ws6")], "000003.png is not a decodable image")
    make_sequence(tmp_path / "sizes", n=4)
    cv2.imwrite(str(tmp_path / "sizes" / "frames" / "000003.png"), np.zeros((10, 10, 3), np.uint8))
    check([str(tmp_path / "sizes"), str(tmp_path / "ws7")], "a VOT sequence has one frame size")
    # a damaged frame in the second sequence used to leave the first written and the workspace half made
    both = tmp_path / "both"
    make_sequence(both / "a", n=4)
    shutil.copytree(tmp_path / "broken", both / "b")
    (tmp_path / "ws8").mkdir()
    check([str(both), str(tmp_path / "ws8")], "nothing was written to")
    assert not any((tmp_path / "ws8").iterdir())
    assert not [p.name for p in tmp_path.iterdir() if p.name.startswith((".ws", "ws")) and p.name != "ws8"]


def _toolkit_overlap(gt: dict, pred: dict, size: tuple[int, int]) -> float:
    """gflow's IoU under the toolkit's conventions: every number rounded to a whole pixel (half to even),
    the boxes clipped to the image, the initialisation frame left out (the stack's burnin: 1)."""
    def box(b):
        x, y, w, h = np.round(np.asarray(b, dtype=float))
        x0, y0, x1, y1 = max(x, 0), max(y, 0), min(x + w, size[0]), min(y + h, size[1])
        return x0, y0, max(x1 - x0, 0), max(y1 - y0, 0)

    frames = sorted(f for f in gt if f > min(gt))
    return float(iou(np.array([box(gt[f]) for f in frames]), np.array([box(pred[f]) for f in frames])).mean())


def test_the_toolkit_evaluates_the_export_and_agrees_with_gflows_overlap(tmp_path):
    vot = shutil.which("vot")
    if vot is None:
        pytest.skip("vot-toolkit is not installed here (no `vot` command on PATH): install it in an environment of "
                    "its own (docs/vot.md; it brings opencv-python) and put its bin folder on PATH")
    gt = make_sequence(tmp_path / "data" / "syn", n=20, labelled=lambda t: t % 2 == 0)
    assert gflow("export", "vot", str(tmp_path / "data"), str(tmp_path / "ws")).returncode == 0
    env = dict(os.environ, PYTHONPATH=str(ROOT), VOT_RESULTS_BINARY="0")
    for cmd in (["evaluate", "--workspace", str(tmp_path / "ws"), "gflow-dcf"],
                ["analysis", "--workspace", str(tmp_path / "ws"), "gflow-dcf", "--name", "a"]):
        r = cli_fork.run_command([vot, *cmd], capture_output=True, text=True, timeout=600, cwd=tmp_path, env=env,
                                 stdin=subprocess.DEVNULL)
        assert r.returncode == 0 and "rror" not in r.stdout + r.stderr, (r.stdout + r.stderr)[-3000:]
    # the toolkit's trajectory (line k is frame k - 1): the boxes gflow track gives
    lines = (tmp_path / "ws" / "results" / "gflow-dcf" / "baseline" / "syn" / "syn_001.txt").read_text().split()
    assert lines[0] == "1" and len(lines) == 20  # the toolkit's code for the initialisation frame
    served = {k: tuple(float(v) for v in line.split(",")) for k, line in enumerate(lines) if k > 0}
    track = gflow("track", str(tmp_path / "data" / "syn"), "--init", ",".join(map(str, gt[0])), "--inline", "--seed",
                  "1", "--no-record", "-q", "--out", str(tmp_path / "track.csv"))
    assert track.returncode == 0, track.stderr
    want = read_boxes(tmp_path / "track.csv")
    assert all(np.abs(np.subtract(served[f], want[f])).max() <= 0.005 + 2e-4 for f in served)
    # its overlap: gflow's IoU over the labelled frames, under its conventions, to the last digit
    result = json.loads((tmp_path / "ws" / "analysis" / "a.json").read_text())["results"]["baseline"]["results"]
    assert result[0][0][0] == pytest.approx(_toolkit_overlap(gt, served, (320, 240)), abs=1e-12)
