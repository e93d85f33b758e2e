"""``gflow trax`` / ``python -m gflow.trax``: a real server process driven by the TraX client library
(vot-trax, as the VOT toolkit drives it) gives the Python API's boxes for the same seed, answers a
request it cannot serve with TraX's error, and passes the toolkit's own ``vot test`` where the
toolkit is installed."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

import cv2
import numpy as np
import pytest

from gflow import Tracker
from gflow_core.synthetic import SyntheticScene
from pipeline.recording.results import read_track

trax = pytest.importorskip("trax", reason="the TraX library is not installed (pip install -e '.[test]' has it)")
from trax import Polygon, Rectangle, TraxException  # noqa: E402
from trax.client import Client  # noqa: E402
from trax.image import BufferImage, FileImage, MemoryImage  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
#: TraX writes numbers with 4 decimals; a C float of a box (< 1000 px) is within 6e-5 px of it
WIRE = 2e-4


class Session:
    """A server process and the client talking to it over its stdin / stdout."""

    def __init__(self, cmd: list[str], proc: subprocess.Popen | None = None):
        self.proc = proc if proc is not None else _spawn(cmd)
        self.log: list[str] = []  # kept alive as long as the client: the library calls it at cleanup
        self.client = Client((self.proc.stdin.fileno(), self.proc.stdout.fileno()), log=self.log.append)

    def initialize(self, image, region) -> tuple[tuple[float, ...], dict]:
        (reg, props), = self.client.initialize({"color": image}, [(region, {})], {})[0]
        return reg.bounds(), props

    def frame(self, image) -> tuple[tuple[float, ...], dict]:
        (reg, props), = self.client.frame({"color": image}, {}, [])[0]
        return reg.bounds(), props

    def end(self) -> tuple[int, str]:
        """Quit (the library crashes if a client with a live session is collected) and wait."""
        self.client.quit()
        self.proc.stdin.close()
        code = self.proc.wait(timeout=60)
        err = self.proc.stderr.read().decode()
        self.proc.stdout.close()
        self.proc.stderr.close()
        return code, err


def _spawn(cmd: list[str]) -> subprocess.Popen:
    """A server process, its stdin / stdout the TraX channel (the client's handshake comes later)."""
    return subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, bufsize=0,
                            cwd=ROOT)


@contextmanager
def session(*args: str, via_gflow: bool = False, proc: subprocess.Popen | None = None) -> Iterator[Session]:
    """A session with a new server (or with ``proc``, a server started by :func:`_spawn` with ``args``)."""
    cmd = [sys.executable, "-m", "pipeline.cli", "trax"] if via_gflow else [sys.executable, "-m", "gflow.trax"]
    s = Session(cmd + list(args), proc)
    try:
        yield s
    finally:
        if s.proc.poll() is None or not s.proc.stdin.closed:
            s.end()


def rgb(frame: np.ndarray):
    return MemoryImage.create(cv2.cvtColor(frame, cv2.COLOR_BGR2RGB))


def assert_served(got: tuple[tuple[float, ...], dict], est) -> None:
    box, props = got
    assert np.abs(np.subtract(box, est.box)).max() < WIRE, (box, est.box)
    assert float(props["confidence"]) == est.confidence  # the property carries the float exactly
    assert (props["state"], props["phase"]) == (est.target_state, est.phase)


