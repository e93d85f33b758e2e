"""Damaged or malformed input files other than pictures, videos and recordings: model files, box and points CSVs,
landmark files, graph, security and router files. Each is refused in one line on stderr naming the file and what
is wrong, a non-zero exit, no traceback and no "internal error", before any work that it could be checked before.

Every case runs the CLI in a process of its own (``tests/cli_fork.py``) on small files written into tmp_path.
"""

from __future__ import annotations

import subprocess
from pathlib import Path

import numpy as np
import pytest

from test_cli_errors import assert_one_line_error, frames, gflow, one_sequence  # noqa: F401  (frames: a fixture)

#: bytes that are not UTF-8 text: a picture's or a recording's, given for a text file
NOT_TEXT = bytes(range(256))


@pytest.mark.parametrize("argv, what", [
    (["run", "bad.txt", "--inline"], "not a graph file"),
    (["run", "demo", "--inline", "--security", "bad.txt"], "not a security file"),
    (["run", "demo", "--inline", "--user", "u", "--password-file", "bad.txt"], "not a password file"),
    (["router", "bad.txt", "--print-config"], "not a router config"),
    (["router", "--listen", "tcp/127.0.0.1:0", "--users-file", "bad.txt", "--print-config"], "not a users file"),
])
def test_a_text_file_that_is_not_text_is_named(tmp_path: Path, argv: list[str], what: str) -> None:
    """A file of bytes given for a graph, a security file, a password file or a router's files: the decoder's
    words alone ("'utf-8' codec can't decode byte 0x80...") named no file."""
    (tmp_path / "bad.txt").write_bytes(NOT_TEXT)
    assert_one_line_error(gflow(*argv, cwd=tmp_path), "bad.txt", what, "byte 0x80 at offset 128")


def test_a_security_file_through_which_a_password_file_that_is_not_text_is_named(tmp_path: Path) -> None:
    (tmp_path / "pw.bin").write_bytes(NOT_TEXT)
    (tmp_path / "security.yaml").write_text("user: u\npassword_file: pw.bin\n")
    r = gflow("run", "demo", "--inline", "--security", "security.yaml", cwd=tmp_path)
    assert_one_line_error(r, "pw.bin", "not a password file")


#: a graph of one source stage, whose lines the cases below change one at a time
GRAPH = "name: g\nstream: s\nstages:\n  source:\n    kind: source\n    params: {kind: synthetic, frames: 2}\n"


@pytest.mark.parametrize("old, new, said", [
    ("kind: source", "kind: [source]", ":5: stage 'source': unknown stage kind ['source']"),
    ("kind: source", "kind: {a: 1}", ":5: stage 'source': unknown stage kind {'a': 1}"),
    ("params: {kind: synthetic, frames: 2}", "params: [1, 2]", ":6: stage 'source': params must be a mapping"),
    ("params: {kind: synthetic, frames: 2}", "params: 5", ":6: stage 'source': params must be a mapping"),
    ("name: g", "name: [g]", ":1: name must be a word or a number, got ['g']"),
    ("stream: s", "stream: {a: 1}", ":2: stream must be a word or a number"),
    ("frames: 2}", "frames: 2}\n    qos: 5", ":7: stage 'source': qos must be a mapping port -> reliable or drop"),
    ("frames: 2}", "frames: 2}\n    max_restarts: x", ":7: stage 'source': max_restarts must be a whole number >= 0"),
    ("frames: 2}", "frames: 2}\n    outputs: {frames: [f]}", ":7: stage 'source': 'frames': ['f']: a port and its "
                                                             "topic are names"),
    ("frames: 2}", "frames: 2}\n    outputs: {[frames]: f}", ": line 7: a key must be a name, got ['frames']"),
])
def test_a_graph_value_of_the_wrong_type_is_named_by_its_line(tmp_path: Path, old: str, new: str, said: str) -> None:
    """A list or a mapping where a graph has a name: "internal error: TypeError: unhashable type: 'list'" for a
    stage's kind or a port, another for its params or its qos; a list for the graph's name named the run "['g']",
    for a topic the topic "gflow/s/['f']"; a max_restarts of text failed naming no file."""
    (tmp_path / "g.yaml").write_text(GRAPH.replace(old, new))
    assert_one_line_error(gflow("run", "g.yaml", "--inline", "--no-record", cwd=tmp_path), "g.yaml" + said)


