"""``gflow view`` against a real pipeline and a real WebSocket client speaking Foxglove's
published protocol (subprotocol foxglove.sdk.v1, the successor of foxglove.websocket.v1 with
the same messages): advertise -> subscribe -> binary message data."""

from __future__ import annotations

import base64
import json
import os
import struct
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytest.importorskip("foxglove", reason="gflow view needs foxglove-sdk (pip install foxglove-sdk)")
ws_client = pytest.importorskip("websockets.sync.client", reason="the test client needs the websockets package")

from pipeline.runtime.transport import free_port  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
WANT = {"/gflow/demo/image", "/gflow/demo/annotations", "/gflow/demo/estimate", "/gflow/demo/_status/filter"}


def _env(rt: Path) -> dict:
    return dict(os.environ, GFLOW_RUNTIME_DIR=str(rt),
                PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))


def _stop(p: subprocess.Popen) -> None:
    if p.poll() is None:
        p.terminate()
        try:
            p.wait(60)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait(10)


def _decode(channel: dict, payload: bytes) -> dict:
    """A message as the Foxglove app decodes it: JSON, or protobuf with the channel's schema."""
    if channel["encoding"] == "protobuf":
        from tests.foxglove_protobuf import decode_with_schema

        return decode_with_schema(channel["schemaName"], base64.b64decode(channel["schema"]), payload)
    return json.loads(payload)


def _receive(ws, want: set[str], view: subprocess.Popen, wait_s: float = 90, retry_s: float = 15) -> dict[str, dict]:
    """Subscribe to the channels whose topics end with one of ``want`` as they are advertised; the
    first message of each, decoded, by that ending."""
    got: dict[str, dict] = {}
    channels: dict[int, dict] = {}
    subs: dict[int, str] = {}
    next_sid = [1]

    def subscribe(chans: list[dict]) -> None:
        new = []
        for ch in chans:
            subs[next_sid[0]] = ch["id"]
            new.append({"id": next_sid[0], "channelId": ch["id"]})
            next_sid[0] += 1
        if new:
            ws.send(json.dumps({"op": "subscribe", "subscriptions": new}))

    with ws:
        end = time.monotonic() + wait_s
        retry = time.monotonic() + retry_s

        def wanted(topic: str) -> str | None:
            return next((w for w in want if topic.endswith(w)), None)

        while not want <= set(got):
            if time.monotonic() > end:
                _stop(view)
                raise AssertionError(f"received only {sorted(got)} (advertised "
                                     f"{sorted(c['topic'] for c in channels.values())}); gflow view said: "
                                     f"{view.stderr.read()[-2000:]}")
            if time.monotonic() > retry:  # a subscription that delivered nothing for a while: ask again
                retry = time.monotonic() + min(10, retry_s)
                again = [c for c in channels.values() if wanted(c["topic"]) not in (None, *got)]
                if again:
                    ws.send(json.dumps({"op": "unsubscribe", "subscriptionIds":
                                        [s for s, c in subs.items() if wanted(channels[c]["topic"]) not in got]}))
                    subscribe(again)
            try:
                frame = ws.recv(timeout=1.0)
            except TimeoutError:
                continue
            if isinstance(frame, str):
                op = json.loads(frame)
                if op.get("op") == "advertise":
                    for ch in op["channels"]:
                        channels[ch["id"]] = ch
                    subscribe([ch for ch in op["channels"] if wanted(ch["topic"])])
                continue
            assert frame[0] == 0x01  # message data: opcode, subscription id, receive time, payload
            sid, _ts = struct.unpack_from("<IQ", frame, 1)
            ch = channels[subs[sid]]
            w = wanted(ch["topic"])
            if w is not None:
                got.setdefault(w, {"channel": ch, "msg": _decode(ch, frame[13:]), "topic": ch["topic"]})
    return got


def _connect(port: int, view: subprocess.Popen, deadline: float):
    ws = None
    while ws is None:
        assert view.poll() is None, view.stderr.read()
        assert time.monotonic() < deadline, "gflow view did not listen"
        try:
            ws = ws_client.connect(f"ws://127.0.0.1:{port}", subprotocols=["foxglove.sdk.v1", "foxglove.websocket.v1"],
                                   open_timeout=5)
        except OSError:
            time.sleep(0.2)
    return ws


