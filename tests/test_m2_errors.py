"""Model files and training input that M2 cannot use give one clear error naming the problem.

Model files: round trips (M2 and morphable), corrupt, truncated, not a zip, pickled arrays,
no or unknown kind, another format version, bad values; through `load_model`,
`gflow info` and `gflow track --tracker m2`. Training input: no foreground, a single frame,
K larger than the data, missing files, bad options (`gflow learn m2`).
"""

from __future__ import annotations

import zipfile
from pathlib import Path

import cv2
import numpy as np
import pytest

from gflow_core.gflow.head_model import EllipsoidHead
from gflow_core.m2.learn import learn
from gflow_core.m2.model import FORMAT_VERSION
from pipeline.cli.main import main
from pipeline.io.modelfile import load_meta, load_model, save_model


def blob_frames(n: int, seed: int = 0) -> list[np.ndarray]:
    """A textured static background with an ellipse walking right: a fixed-camera training video."""
    rng = np.random.default_rng(seed)
    small = rng.uniform(0, 1, (8, 10))
    bg = np.clip(60 + 50 * cv2.resize(small, (120, 90), interpolation=cv2.INTER_CUBIC), 0, 255).astype(np.uint8)
    out = []
    for t in range(n):
        f = cv2.cvtColor(bg, cv2.COLOR_GRAY2BGR)
        cv2.ellipse(f, (20 + 4 * t, 45), (9 + (t % 3), 20), 0, 0, 360, (230, 220, 210), -1)
        out.append(f)
    return out


def write_folder(folder: Path, frames: list[np.ndarray]) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    for i, f in enumerate(frames):
        cv2.imwrite(str(folder / f"{i:06d}.png"), f)
    return folder


@pytest.fixture(scope="module")
def model_file(tmp_path_factory) -> Path:
    from gflow_core.m2 import training

    ts = training.curves_from_background(blob_frames(16), max_points=60)
    path = tmp_path_factory.mktemp("mf") / "m.npz"
    save_model(path, learn(ts, "chamfer", K=3), meta={"canny_low": 50.0, "canny_high": 150.0, "source": "blobs"})
    return path