def test_trax_serves_the_apis_boxes_through_a_reinitialisation(tmp_path):
    """Start, initialise, 30 frames, re-initialise (a polygon: its bounding box), 5 more, quit: every
    answer is the API's estimate with the same seed, whatever form the image comes in."""
    scene = SyntheticScene()
    frames = [scene.render(t) for t in range(37)]
    paths = []
    for t, f in enumerate(frames):
        paths.append(tmp_path / f"{t:06d}.png")
        cv2.imwrite(str(paths[-1]), f)
    out = tmp_path / "served.csv"
    # boxes with the 2 decimals of a ground-truth file (TraX carries 4)
    box0, box31 = (tuple(round(v, 2) for v in scene.truth_box(t)) for t in (0, 31))
    # the API: one track over frames 0..30, a new one from frame 31 (its frames count from 0 again)
    first = Tracker(seed=3)  # the default tracker, as the server's without --tracker
    want = [first.init(frames[0], box0)] + [first.update(f) for f in frames[1:31]]
    second = Tracker(seed=3)
    want += [second.init(frames[31], box31)] + [second.update(f) for f in frames[32:]]

    with session("--seed", "3", "--out", str(out), via_gflow=True) as s:
        assert s.client.tracker_name == f"gflow-{first.name}"
        assert s.client.region_formats == ["rectangle", "polygon"]
        got = [s.initialize(FileImage.create(str(paths[0])), Rectangle.create(*box0))]
        for t in range(1, 31):  # a path, an RGB array, an encoded buffer: the same pixels
            image = (FileImage.create(str(paths[t])), rgb(frames[t]),
                     BufferImage.create(cv2.imencode(".png", frames[t])[1].tobytes()))[t % 3]
            got.append(s.frame(image))
        x, y, w, h = box31
        x2, y2 = round(x + w, 2), round(y + h, 2)
        got.append(s.initialize(rgb(frames[31]), Polygon.create([(x, y), (x2, y + 5), (x + 10, y2), (x, y2 - 5)])))
        got += [s.frame(FileImage.create(str(p))) for p in paths[32:]]
        code, err = s.end()
    assert (code, err) == (0, "")
    assert len(got) == len(want) == 37
    for g, e in zip(got, want):
        assert_served(g, e)
    # --out: the boxes served, as gflow track writes them, a row per image of the session
    rows = read_track(out)
    assert sorted(rows.boxes) == list(range(37))
    for k, e in enumerate(want):
        assert rows.boxes[k] == tuple(float(f"{v:.2f}") for v in e.box)
        assert rows.states is not None and rows.states[k] == e.target_state


@pytest.mark.data
def test_trax_boxes_are_gflow_track_inline_byte_for_byte(caviar1, tmp_path):
    """On real frames: the server's --out file and gflow track --inline's --out file are the same bytes,
    and what crossed the wire is within TraX's 4 decimals of it."""
    files = sorted((caviar1 / "frames").iterdir())[:40]
    init = "129,71,30,79"  # caviar1's frame-0 ground truth
    # gflow track runs while the server is driven (two processes side by side), then both files are compared
    track = subprocess.Popen([sys.executable, "-m", "pipeline.cli", "track", str(caviar1), "--init", init, "--stop", "40",
                              "--inline", "--seed", "5", "--no-record", "-q", "--out", str(tmp_path / "track.csv")],
                             stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT)
    try:
        with session("--seed", "5", "--out", str(tmp_path / "trax.csv")) as s:
            got = [s.initialize(FileImage.create(str(files[0])), Rectangle.create(129, 71, 30, 79))]
            got += [s.frame(FileImage.create(str(f))) for f in files[1:]]
            assert s.end()[0] == 0
        _, err = track.communicate(timeout=300)
    finally:
        if track.poll() is None:
            track.kill()
            track.wait()
    assert track.returncode == 0, err
    assert (tmp_path / "trax.csv").read_bytes() == (tmp_path / "track.csv").read_bytes()
    rows = read_track(tmp_path / "track.csv")
    assert len(got) == len(rows.boxes) == 40
    for k, (box, _) in enumerate(got):
        assert np.abs(np.subtract(box, rows.boxes[k])).max() <= 0.005 + WIRE  # the CSV has 2 decimals


