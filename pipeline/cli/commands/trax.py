"""``gflow trax``: serve a tracker over TraX, the protocol the VOT toolkit runs trackers with.

The server is the Python API's (:mod:`gflow.trax`, ``python -m gflow.trax``): this command checks
its options and that the protocol library is installed, then becomes that program (``exec``), so
the client's stdin and stdout are the server's own. ``docs/vot.md`` shows the toolkit's side.
"""

from __future__ import annotations

ORDER = 32

import argparse
import importlib.util
import os
import sys
from pathlib import Path
from typing import Any

from pipeline.cli.commands.common import CliError, nonnegative_int, refuse_dangling_link, refuse_recording
from pipeline.cli.trackers import TRACKERS
#: what to run when the ``trax`` module is missing (``gflow.trax.INSTALL_HINT`` says the same)
INSTALL_HINT = "pip install 'gflow[vot]' (or pip install vot-trax)"


def add_trax_args(p: argparse.ArgumentParser) -> None:
    """The options of ``gflow trax`` and ``python -m gflow.trax``."""
    p.add_argument("--tracker", choices=sorted(TRACKERS),
                   help="the tracker to serve (default: gflow track's default tracker; README 'Which tracker')")
    p.add_argument("--seed", type=nonnegative_int, default=1,
                   help="random seed (default 1, as gflow track's): the boxes of gflow track --inline --seed SEED")
    p.add_argument("--model", metavar="FILE",
                   help="m2: the model of gflow learn m2 (required); gflow: face (default), ellipsoid or a model "
                        "file of gflow learn gflow")
    p.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                   help="a parameter of the tracker, as gflow info TRACKER lists it and gflow.Tracker takes it "
                        "(VALUE read as YAML: 500, 0.3, true); repeat for more")
    p.add_argument("--out", metavar="CSV",
                   help="also write the boxes served, as gflow track --out writes them (frame = the image's index "
                        "in the session); give an absolute path: the toolkit runs trackers in a folder of its own")


def tracker_params(args: argparse.Namespace) -> dict[str, Any]:
    """The keywords for ``gflow.Tracker`` of ``--set NAME=VALUE`` and ``--model``."""
    import yaml

    out: dict[str, Any] = {}
    for item in args.set or []:
        name, eq, value = item.partition("=")
        if not eq or not name.strip().isidentifier():
            raise CliError(f"--set expects NAME=VALUE (a parameter of the tracker: gflow info "
                           f"{args.tracker or 'TRACKER'}), got {item!r}")
        try:
            out[name.strip()] = yaml.safe_load(value)
        except yaml.YAMLError:
            raise CliError(f"--set {item}: the value is not a number, a word or a list") from None
    from gflow_core.registry import trackers

    specs = trackers()
    if args.model is not None:
        takes = [n for n, s in specs.items() if s.model_option]  # the trackers that take a model
        from pipeline.cli.commands.track import DEFAULT_TRACKER

        tracker = args.tracker or DEFAULT_TRACKER  # the default's (dcf) refusal listed its hundred parameters
        if tracker not in takes:
            raise CliError(f"--model is an option of --tracker {' / '.join(takes)}, not of --tracker {tracker}")
        if "model" in out:
            raise CliError("give the model once: --model FILE or --set model=FILE")
        from pipeline.cli.trackers import check_model

        check_model(tracker, args.model, "--model")
        out["model"] = args.model
    spec = specs.get(args.tracker or "")
    if spec is not None and spec.model_required and "model" not in out:
        raise CliError(f"--tracker {spec.name} needs --model MODEL.npz"
                       + (" (learn one with gflow learn m2)" if spec.name == "m2" else ""))
    from pipeline.cli.commands.track import DEFAULT_TRACKER

    _check_values(out, specs.get(args.tracker or DEFAULT_TRACKER))
    return out


def _check_values(params: dict[str, Any], spec) -> None:
    """The values of the tracker's parameters among ``params``, checked in gflow track's words (a
    wrong type reached the tracker and ended the server with a traceback); other names are the
    tracker's to refuse."""
    from pipeline.runtime.tracker_block import block_values, tracker_fields

    if spec is None:
        return
    _refuse_unknown(params, spec)
    mine = {k: v for k, v in params.items() if k in tracker_fields(spec.params)}
    try:
        block_values(spec.params, mine)
    except ValueError as e:
        how = " ".join(f"--set {k}={v}" for k, v in mine.items() if k in str(e)) or "--set"
        raise CliError(f"{how}: {e}") from None


def _refuse_unknown(params: dict[str, Any], spec) -> None:
    """A name in ``params`` the tracker does not take, said as gflow track says it: the closest names and
    where to find them all (the tracker's own refusal listed every parameter, a hundred for dcf, on the
    one line)."""
    import difflib

    from pipeline.runtime.tracker_block import tracker_fields

    known = tracker_fields(spec.params)
    for name in params:
        if name in known or (name == "model" and spec.model_option):
            continue
        close = difflib.get_close_matches(name, known, n=3)
        hint = f"did you mean {', '.join(map(repr, close))}? " if close else ""
        raise CliError(f"--set {name}={params[name]}: {spec.params.__name__} has no parameter {name!r} ({hint}`gflow info "
                       f"{spec.name}` lists all {len(known)})")


def argv_of(args: argparse.Namespace) -> list[str]:
    """``python -m gflow.trax``'s arguments for the options of ``gflow trax``."""
    argv = ["--seed", str(args.seed)] + (["--tracker", args.tracker] if args.tracker else [])
    if args.model is not None:
        argv += ["--model", args.model]
    for item in args.set or []:
        argv += ["--set", item]
    if args.out:
        argv += ["--out", args.out]
    return argv


def cmd_trax(args: argparse.Namespace) -> int:
    if importlib.util.find_spec("trax") is None:
        raise CliError(f"the TraX library (package vot-trax) is not installed: {INSTALL_HINT}")
    tracker_params(args)  # a mistyped option fails here, in one line
    if args.seed < 0:
        raise CliError(f"--seed must be >= 0, got {args.seed}")
    refuse_dangling_link(args.out, "--out")  # before its folder, where the link points
    if args.out and not Path(args.out).resolve().parent.is_dir():
        raise CliError(f"--out {args.out}: folder {Path(args.out).parent} does not exist")
    if args.out:
        refuse_recording(args.out, "--out")
    sys.stdout.flush()
    sys.stderr.flush()
    os.execv(sys.executable, [sys.executable, "-m", "gflow.trax", *argv_of(args)])
    return 0  # not reached: exec replaces this process


def register(sub) -> None:
    p = sub.add_parser("trax", help="serve a tracker over TraX, for the VOT toolkit (docs/vot.md)",
                       description="Serve one of gflow's trackers over TraX (stdin / stdout), the protocol the VOT "
                                   "toolkit runs trackers with: each initialize starts the tracker on a region "
                                   "(a rectangle, or a polygon's bounding box), each frame is answered with the "
                                   "box and the properties confidence and state. Runs the Python API, no stage "
                                   "processes. Needs the vot-trax package: " + INSTALL_HINT + ".",
                       epilog="trackers.ini: command = gflow trax --tracker chamfer (docs/vot.md)")
    add_trax_args(p)
    p.set_defaults(func=cmd_trax)
