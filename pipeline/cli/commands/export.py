"""``gflow export vot DATA OUT``: sequences with ground truth as a VOT toolkit workspace.

DATA is what ``gflow benchmark`` reads: a sequence folder (``frames/`` and ``groundtruth.csv``)
or a folder of them. OUT becomes a workspace that ``vot evaluate --workspace OUT`` runs with no
download: the sequences in the VOT layout, a stack, and a ``trackers.ini`` that serves gflow's
trackers over TraX with this Python (:mod:`pipeline.io.vot_workspace` says how each file is
written; ``docs/vot.md`` how to use them).
"""

from __future__ import annotations

ORDER = 33

import shutil
import sys
import tempfile
from pathlib import Path

from pipeline.cli.commands.common import CliError, refuse_dangling_link


def _is_sequence(folder: Path) -> bool:
    """A sequence folder, as ``gflow benchmark`` finds one: ``frames/`` and ``groundtruth.csv``."""
    return (folder / "frames").is_dir() and (folder / "groundtruth.csv").is_file()


def _wanted(text: str) -> list[str]:
    """The sequences ``--sequences`` names; one named twice (exported once without a word) is refused."""
    from pipeline.app.names import comma_names

    try:
        return comma_names(text, "--sequences")
    except ValueError as e:
        raise CliError(str(e)) from None


def _check_out(out: Path) -> None:
    refuse_dangling_link(str(out), "OUT")
    if out.exists() and not out.is_dir():
        raise CliError(f"{out} is a file; give a new folder for the workspace")
    if out.is_dir() and any(out.iterdir()):
        raise CliError(f"{out} is not empty; give a new folder for the workspace")
    if not out.resolve().parent.is_dir():
        raise CliError(f"folder {out.parent} does not exist")


def _read_models(args) -> None:
    """Read each model file given, as the served tracker will: a file that is not a model, or a model of the other
    tracker's kind (an M2 model given to gflow), was written into trackers.ini and found only when the toolkit ran
    it."""
    from pipeline.cli.commands.benchmark import model_given, model_options
    from pipeline.cli.trackers import TRACKERS
    from pipeline.io.modelfile import kind_of, load_model

    for name, opt in model_options().items():
        model = model_given(args, name)
        if model and Path(model).is_file():
            try:
                kind = kind_of(load_model(model))
            except ValueError as e:
                raise CliError(f"{opt}: {e}") from None
            want = getattr(TRACKERS[name], "MODEL_KIND", kind)
            if kind != want:
                raise CliError(f"{opt}: {model} holds a model of kind {kind!r}; --tracker {name} needs one of kind "
                               f"{want!r}")


def served_trackers(args) -> dict[str, list[str]]:
    """{tracker: its ``gflow trax`` options} of trackers.ini: every registered tracker, dcf (the
    default) first; one that needs a model only when ``--NAME-model`` gives it one, which a tracker
    taking a model gets as ``gflow trax --model`` (a file's absolute path)."""
    from gflow_core.registry import trackers

    from pipeline.cli.commands.benchmark import model_given

    out: dict[str, list[str]] = {}
    for name, spec in sorted(trackers().items(), key=lambda kv: (kv[0] != "dcf", kv[0])):
        model = model_given(args, name)
        if spec.model_required and not model:
            continue
        out[name] = ["--tracker", name]
        if model:
            out[name] += ["--model", str(Path(model).resolve()) if Path(model).is_file() else model]
    return out