@pytest.fixture(scope="module")
def m2_model(tmp_path_factory) -> tuple[Path, Path]:
    """An M2 contour model learned on 16 frames of a walking ellipse, and the folder of those frames."""
    from test_m2_errors import blob_frames, write_folder

    from gflow_core.m2 import training
    from gflow_core.m2.learn import learn
    from pipeline.io.modelfile import save_model

    where = tmp_path_factory.mktemp("m2")
    ts = training.curves_from_background(blob_frames(16), max_points=60)
    model = save_model(where / "m.npz", learn(ts, "chamfer", K=3), meta={"canny_low": 50.0, "canny_high": 150.0})
    return model, write_folder(where / "frames", blob_frames(4))


def _changed(model: Path, dest: Path, **arrays) -> Path:
    """``model`` written to ``dest`` with ``arrays`` in place of its own (None: left out)."""
    with np.load(model, allow_pickle=False) as z:
        a = {k: z[k] for k in z.files}
    a.update({k: v for k, v in arrays.items() if v is not None})
    for k in [k for k, v in arrays.items() if v is None]:
        del a[k]
    with open(dest, "wb") as f:
        np.savez(f, **a)
    return dest


def _track_m2(model: Path, frames_dir: Path, cwd: Path) -> subprocess.CompletedProcess:
    return gflow("track", str(frames_dir), "--tracker", "m2", "--model", str(model), "--init", "10,25,20,40",
                 "--out", "o.csv", "--inline", "-q", "--no-record", cwd=cwd)


@pytest.mark.parametrize("meta, said", [
    ({"meta_canny_low": np.array([50.0])}, "canny_low must be a number >= 0 (as gflow learn m2 writes it), got [50.0]"),
    ({"meta_canny_low": np.array(50 + 0j)}, "canny_low must be a number >= 0"),
    ({"meta_canny_high": np.array("x")}, "canny_high must be a number >= 0 (as gflow learn m2 writes it), got 'x'"),
    ({"meta_canny_high": np.array(np.nan)}, "canny_high must be a number >= 0"),
    ({"meta_canny_low": np.array(-1.0)}, "canny_low must be a number >= 0"),
    ({"meta_canny_low": np.array(200.0)}, "canny_low 200 above canny_high 150"),
    ({"meta_canny_high": None}, "canny_low without canny_high"),
    ({"meta_blur": np.array(np.inf)}, "blur must be a number >= 0"),
])
def test_an_m2_models_edge_settings_are_checked_before_tracking(tmp_path: Path, m2_model: tuple[Path, Path],
                                                                  meta: dict, said: str) -> None:
    """The Canny thresholds and blur an M2 model file keeps: a list or a complex number there was "internal error:
    TypeError", text an error naming no file, NaN or a negative number a run that found no edge on any frame."""
    bad = _changed(m2_model[0], tmp_path / "bad.npz", **meta)
    assert_one_line_error(_track_m2(bad, m2_model[1], tmp_path), "bad.npz: the model's metadata", said)
    assert not (tmp_path / "o.csv").exists()


def test_an_m2_model_whose_dynamics_diverge_is_refused_before_tracking(tmp_path: Path,
                                                                        m2_model: tuple[Path, Path]) -> None:
    """An AR(1) matrix with an eigenvalue above 1 (no learned one has): the run spent minutes on each frame, its
    particles run off to boxes of every size."""
    A = -np.ones((4, 4)) - np.eye(4)
    bad = _changed(m2_model[0], tmp_path / "bad.npz", ar_A=A)
    r = _track_m2(bad, m2_model[1], tmp_path)
    assert_one_line_error(r, "bad.npz: M2 model dynamics: ar_A has an eigenvalue of modulus 5 > 1")
    assert_one_line_error(gflow("info", str(bad), cwd=tmp_path), "bad.npz", "would diverge")


