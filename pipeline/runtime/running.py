"""Which gflow pipelines run on this machine, and where: one small JSON file per running
launcher (or replay) in the user's runtime folder, so ``gflow topics / echo / hz / ps / pub``
find them without ``--connect``.

Folder: ``$GFLOW_RUNTIME_DIR``, else ``$XDG_RUNTIME_DIR/gflow``, else
``<tmp>/gflow-<uid>``. File ``<stream>-<pid>.json``::

    {"kind": "pipeline", "name": "demo", "stream": "demo", "pid": 1234,
     "endpoints": ["tcp/127.0.0.1:7447"], "stages": ["source", ...], "started": 1763870000.1,
     "recording": "recordings/demo-....mcap", "camera": "demo", "no_record": false}

``external`` lists the topics the graph takes from outside (``gflow replay`` may feed those).
``recording`` is None where this launcher does not record (``no_record`` true for a ``--no-record`` run).

``stream`` is the run's own stream (``demo-3f9c2a``: see ``pipeline.runtime.runid``), ``camera``
the graph's; the tools accept a topic named by the graph's stream when one run of it is running.

The file is written when the launcher listens and removed when it exits (also on an
exception or Ctrl-C). A file left by a killed process is recognised by its dead PID, ignored
and removed by the next reader.
"""

from __future__ import annotations

import atexit
import json
import os
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

__all__ = ["runtime_dir", "Announcement", "announce", "running", "describe_none", "runs_of_camera", "await_running"]


def runtime_dir() -> Path:
    """The folder holding one file per running pipeline (not created here)."""
    if os.environ.get("GFLOW_RUNTIME_DIR"):
        return Path(os.environ["GFLOW_RUNTIME_DIR"])
    if os.environ.get("XDG_RUNTIME_DIR"):
        return Path(os.environ["XDG_RUNTIME_DIR"]) / "gflow"
    uid = os.getuid() if hasattr(os, "getuid") else 0
    return Path(tempfile.gettempdir()) / f"gflow-{uid}"


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process: alive
        return True
    return True


@dataclass
class Announcement:
    """A running pipeline's file; ``close()`` (or leaving the ``with``) removes it."""

    path: Path
    info: dict = field(default_factory=dict)

    def close(self) -> None:
        try:
            self.path.unlink()
        except FileNotFoundError:
            pass

    def __enter__(self) -> "Announcement":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def announce(stream: str, endpoints: list[str] | tuple[str, ...], *, name: str = "", stages: list[str] | None = None,
             kind: str = "pipeline", recording: str | None = None, camera: str = "",
             no_record: bool = False, external: list[str] | None = None,
             graph: list[str] | None = None) -> Announcement:
    """Write this process's file (atomically) and return the handle that removes it. ``no_record``:
    a ``--no-record`` run (its results read from a temporary file, not announced as a recording);
    ``external``: the topics its graph takes from outside (a replay may feed them); ``stages``: the stages this
    process runs, ``graph``: every stage of its graph (on other hosts too)."""
    d = runtime_dir()
    d.mkdir(parents=True, exist_ok=True, mode=0o700)
    pid = os.getpid()
    info = {"kind": kind, "name": name or stream, "stream": stream, "pid": pid,
            "endpoints": [e.replace("0.0.0.0", "127.0.0.1") for e in endpoints], "stages": list(stages or []),
            "started": time.time(), "recording": recording, "camera": camera or stream, "no_record": no_record,
            "external": list(external or []), "graph": list(graph or [])}
    path = d / f"{stream}-{pid}.json"
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(info))
    os.replace(tmp, path)
    a = Announcement(path, info)
    atexit.register(a.close)
    return a


def running(stream: str | None = None, everyone: bool = False) -> list[dict]:
    """Every live announcement (oldest first), optionally of one stream; stale files are removed.

    Only the user's own pipelines (announcement files this user owns: a runtime folder shared
    between users, ``GFLOW_RUNTIME_DIR`` say, holds others' too), unless ``everyone``; each
    announcement says its owner's uid as ``uid``."""
    d = runtime_dir()
    out = []
    me = os.getuid() if hasattr(os, "getuid") else 0
    for f in sorted(d.glob("*.json")) if d.is_dir() else []:
        try:
            uid = f.stat().st_uid
            if uid != me and not everyone:
                continue  # another user's pipeline
            info = json.loads(f.read_text())
            pid = int(info["pid"])
            info["uid"] = uid
        except (OSError, ValueError, KeyError, TypeError):
            continue  # being written, or not ours
        if not _alive(pid) and uid == me:
            try:
                f.unlink()
            except OSError:
                pass
            continue
        if stream is None or info.get("stream") == stream:
            out.append(info)
    return sorted(out, key=lambda i: i.get("started", 0))


def describe_none(stream: str | None = None) -> str:
    """The one-line message for 'nothing is running'."""
    what = f"no running gflow pipeline with stream {stream!r}" if stream else "no running gflow pipeline"
    others = sorted({str(i.get("stream")) for i in running()}) if stream else []
    if others:  # a mistyped stream: say which run
        return f"{what} on this machine; running: {', '.join(others)}"
    return (f"{what} on this machine (none announced in {runtime_dir()}); start one (gflow demo, track, run, "
            f"replay) or give --connect ENDPOINT")


def runs_of_camera(camera: str) -> list[dict]:
    """The running pipelines whose graph's stream is ``camera`` (each run has its own stream,
    ``demo-3f9c2a`` for the graph stream ``demo``)."""
    return [i for i in running() if i.get("camera") == camera and i.get("stream") != camera]


def await_running(stream: str | None = None, until: float | None = None, poll: float = 0.1) -> bool:
    """Wait until a pipeline is announced (of ``stream``: its run's stream or its graph's), or the
    monotonic time ``until`` (None: no end); True when one runs. For a tool started before its run."""
    def found() -> bool:
        return any(stream is None or stream in (i.get("stream"), i.get("camera")) for i in running())

    while not found():
        if until is not None and time.monotonic() >= until:
            return False
        time.sleep(poll)
    return True