def _refused(tmp_path, requests, *args: str, proc: subprocess.Popen | None = None) -> tuple[str, int, str]:
    """Send requests until the server refuses one: (the client's exception, exit code, stderr)."""
    with session(*args, proc=proc) as s:
        with pytest.raises(TraxException) as e:
            for kind, image, region in requests:
                s.initialize(image, region) if kind == "initialize" else s.frame(image)
        code, err = s.end()
    return str(e.value), code, err


def test_a_request_the_server_cannot_serve_gets_a_trax_error(tmp_path):
    """A missing image, an undecodable one, a region without area, a box off the image, a frame before
    any initialize: the client gets TraX's error naming the mistake, the server exits 1 with one line."""
    frame = SyntheticScene().render(0)
    good = tmp_path / "good.png"
    cv2.imwrite(str(good), frame)
    (tmp_path / "text.jpg").write_text("not an image")
    box = Rectangle.create(100, 80, 60, 60)
    cases = [
        ([("initialize", FileImage.create(str(tmp_path / "missing.jpg")), box)], "cannot read image"),
        ([("initialize", FileImage.create(str(good)), box), ("frame", FileImage.create(str(tmp_path / "text.jpg")), None)],
         "is not a decodable image"),
        ([("initialize", FileImage.create(str(good)), Polygon.create([(10, 10), (50, 10), (90, 10)]))],
         "region has no area"),
        ([("initialize", FileImage.create(str(good)), Rectangle.create(900, 900, 20, 20))], "init"),
        ([("frame", FileImage.create(str(good)), None)], "a frame before any initialize"),
        ([("initialize", FileImage.create(str(good)), box), ("frame", rgb(frame[:100, :100]), None)], "size changed"),
    ]
    # one server per case, all started at once (each loads the tracker before its handshake), then each driven
    servers = [_spawn([sys.executable, "-m", "gflow.trax"]) for _ in cases]
    try:
        answers = [_refused(tmp_path, requests, proc=server) for (requests, _), server in zip(cases, servers)]
    finally:
        for server in servers:
            if server.poll() is None:
                server.kill()
                server.wait()
    for (requests, says), (told, code, err) in zip(cases, answers):
        if requests[0][0] == "initialize":  # (a client that never initialised reads the quit as its own error)
            assert told.startswith("Server terminated the session: ") and says in told, told
        assert code == 1
        lines = err.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("gflow trax: error: ") and says in lines[0], err


def test_regions_other_than_rectangles_and_polygons_are_refused():
    """The client library turns a mask into a polygon before sending it; a region that still arrives
    as a mask or a special code is refused in the same way."""
    from trax.region import Mask, Special

    from gflow.trax import RequestError, box_of_region

    assert box_of_region(Polygon.create([(1, 2), (5, 1), (9, 7)])) == (1.0, 1.0, 8.0, 6.0)
    assert box_of_region(Rectangle.create(147.99, 113.07, 33.02, 32.02)) == (147.99, 113.07, 33.02, 32.02)
    for region in (Mask.create(np.ones((3, 4), np.uint8), 2, 3), Special.create(0)):
        with pytest.raises(RequestError, match="this tracker takes a rectangle or a polygon"):
            box_of_region(region)


def test_a_uniform_first_image_waits_for_a_usable_one_as_gflow_track_does(tmp_path):
    """The API cannot start on a uniform frame; the server answers with the given box (confidence 0)
    and starts the track, from that box, on the next usable image (frame index 1, as gflow track)."""
    scene = SyntheticScene()
    frames = [np.full_like(scene.render(0), 128), scene.render(1), scene.render(2)]
    box0 = tuple(round(v, 2) for v in scene.truth_box(0))
    t = Tracker("appearance", seed=2)
    want = [t.init(frames[1], box0, frame_index=1), t.update(frames[2])]
    with session("--seed", "2", "--tracker", "appearance") as s:
        box, props = s.initialize(rgb(frames[0]), Rectangle.create(*box0))
        assert np.abs(np.subtract(box, box0)).max() < WIRE
        assert (props["confidence"], props["state"], props["phase"]) == ("0", "lost", "waiting")
        for f, e in zip(frames[1:], want):
            assert_served(s.frame(rgb(f)), e)
        assert s.end()[0] == 0