@pytest.mark.parametrize("argv", [
    ["eval", "--gt", "data/s/groundtruth.csv", "--pred", "good.csv"],
    ["eval", "--gt", "good.csv", "--pred", "data/s/groundtruth.csv"],
    ["export", "vot", "data/s", "out"],
    ["learn", "m2", "data/s/frames", "--boxes", "data/s/groundtruth.csv", "--metric", "l2", "-K", "2", "--out",
     "m.npz"],
])
def test_a_box_beyond_any_image_is_refused_by_its_line(tmp_path: Path, frames: Path, argv: list[str]) -> None:
    """A box of 1e308 px: eval printed overflow warnings and a score, export vot wrote it, learn m2 said "internal
    error: OverflowError"."""
    seq = one_sequence(tmp_path, frames)
    (tmp_path / "good.csv").write_text((seq / "groundtruth.csv").read_text())
    (seq / "groundtruth.csv").write_text("frame,x,y,w,h\n0,10,10,1e308,1e308\n1,10,10,20,20\n")
    assert_one_line_error(gflow(*argv, cwd=tmp_path), "groundtruth.csv:2: box value 1e+308 is beyond any image")
    assert not (tmp_path / "out").exists() and not (tmp_path / "m.npz").exists()


def _npz_damage(good: bytes, damage: str) -> bytes:
    """``good`` (an .npz archive's bytes) damaged: cut short, emptied, or a single .npy array or text in its place."""
    if damage == "truncated":
        return good[: len(good) - 30]
    if damage == "npy":
        import io

        b = io.BytesIO()
        np.save(b, np.zeros((2, 468, 3)))
        return b.getvalue()
    return {"empty": b"", "text": b"frame,landmark,x,y\n"}[damage]


@pytest.mark.parametrize("damage, said", [
    ("truncated", "not a readable {} (corrupt or truncated npz"), ("npy", "it is a single .npy array"),
    ("empty", "it is an empty file"), ("text", "it is not a zip archive"),
])
@pytest.mark.parametrize("argv, what", [
    (["eval", "--landmarks", "bad.npz", "--points", "p.csv"], "landmark file"),
    (["learn", "gflow", "bad.npz", "--out", "m.npz"], "landmark file"),
    (["learn", "m2", "bad.npz", "--metric", "l2", "-K", "2", "--out", "m.npz"], "AVLetters file"),
])
def test_a_damaged_landmark_or_letters_file_says_what_it_is(tmp_path: Path, damage: str, said: str, argv: list[str],
                                                            what: str) -> None:
    """A landmark file cut short was called "not a zip archive", a single .npy array too; an AVLetters file that is
    text was said to hold pickled data "if you trust the file...", and a .npy array given for one was "internal
    error: TypeError"."""
    buf = tmp_path / "good.npz"
    np.savez(buf, landmarks=np.zeros((2, 468, 3)))
    (tmp_path / "bad.npz").write_bytes(_npz_damage(buf.read_bytes(), damage))
    (tmp_path / "p.csv").write_text("frame,landmark,x,y\n0,33,1,1\n")
    line = assert_one_line_error(gflow(*argv, cwd=tmp_path), "bad.npz: ", said.format(what))
    assert what in line and "pickle" not in line
    assert not (tmp_path / "m.npz").exists()


def test_whatever_the_damage_a_model_or_landmark_file_reads_or_says_why(tmp_path: Path,
                                                                         m2_model: tuple[Path, Path]) -> None:
    """Bytes of a model file and of a landmark file (stored, or compressed as np.savez_compressed writes it)
    flipped anywhere, the file perhaps cut: reading it gives the model, or a ValueError or an OSError naming the
    file, never another exception (a damaged header's NotImplementedError or "encrypted" RuntimeError, a damaged
    compressed member's zlib.error: "internal error" on the command line)."""
    from hypothesis import HealthCheck, given, settings
    from hypothesis import strategies as st

    from pipeline.io.landmarks import read_landmarks
    from pipeline.io.modelfile import load_model

    np.savez(tmp_path / "lm.npz", landmarks=np.zeros((2, 5, 3)))
    np.savez_compressed(tmp_path / "lmz.npz", landmarks=np.zeros((2, 5, 3)))
    files = [(m2_model[0].read_bytes(), load_model), ((tmp_path / "lm.npz").read_bytes(), read_landmarks),
             ((tmp_path / "lmz.npz").read_bytes(), read_landmarks)]

    @settings(max_examples=60, deadline=None, derandomize=True,
              suppress_health_check=[HealthCheck.function_scoped_fixture])
    @given(which=st.integers(0, 2), at=st.floats(0, 1), n=st.integers(1, 16), xor=st.integers(1, 255),
           cut=st.one_of(st.none(), st.floats(0, 1)))
    def damaged(which: int, at: float, n: int, xor: int, cut: float | None) -> None:
        data, read = files[which]
        d = bytearray(data)
        start = int(at * (len(d) - 1))
        for i in range(start, min(start + n, len(d))):
            d[i] ^= xor
        bad = tmp_path / "bad.npz"
        bad.write_bytes(bytes(d[: None if cut is None else int(cut * len(d))]))
        try:
            read(bad)
        except (ValueError, OSError) as e:
            assert str(bad) in str(e), e

    damaged()