def test_foxglove_client_receives_video_overlays_and_estimates(tmp_path: Path) -> None:
    rt = tmp_path / "rt"
    run = subprocess.Popen([sys.executable, "-m", "pipeline.cli.main", "run", "demo", "--set", "source.realtime=true",
                            "--set", "source.fps=20", "--set", "source.frames=3000", "--set", "filter.particles=100",
                            "--no-record", "--listen", "tcp/127.0.0.1:0", "--stream", "demo"],
                           env=_env(rt), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    view = None
    try:
        deadline = time.monotonic() + 60
        while not (rt.is_dir() and list(rt.glob("*.json"))):
            assert time.monotonic() < deadline, "the pipeline did not announce itself"
            time.sleep(0.1)
        port = free_port()
        view = subprocess.Popen([sys.executable, "-m", "pipeline.cli.main", "view", "--port", str(port)], env=_env(rt),
                                stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        ws = _connect(port, view, deadline + 30)
        got = _receive(ws, WANT, view)
    finally:
        if view is not None:
            _stop(view)
        _stop(run)
    img = got["/gflow/demo/image"]  # foxglove-sdk's message and schema, decoded with the schema advertised
    assert img["channel"]["schemaName"] == "foxglove.CompressedImage" and img["channel"]["encoding"] == "protobuf"
    assert img["msg"]["format"] == "jpeg" and img["msg"]["data"][:2] == b"\xff\xd8"
    ann = got["/gflow/demo/annotations"]
    assert ann["channel"]["schemaName"] == "foxglove.ImageAnnotations" and ann["channel"]["encoding"] == "protobuf"
    assert ann["msg"]["points"] and len(ann["msg"]["points"][0]["points"]) >= 4
    assert ann["msg"]["texts"][0]["text"].startswith("frame ") and ann["msg"]["timestamp"] == ann["msg"]["texts"][0]["timestamp"]
    est = got["/gflow/demo/estimate"]["msg"]
    assert est["type"] == "Estimate" and len(est["box"]) == 4 and est["ess"] > 0 and est["state"] in ("track", "coast")
    st = got["/gflow/demo/_status/filter"]["msg"]
    assert st["type"] == "StageStatus" and st["stage"] == "filter"


def test_view_and_hz_started_before_a_track_run_show_it(tmp_path: Path) -> None:
    """``gflow view`` and ``gflow hz --wait`` started before ``gflow track --realtime``: they wait for
    the run, and the view shows its frames with the box drawn as image annotations (no render stage)."""
    from tests.conftest import data_dir

    seq = data_dir("caviar1")  # 382 frames: 15 s at 25 frames/s
    rt = tmp_path / "rt"
    port = free_port()
    cmd = [sys.executable, "-m", "pipeline.cli.main"]
    view = subprocess.Popen([*cmd, "view", "--port", str(port), "--duration", "300"], env=_env(rt),
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    hz = subprocess.Popen([*cmd, "hz", "frames", "--wait", "120", "--duration", "2"], env=_env(rt),
                          stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    run = None
    try:
        assert "waiting for a pipeline" in view.stderr.readline()  # nothing runs yet: it waits, it does not exit
        # hz too: a run started before hz has looked would be found at once, with no wait to show
        assert "waiting up to" in hz.stderr.readline()
        run = subprocess.Popen([*cmd, "track", str(seq), "--init", "129,71,30,79", "--out", str(tmp_path / "b.csv"),
                                "--realtime", "--fps", "25", "--no-record", "-q"], env=_env(rt),
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        ws = _connect(port, view, time.monotonic() + 120)
        got = _receive(ws, {"/frames", "/box"}, view, retry_s=3)  # a subscription the server missed: asked again
        out, err = hz.communicate(timeout=120)
        assert hz.returncode == 0, err
        assert "/frames" in err + out, (out, err)
    finally:
        _stop(view)
        _stop(hz)
        if run is not None:
            _stop(run)
    img = got["/frames"]
    assert img["channel"]["schemaName"] == "foxglove.CompressedImage" and img["msg"]["data"][:2] == b"\xff\xd8"
    ann = got["/box"]
    assert ann["channel"]["schemaName"] == "foxglove.ImageAnnotations"
    assert ann["topic"] == img["topic"].rsplit("/", 1)[0] + "/box"
    assert len(ann["msg"]["points"][-1]["points"]) == 4 and ann["msg"]["texts"][0]["text"].startswith("frame ")
