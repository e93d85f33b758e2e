"""``gflow foxglove``: every exported message decodes the way Foxglove decodes it (JSON, or
protobuf with the foxglove-sdk schema its channel names), read back with the mcap library."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
from mcap.reader import make_reader
import cli_fork

ROOT = Path(__file__).resolve().parent.parent


def gflow(cwd: Path, *args: str) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    return cli_fork.run_command([sys.executable, "-m", "pipeline.cli.main", *args], cwd=cwd, env=env, capture_output=True,
                                text=True, timeout=120)


def test_export_has_sdk_images_and_overlays_and_json_estimates(tmp_path: Path) -> None:
    from tests.foxglove_protobuf import decode_with_schema

    r = gflow(tmp_path, "run", "demo", "--inline", "--set", "source.frames=8", "--record", "run.mcap")
    assert r.returncode == 0, r.stderr
    r = gflow(tmp_path, "foxglove", "run.mcap", "fox.mcap")
    assert r.returncode == 0, r.stderr
    assert "left out: gflow/demo/: " in r.stdout and "features 8" in r.stdout
    seen: dict[str, list] = {}
    with open(tmp_path / "fox.mcap", "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            if schema is not None and schema.name.startswith("foxglove."):  # the SDK's message and schema
                assert channel.message_encoding == schema.encoding == "protobuf"
                obj = decode_with_schema(schema.name, schema.data, message.data)
            else:
                assert channel.message_encoding == "json"
                obj = json.loads(message.data)
            seen.setdefault(channel.topic, []).append((schema.name if schema else "", obj))
    frames = seen["gflow/demo/frames"]
    assert len(frames) == 8 and frames[0][0] == "foxglove.CompressedImage"
    img = cv2.imdecode(np.frombuffer(frames[0][1]["data"], np.uint8), cv2.IMREAD_COLOR)
    assert img is not None and img.shape[:2] == (240, 320)
    assert len(seen["gflow/demo/image"]) == 8 and seen["gflow/demo/image"][0][1]["format"] == "jpeg"
    ann = seen["gflow/demo/annotations"]
    assert ann[0][0] == "foxglove.ImageAnnotations" and ann[0][1]["texts"][0]["text"].startswith("frame ")
    est = [o for _, o in seen["gflow/demo/estimate"] if o["type"] == "Estimate"]
    assert len(est) == 8 and all(len(e["box"]) == 4 and e["ess"] > 0 for e in est)
    assert "gflow/demo/features" not in seen and "gflow/demo/particles" not in seen
    with open(tmp_path / "fox.mcap", "rb") as f:
        assert "gflow.graph" in {m.name for m in make_reader(f).iter_metadata()}
    r = gflow(tmp_path, "foxglove", "run.mcap", "run.mcap")
    assert r.returncode == 2 and "new file" in r.stderr