@pytest.mark.parametrize("row, said", [("-1,33,5,5", ":3: frame -1: frame and landmark numbers start at 0"),
                                       ("0,-33,5,5", ":3: landmark -33: frame and landmark numbers start at 0")])
def test_a_points_row_of_a_negative_frame_or_landmark_is_refused_by_its_line(tmp_path: Path, row: str,
                                                                           said: str) -> None:
    """A box file's negative frame was refused, a points file's was left out of the score without a word."""
    np.savez(tmp_path / "ref.npz", landmarks=np.zeros((1, 468, 3)))
    good = "".join(f"0,{lm},0,0\n" for lm in (33, 133, 362, 263, 61, 291))
    first, rest = good.split("\n", 1)
    (tmp_path / "p.csv").write_text(f"frame,landmark,x,y\n{first}\n{row}\n{rest}")
    assert_one_line_error(gflow("eval", "--landmarks", "ref.npz", "--points", "p.csv", cwd=tmp_path), "p.csv" + said)


def test_landmarks_whose_eye_corners_coincide_are_one_line(tmp_path: Path) -> None:
    """Eye corners 33 and 263 at one place in every frame (a landmark file of another layout, say): numpy's
    "RuntimeWarning: invalid value encountered in divide" and its source line came before the error."""
    lm = np.random.default_rng(0).normal(0, 50, (5, 468, 3)) + 200
    lm[:, 263] = lm[:, 33]
    np.savez(tmp_path / "lm.npz", landmarks=lm)
    r = gflow("learn", "gflow", "lm.npz", "--out", "m.npz", "-k", "2", "--vertices", "20", "-q", cwd=tmp_path)
    assert_one_line_error(r, "the eye corners 33 and 263 coincide")
    assert not (tmp_path / "m.npz").exists()


FACE = Path(__file__).resolve().parent.parent / "pipeline" / "models" / "face.npz"


@pytest.mark.parametrize("opt, which, said", [
    ("--gflow-model", "m2", "holds a model of kind 'm2'; --tracker gflow needs one of kind 'morphable'"),
    ("--m2-model", "face", "holds a model of kind 'morphable'; --tracker m2 needs one of kind 'm2'"),
])
def test_export_vot_refuses_a_model_of_the_other_tracker(tmp_path: Path, frames: Path, m2_model: tuple[Path, Path],
                                                         opt: str, which: str, said: str) -> None:
    """An M2 model given to gflow, or the face model to m2, was written into trackers.ini without a word, and found
    only when the VOT toolkit ran the tracker."""
    one_sequence(tmp_path, frames)
    model = m2_model[0] if which == "m2" else FACE
    r = gflow("export", "vot", "data/s", "out", opt, str(model), cwd=tmp_path)
    assert_one_line_error(r, f"{opt}: {model} {said}")
    assert not (tmp_path / "out").exists()


def test_trax_names_the_model_file_whose_edge_settings_it_refuses(tmp_path: Path,
                                                                   m2_model: tuple[Path, Path]) -> None:
    bad = _changed(m2_model[0], tmp_path / "bad.npz", meta_canny_low=np.array("x"))
    r = gflow("trax", "--tracker", "m2", "--model", str(bad), cwd=tmp_path, input="")
    assert_one_line_error(r, f"{bad}: the model's metadata canny_low must be a number >= 0")