def _arrays(path: Path) -> dict[str, np.ndarray]:
    with np.load(path, allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


def _fails(capsys, argv: list[str], *needles: str) -> str:
    assert main(argv) == 2
    err = capsys.readouterr().err
    for n in needles:
        assert n in err, f"{n!r} not in {err!r}"
    return err


def test_model_files_round_trip(model_file, tmp_path) -> None:
    m = load_model(model_file)
    again = save_model(tmp_path / "again.npz", m)
    a, b = _arrays(model_file), _arrays(again)
    assert a.keys() - b.keys() == {"meta_canny_low", "meta_canny_high", "meta_source"}
    for k in b:
        assert np.array_equal(a[k], b[k]), k
    assert load_meta(model_file) == {"canny_low": 50.0, "canny_high": 150.0, "source": "blobs"}
    # the G-flow user model shares the file format, with kind "morphable"
    head = EllipsoidHead().model()
    p = save_model(tmp_path / "head.npz", head)
    back = load_model(p)
    assert str(_arrays(p)["kind"]) == "morphable"
    assert np.array_equal(back.bases, head.bases) and np.array_equal(back.triangles, head.triangles)
    with pytest.raises(TypeError, match="cannot save a dict"):
        save_model(tmp_path / "x.npz", {"a": 1})


@pytest.mark.parametrize("damage, message", [
    ("truncated", "corrupt or truncated"),
    ("flipped", "corrupt or truncated"),
    ("empty", "empty file"),
    ("text", "not a zip archive"),
    ("pickled", "pickled"),
    ("no_kind", "no 'kind' entry"),
    ("other_kind", "unknown model kind 'hmm'"),
    ("version", f"format version {FORMAT_VERSION + 1} is not supported"),
    ("nan_sigma", "sigma contains NaN"),
    ("missing_array", "missing the array"),
])
def test_bad_model_file(model_file, tmp_path, capsys, damage, message) -> None:
    raw = model_file.read_bytes()
    bad = tmp_path / f"{damage}.npz"
    arrays = _arrays(model_file)
    if damage == "truncated":
        bad.write_bytes(raw[: len(raw) * 2 // 3])
    elif damage == "flipped":
        # corrupt a byte inside the first member's data: its CRC no longer matches
        with zipfile.ZipFile(model_file) as z:
            info = z.infolist()[0]
        at = info.header_offset + 30 + len(info.filename) + info.compress_size // 2
        b = bytearray(raw)
        b[at] ^= 0xFF
        bad.write_bytes(bytes(b))
    elif damage == "empty":
        bad.write_bytes(b"")
    elif damage == "text":
        bad.write_text("this is not a model\n")
    else:
        if damage == "pickled":
            arrays["d"] = np.array([{"x": 1}, 2, 3], dtype=object)
        elif damage == "no_kind":
            del arrays["kind"]
        elif damage == "other_kind":
            arrays["kind"] = np.array("hmm")
        elif damage == "version":
            arrays["format_version"] = np.array(FORMAT_VERSION + 1)
        elif damage == "nan_sigma":
            arrays["sigma"] = np.full_like(arrays["sigma"], np.nan)
        elif damage == "missing_array":
            del arrays["markov"]
        with open(bad, "wb") as f:
            np.savez(f, **arrays)
    with pytest.raises(ValueError, match=message) as e:
        load_model(bad)
    assert str(bad) in str(e.value)
    # the commands say the same, naming the file, and exit with status 2
    _fails(capsys, ["info", str(bad)], str(bad), message)
    _fails(capsys, ["track", str(tmp_path), "--tracker", "m2", "--model", str(bad), "--init", "1,1,5,5",
                    "--out", str(tmp_path / "o.csv"), "--inline", "-q"], str(bad), message)


def test_model_file_misuse(model_file, tmp_path, capsys) -> None:
    folder = write_folder(tmp_path / "f", blob_frames(3))
    _fails(capsys, ["track", str(folder), "--tracker", "m2", "--init", "1,1,5,5", "--out", str(tmp_path / "o.csv")],
           "--tracker m2 needs --model")
    _fails(capsys, ["track", str(folder), "--tracker", "m2", "--model", str(tmp_path / "nope.npz"), "--init",
                    "1,1,5,5", "--out", str(tmp_path / "o.csv")], "model file not found")
    head = save_model(tmp_path / "head.npz", EllipsoidHead().model())
    _fails(capsys, ["track", str(folder), "--tracker", "m2", "--model", str(head), "--init", "1,1,5,5",
                    "--out", str(tmp_path / "o.csv")], "MorphableModel, not an M2 model")


def test_learn_bad_training_input(tmp_path, capsys) -> None:
    out = str(tmp_path / "m.npz")
    # a static scene: background subtraction finds no foreground
    still = write_folder(tmp_path / "still", [blob_frames(1)[0]] * 6)
    _fails(capsys, ["learn", "m2", str(still), "-K", "2", "--out", out, "-q"], "no foreground found")
    moving = write_folder(tmp_path / "moving", blob_frames(8))
    _fails(capsys, ["learn", "m2", str(moving), "--frames", "3:4", "-K", "1", "--out", out, "-q"],
           "a single training frame")
    _fails(capsys, ["learn", "m2", str(moving), "-K", "12", "--out", out, "-q"], "-K 12 exemplars but only 8")
    _fails(capsys, ["learn", "m2", str(moving), "-K", "8", "--out", out, "-q"], "-K 8 exemplars but only 8")
    _fails(capsys, ["learn", "m2", str(tmp_path / "nothing"), "--out", out, "-q"], "training source not found")
    _fails(capsys, ["learn", "m2", str(moving), "--boxes", str(tmp_path / "gt.csv"), "--out", out, "-q"],
           "box file not found")
    _fails(capsys, ["learn", "m2", str(moving), "--frames", "5:2", "--out", out, "-q"], "0 <= A < B")
    _fails(capsys, ["learn", "m2", str(moving), "--frames", "20:30", "--out", out, "-q"], "no decodable frame")
    _fails(capsys, ["learn", "m2", str(moving), "--metric", "shuffle", "--patch-size", "big", "--out", out, "-q"],
           "WxH")
    _fails(capsys, ["learn", "m2", str(moving), "--reps", "1", "--out", out, "-q"], "AVLetters")
    (tmp_path / "gt.csv").write_text("frame,x,y,w,h\n100,1,1,5,5\n")
    _fails(capsys, ["learn", "m2", str(moving), "--boxes", str(tmp_path / "gt.csv"), "--out", out, "-q"],
           "no box for any of the training frames")
    assert not Path(out).exists()
    # the same folder learns fine with a sensible K, and the model file holds what was learned
    assert main(["learn", "m2", str(moving), "-K", "3", "--out", out, "-q"]) == 0
    assert load_model(out).K == 3 and load_meta(out)["training"] == "background"
