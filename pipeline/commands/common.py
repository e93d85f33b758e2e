"""Helpers shared by the commands: errors, zenoh options, running a plan."""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from ..graph import Plan
from ..transport import ZenohSettings, free_port

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"


class CliError(Exception):
    """A user error: printed as one line, exit status 2."""


def parse_box(text: str) -> tuple[float, float, float, float]:
    try:
        vals = tuple(float(v) for v in text.replace(" ", "").split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected X,Y,W,H numbers, got {text!r}") from None
    if len(vals) != 4:
        raise argparse.ArgumentTypeError(f"expected 4 numbers X,Y,W,H, got {len(vals)}")
    if not all(np.isfinite(vals)):
        raise argparse.ArgumentTypeError("box has NaN or inf")
    if vals[2] <= 0 or vals[3] <= 0:
        raise argparse.ArgumentTypeError(f"box width and height must be positive, got W={vals[2]}, H={vals[3]}")
    return vals  # type: ignore[return-value]


def parse_sets(items: list[str]) -> dict[str, dict]:
    """``stage.param=value`` (value parsed as YAML: numbers, lists, true/false) -> overrides."""
    import yaml

    out: dict[str, dict] = {}
    for it in items or []:
        if "=" not in it or "." not in it.split("=", 1)[0]:
            raise CliError(f"--set expects stage.param=value, got {it!r}")
        key, val = it.split("=", 1)
        stage, param = key.split(".", 1)
        out.setdefault(stage, {})[param] = yaml.safe_load(val)
    return out


def zenoh_from_args(args, default_connect: bool) -> ZenohSettings:
    listen = tuple(args.listen or ())
    connect = tuple(args.connect or ())
    if default_connect and not connect and args.mode != "router":
        connect = (DEFAULT_ENDPOINT,)
    if not listen:
        listen = ("tcp/127.0.0.1:0",)
    return ZenohSettings(mode=args.mode, listen=listen, connect=connect, multicast=args.multicast)


def launcher_zenoh(args) -> ZenohSettings:
    """The launcher listens on 7447 (so `gflow topics` finds it) unless busy or told otherwise."""
    if args.listen:
        listen = tuple(args.listen)
    else:
        import socket

        with socket.socket() as s:
            try:
                s.bind(("127.0.0.1", 7447))
                listen = (DEFAULT_ENDPOINT,)
            except OSError:
                listen = (f"tcp/127.0.0.1:{free_port()}",)
    return ZenohSettings(mode=args.mode, listen=listen, connect=tuple(args.connect or ()), multicast=args.multicast)


def add_zenoh_args(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("zenoh network (default: peer mode on loopback, multicast scouting off)")
    g.add_argument("--mode", choices=["peer", "client", "router"], default="peer", help="zenoh session mode")
    g.add_argument("--listen", action="append", metavar="ENDPOINT",
                   help="endpoint to listen on, e.g. tcp/0.0.0.0:7447 (repeatable)")
    g.add_argument("--connect", action="append", metavar="ENDPOINT",
                   help="endpoint to connect to, e.g. tcp/10.0.0.5:7447 for a zenoh router (repeatable)")
    g.add_argument("--multicast", action="store_true", help="enable multicast scouting (off by default)")


def run_plan(plan: Plan, args, recording: str | None, total: int | None, quiet: bool = False, strict: bool = True):
    """Run a plan inline or as processes; return (recording path, seconds, frames, per-stage info).
    With ``strict=False`` a run that did not finish cleanly returns (``info["ok"]`` False) instead of
    raising, so the caller can keep what was tracked."""
    if getattr(args, "inline", False):
        from ..inline import run_inline

        last = [0.0]

        def progress(n: int) -> None:
            now = time.monotonic()
            if not quiet and now - last[0] > 1.0:
                last[0] = now
                print(f"  {n}" + (f"/{total}" if total else "") + " frames", file=sys.stderr)

        md = {"gflow.graph": {"name": plan.name, "stream": plan.stream, "yaml": plan.source_text},
              "gflow.config": plan.config_metadata()}
        r = run_inline(plan, progress=progress, recording=recording, metadata=md)
        bad = {n: e for n, e in r.errors.items() if e}
        return r.recording, r.seconds, r.frames, {"mode": "inline", "steps": r.steps, "errors": bad}
    from ..launcher import Launcher

    res = Launcher(plan, zenoh=launcher_zenoh(args), recording=recording, progress=not quiet,
                   total_frames=total).run()
    if res.interrupted:
        print("interrupted: stages stopped, recording closed", file=sys.stderr)
    for n, e in res.exits.items():
        if e.returncode != 0:
            print(f"stage {n} exited with status {e.returncode}: {e.last_error}", file=sys.stderr)
    src = next(n for n, s in plan.stages.items() if s.is_source())
    frames = res.status[src].steps if src in res.status else 0
    info = {"mode": "processes", "ok": res.ok, "pids": res.pids, "peak_rss_mb": res.peak_rss_mb,
            "errors": len(res.errors), "fps": {n: s.fps for n, s in res.status.items()},
            "interrupted": res.interrupted, "stall": res.stall,
            "restarts": {n: e.restarts for n, e in res.exits.items() if e.restarts}, "estimates": res.estimates}
    if res.stall:
        print(res.stall, file=sys.stderr)
    if strict and not res.ok and not res.interrupted:
        raise CliError("the pipeline did not finish cleanly (see the messages above)")
    return res.recording, res.seconds, frames, info