@pytest.mark.parametrize("where, said", [
    ("tracker: {name: appearance, params: {std_log_s: .nan}}", "g.yaml:14: tracker appearance: std_log_s must be a "
                                                               "number, got nan"),
    ("tracker: {name: appearance, params: {scale_step: .nan}}", "scale_step must be a number, got nan"),
])
def test_a_graph_parameter_of_nan_is_refused_by_its_line(tmp_path: Path, frames: Path, where: str, said: str) -> None:
    """``.nan`` where a tracker's own checks do not look: the run failed every frame ("stage_exception: frame 0:
    ValueError: alpha contains NaN or inf") and exited 0."""
    graph = (Path(__file__).resolve().parent.parent / "pipeline" / "graphs" / "appearance.yaml").read_text()
    line = next(ln for ln in graph.splitlines() if ln.startswith("tracker:"))
    assert graph.splitlines().index(line) == 13
    (tmp_path / "g.yaml").write_text(graph.replace(line, where))
    r = gflow("run", "g.yaml", "--inline", "--no-record", "--set", "filter.init=[10,10,20,20]", "--set",
              "proposal.init=[10,10,20,20]", "--set", f"source.path={frames}", cwd=tmp_path)
    assert_one_line_error(r, said)


@pytest.mark.parametrize("argv, said", [
    (["eval", "--landmarks", "huge.npz", "--points", "p.csv"], "huge.npz: 'landmarks' has values beyond any image"),
    (["learn", "gflow", "huge.npz", "--out", "m.npz"], "huge.npz: 'landmarks' has values beyond any image"),
    (["eval", "--landmarks", "ref.npz", "--points", "huge.csv"], "huge.csv:2: point 1e+308 is beyond any image"),
])
def test_landmarks_or_points_beyond_any_image_are_refused(tmp_path: Path, argv: list[str], said: str) -> None:
    """Landmarks of 1e300 px: numpy's overflow warnings, then "has no frame with the scored landmarks" (eval) or
    "SVD did not converge" (learn gflow), neither naming the file; points of 1e308 px: "no frame has both reference
    landmarks and tracked points; are the frame numbers aligned?", as though the frames were at fault."""
    ref = np.random.default_rng(0).normal(200, 30, (3, 468, 3))
    np.savez(tmp_path / "ref.npz", landmarks=ref)
    np.savez(tmp_path / "huge.npz", landmarks=ref * 1e300)
    rows = "".join(f"{f},{lm},5,5\n" for f in range(3) for lm in (33, 133, 362, 263, 61, 291))
    (tmp_path / "p.csv").write_text("frame,landmark,x,y\n" + rows)
    (tmp_path / "huge.csv").write_text("frame,landmark,x,y\n0,33,1e308,5\n" + rows[rows.index("\n") + 1:])
    assert_one_line_error(gflow(*argv, cwd=tmp_path), said)
    assert not (tmp_path / "m.npz").exists()


@pytest.mark.parametrize("array, value, said", [
    ("starts", np.arange(0, 30, 6) + 0.5, "starts must be whole numbers, got float64"),
    ("repetitions", np.array(list("11122")), "repetitions must be whole numbers, got <U1"),
    ("letters", np.arange(5), "letters must be text, got int64"),
])
def test_an_avletters_array_of_the_wrong_kind_is_named(tmp_path: Path, array: str, value: np.ndarray,
                                                       said: str) -> None:
    """Utterance starts of 0.5 were cut to whole frames without a word; repetitions written as text were read as
    numbers where they could be and failed naming no file where not ("invalid literal for int() with base 10");
    letters of numbers were taken for letters."""
    from test_cli_errors import _letters_file

    with np.load(_letters_file(tmp_path / "good.npz")) as z:
        arrays = {k: z[k] for k in z.files}
    np.savez(tmp_path / "av.npz", **{**arrays, array: value})
    r = gflow("learn", "m2", "av.npz", "--metric", "l2", "-K", "2", "--out", "m.npz", "-q", cwd=tmp_path)
    assert_one_line_error(r, "av.npz: " + said)
    assert not (tmp_path / "m.npz").exists()