def test_bad_options_and_a_missing_library_are_one_line_errors(tmp_path):
    """A mistyped parameter or a missing model fails before the handshake; without vot-trax both
    commands say how to install it."""
    wrong = (
        ([sys.executable, "-m", "gflow.trax", "--set", "partcles=500"], "partcles"),
        ([sys.executable, "-m", "gflow.trax", "--tracker", "m2"], "needs --model"),
        ([sys.executable, "-m", "pipeline.cli", "trax", "--tracker", "chamfer", "--model", "x.npz"],
         "--model is an option of --tracker gflow / m2"),
        ([sys.executable, "-m", "pipeline.cli", "trax", "--set", "particles"], "--set expects NAME=VALUE"),
        # the default tracker's refusals listed its hundred and ten parameters on the one line
        ([sys.executable, "-m", "pipeline.cli", "trax", "--model", "x.npz"],
         "--model is an option of --tracker gflow / m2, not of --tracker dcf"),
        ([sys.executable, "-m", "pipeline.cli", "trax", "--set", "partcles=500"],
         "--set partcles=500: DCFParams has no parameter 'partcles' (did you mean 'particles'?"),
    )
    hide = "import sys; sys.modules['trax'] = None; "
    missing = [[sys.executable, "-c", hide + "from pipeline.cli.main import main; sys.exit(main(['trax']))"],
               [sys.executable, "-c", hide + "from gflow.trax import main; sys.exit(main([]))"]]
    # the eight commands side by side (each is a Python start-up and an import of gflow), then each checked
    done = _run_together([cmd for cmd, _ in wrong] + missing)
    for (cmd, says), r in zip(wrong, done):
        assert r.returncode == 2 and r.stdout == "", (cmd, r)
        lines = r.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("gflow trax: error: ") and says in lines[0], r.stderr
    for r in done[len(wrong):]:
        assert r.returncode == 2 and r.stdout == ""
        assert r.stderr.strip() == ("gflow trax: error: the TraX library (package vot-trax) is not installed: "
                                    "pip install 'gflow[vot]' (or pip install vot-trax)")


def _run_together(cmds: list[list[str]]) -> list[subprocess.CompletedProcess]:
    """Run the commands at once (stdin empty, in the repository) and wait for them all: what each gave."""
    procs = [subprocess.Popen(c, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                              cwd=ROOT) for c in cmds]
    try:
        outs = [p.communicate(timeout=120) for p in procs]
        return [subprocess.CompletedProcess(c, p.returncode, *out) for c, p, out in zip(cmds, procs, outs)]
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.wait()


def test_vot_test_passes_for_the_default_tracker(tmp_path):
    """The toolkit's own check of a tracker integration (a generated sequence, initialise, every
    frame, stop), with the trackers.ini that gflow export vot writes."""
    vot = shutil.which("vot")
    if vot is None:
        pytest.skip("vot-toolkit is not installed here (no `vot` command on PATH): install it in an environment of "
                    "its own (docs/vot.md; it brings opencv-python) and put its bin folder on PATH")
    from pipeline.io.vot_workspace import trackers_ini

    (tmp_path / "trackers.ini").write_text(trackers_ini(sys.executable, {"dcf": ["--tracker", "dcf"]}))
    r = subprocess.run([vot, "test", "gflow-dcf"], capture_output=True, text=True, timeout=300, cwd=tmp_path,
                       stdin=subprocess.DEVNULL, env=dict(os.environ, PYTHONPATH=str(ROOT)))
    out = r.stdout + r.stderr
    assert r.returncode == 0 and "Test concluded successfuly" in out, out[-3000:]  # the toolkit's spelling
    assert "@@TRAX:state" in out and "@@TRAX:quit" in out