def cmd_export_vot(args) -> int:
    from pipeline.evaluation.sequence_benchmark import find_sequences

    out = Path(args.out)
    _check_out(out)
    from pipeline.cli.commands.benchmark import check_models

    check_models(args)
    _read_models(args)
    data = Path(args.data)
    if args.sequences is not None and data.is_dir() and not _is_sequence(data):
        # chosen by folder name before any is read: a sequence left out with a bad groundtruth.csv
        # refused the export of the ones chosen (and hid a mistyped name)
        want = _wanted(args.sequences)
        known = sorted(c.name for c in data.iterdir() if c.is_dir() and not c.name.startswith(".") and _is_sequence(c))
        unknown = [n for n in want if n not in known]
        if known and (unknown or not want):
            raise CliError(f"unknown sequence {unknown[0] if unknown else '(none given)'} in --sequences (known: "
                           f"{', '.join(known)})")
        if known:
            seqs, notes = find_sequences([str(data / n) for n in want])
        else:  # none there: find_sequences says what the folder is instead
            seqs, notes = find_sequences([args.data])
    else:
        seqs, notes = find_sequences([args.data])
    if args.sequences is not None:  # '' too: it names no sequence, not all of them
        want = _wanted(args.sequences)
        unknown = [n for n in want if n not in {s.name for s in seqs}]
        if unknown or not want:
            raise CliError(f"unknown sequence {unknown[0] if unknown else '(none given)'} in --sequences (known: "
                           f"{', '.join(s.name for s in seqs)})")
        seqs = [s for s in seqs if s.name in want]
    for n in notes:
        print(f"note: {n}", file=sys.stderr)
    # written beside OUT and moved into place whole, so that a damaged frame or Ctrl-C leaves no
    # half-written workspace behind
    final = out.resolve()
    work = Path(tempfile.mkdtemp(prefix=f".{final.name}.partial-", dir=final.parent))
    try:
        done = _write_workspace(args, seqs, work)
        if final.is_dir():
            final.rmdir()  # checked empty above
        work.rename(final)
    except ValueError as err:
        raise CliError(f"{err} (nothing was written to {out})") from None
    finally:
        shutil.rmtree(work, ignore_errors=True)
    trackers = served_trackers(args)
    print(f"VOT workspace in {out}: {len(done)} sequences; trackers {', '.join('gflow-' + t for t in trackers)}; "
          f"run: vot evaluate --workspace {out} gflow-dcf")
    return 0


def _write_workspace(args, seqs: list, out: Path) -> list:
    """Every file of the workspace in the folder ``out``; the sequences written (their entries).
    ``ValueError`` for a frame or ground truth that cannot be read."""
    from pipeline.io.vot_workspace import stack_yaml, trackers_ini, workspace_config, write_list, write_sequence

    done = []
    for s in seqs:
        e = write_sequence(out / "sequences" / s.name, s.name, s.path / "frames", s.groundtruth)
        done.append(e)
        how = "copied" if e.copied else "re-encoded as PNG"
        print(f"{e.name}: {e.length} frames from frame {e.first} ({e.labelled} with ground truth), "
              f"{e.size[0]}x{e.size[1]}, {how}")
        for line in e.damaged:
            print(f"warning: {line}", file=sys.stderr)
    write_list(out / "sequences", [e.name for e in done])
    sparse = [e.name for e in done if not e.dense]
    title = f"gflow export of {Path(args.data).name}: {', '.join(e.name for e in done)}"
    (out / "stack.yaml").write_text(stack_yaml(title, supervised=not sparse))
    trackers = served_trackers(args)
    (out / "trackers.ini").write_text(trackers_ini(sys.executable, trackers))
    (out / "config.yaml").write_text(workspace_config())
    if sparse:
        print(f"note: {', '.join(sparse)} {'has' if len(sparse) == 1 else 'have'} frames without ground truth "
              f"(written as nan rows, which the toolkit leaves out of its analyses); the stack has no reinit "
              f"experiment, which needs a box on every frame")
    return done


def register(sub) -> None:
    p = sub.add_parser("export", help="write sequences for other tools (vot: a VOT toolkit workspace)",
                       description="Write data in another tool's layout.")
    kinds = p.add_subparsers(dest="kind", metavar="KIND", required=True)
    v = kinds.add_parser("vot", help="sequences with ground truth as a VOT toolkit workspace (docs/vot.md)",
                         description="Write the sequences of DATA (what gflow benchmark reads: a folder with frames/ "
                                     "and groundtruth.csv, or a folder of them) as a VOT toolkit workspace in OUT: "
                                     "sequences/NAME/color/00000001.jpg ..., groundtruth.txt (a frame without ground "
                                     "truth is a nan row), sequence, list.txt, and stack.yaml, trackers.ini and "
                                     "config.yaml, so that vot evaluate --workspace OUT runs with no download. VOT "
                                     "frame 1 is each sequence's first frame with ground truth.",
                         epilog="example: gflow export vot ../shared/data vot-workspace --sequences caviar1,jumping")
    v.add_argument("data", metavar="DATA", help="a sequence folder (frames/, groundtruth.csv) or a folder of them")
    v.add_argument("out", metavar="OUT", help="the workspace folder to write (new or empty)")
    v.add_argument("--sequences", metavar="A,B", help="only these sequences of DATA")
    from pipeline.cli.commands.benchmark import add_model_options

    add_model_options(v, "serve")
    v.set_defaults(func=cmd_export_vot)
