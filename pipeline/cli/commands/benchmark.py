"""``gflow benchmark DATASET...``: every tracker on every sequence folder, one table per tracker.

The logic (finding sequences, scoring, JSON and plots) is in :mod:`pipeline.evaluation.sequence_benchmark`,
the tables in :mod:`pipeline.evaluation.benchmark_tables`, the stress benchmark in
:mod:`pipeline.evaluation.stress_benchmark`, the variants (``--variant grey``) in
:mod:`pipeline.evaluation.variant_benchmark`;
each tracker runs as a :class:`pipeline.app.TrackRequest`, checked and planned as ``gflow track``
plans its own (:func:`.track.request_plan`) and run by :func:`pipeline.app.track`. The trackers that
take a model get a ``--NAME-model`` option (:attr:`gflow_core.spec.TrackerSpec.model_option`).
"""

from __future__ import annotations

ORDER = 31

import copy
import json
import shutil
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING

from pipeline.cli.trackers import TRACKERS, spec_of
from pipeline.cli.commands.common import (CliError, check_new_picture, frame_range, nonnegative_int, range_past_note,
                                          refuse_dangling_link, say_notes, source_frames, start_work, whole_number)

if TYPE_CHECKING:  # imported where used: the application layer is not needed to parse the options
    from pipeline.app import TrackRequest


def model_options() -> dict[str, str]:
    """{tracker: the option giving its model} of the trackers that take one (``--m2-model``):
    :attr:`gflow_core.spec.TrackerSpec.model_option`."""
    from gflow_core.registry import trackers

    return {name: f"--{name.replace('_', '-')}-model" for name, spec in trackers().items() if spec.model_option}


def add_model_options(p, what: str) -> None:
    """A ``--NAME-model`` option for every tracker that takes a model (``what``: what it does with it)."""
    from gflow_core.registry import get

    for name, opt in model_options().items():
        spec = get(name)
        p.add_argument(opt, metavar="MODEL", help=f"{what} --tracker {name} with this model, its "
                       f"gflow track {spec.model_option} (a model file" + (f"; without one, {name} is skipped)"
                                                                         if spec.model_required else
                                                                         " or a built-in model's name)"))


def model_given(args, name: str) -> str | None:
    """The model ``--NAME-model`` gave tracker ``name`` (None: none given, or it takes none)."""
    opt = model_options().get(name)
    return getattr(args, opt[2:].replace("-", "_"), None) if opt else None


def _names(text: str | None, known: list[str], what: str, noun: str) -> list[str]:
    """The names of a comma-separated option ``--what``, each one of ``known`` (a ``noun``)."""
    from pipeline.app.names import comma_names

    if text is None:
        return list(known)
    try:
        names = comma_names(text, f"--{what}")  # a name given twice (run once without a word) is refused
    except ValueError as e:
        raise CliError(str(e)) from None
    if not names:
        raise CliError(f"--{what} needs at least one name (known: {', '.join(known)})")
    bad = [n for n in names if n not in known]
    if bad:
        raise CliError(f"unknown {noun} {bad[0]!r} in --{what} (known: {', '.join(known)})")
    return names


def _opencv_names(text: str | None) -> list[str]:
    """The OpenCV trackers of ``--opencv`` (``none``: no OpenCV tracker)."""
    from pipeline.evaluation.sequence_benchmark import OPENCV_TRACKERS

    if not text or text.strip() == "none":
        return []
    return _names(text, list(OPENCV_TRACKERS), "opencv", "OpenCV tracker")


def _opencv_missing(names: list[str]) -> dict[str, str]:
    """{name: why} of the OpenCV trackers this OpenCV does not have."""
    from pipeline.evaluation.sequence_benchmark import opencv_tracker

    return {c: opencv_tracker(c)[1] for c in names if opencv_tracker(c)[0] is None}


def check_models(args) -> None:
    """Each ``--NAME-model`` given names a file, or a built-in model of its tracker by a word (``face``,
    ``ellipsoid``): :func:`pipeline.cli.trackers.check_model`."""
    from pipeline.cli.trackers import check_model

    for name, opt in model_options().items():
        model = model_given(args, name)
        if model:
            check_model(name, model, opt)


def _request(args, seq, name: str, start: int, stop: int | None, folder: Path) -> tuple[str, TrackRequest]:
    """Where this benchmark run writes its boxes, and the request it is (the box of frame ``start``,
    one seed), as ``gflow track`` would make it of the same options."""
    from pipeline.app import TrackRequest

    folder.mkdir(parents=True, exist_ok=True)  # the benchmark's own folder (gflow track makes none)
    params = {}
    model = model_given(args, name)
    if model:
        params[spec_of(name).model_dest] = model
    box = seq.groundtruth[start]
    request = TrackRequest(source=str(seq.path), init=(float(box[0]), float(box[1]), float(box[2]), float(box[3])),
                           tracker=name, params=params, sets=tuple(args.set or ()), seed=args.seed,
                           record=str(folder / f"{name}.mcap"), inline=args.inline, start=start, stop=stop,
                           quiet=args.quiet)
    return str(folder / f"{name}.csv"), request


def _planned(args, seq, name: str, start: int, stop: int | None, folder: Path):
    """(boxes CSV, plan) of one run, or why it is skipped (a tracker needing a model nobody gave, or a
    request ``gflow track`` would refuse; with a model given, the refusal is raised)."""
    from pipeline.cli.commands.track import request_plan

    if spec_of(name).model_required and not model_given(args, name):
        return f"skipped: needs {model_options()[name]} MODEL.npz"
    if (folder / f"{name}.mcap").exists():  # an error, not a skipped run: every run of an --out-dir used before
        raise CliError(f"--out-dir {args.out_dir}: {folder / f'{name}.mcap'} exists (an earlier run's); a recording "
                       f"is never overwritten: give a new folder")
    out, request = _request(args, seq, name, start, stop, folder)
    try:
        return out, request_plan(request, out)
    except CliError as e:
        if model_given(args, name):
            raise
        return f"skipped: {e}"


def _refuse_unused_models(args, names: list[str]) -> None:
    """A ``--NAME-model`` given for a tracker ``--trackers`` leaves out (``--trackers dcf --m2-model M``): the model
    was neither read nor used, and nothing said so."""
    for name, opt in model_options().items():
        if model_given(args, name) and name not in names:
            raise CliError(f"{opt} gives --tracker {name} its model, but --trackers {args.trackers} does not run "
                           f"{name}: add {name} to --trackers, or leave {opt} out")


def _check_paths(args) -> None:
    """Model files, plot names and --out-dir, before any work."""
    check_models(args)
    for opt in ("plot", "precision_plot"):
        v = getattr(args, opt)
        if v and Path(v).suffix.lower() not in (".png", ".pdf", ".svg", ".jpg", ".jpeg"):
            raise CliError(f"--{opt.replace('_', '-')} {v}: give a .png (or .pdf, .svg, .jpg) file name")
        refuse_dangling_link(v, f"--{opt.replace('_', '-')}")  # before its folder, where the link points
        if v and not Path(v).resolve().parent.is_dir():
            raise CliError(f"--{opt.replace('_', '-')} {v}: folder {Path(v).parent} does not exist")
        if v:
            check_new_picture(v, opt)  # an earlier plot
    refuse_dangling_link(args.out_dir, "--out-dir")
    if args.out_dir and Path(args.out_dir).exists() and not Path(args.out_dir).is_dir():
        raise CliError(f"--out-dir {args.out_dir} is a file, not a folder")


def _refuse_earlier_runs(args, seqs, names: list[str], cv_names: list[str], seeds: list[int],
                         folders: list[Path]) -> None:
    """An --out-dir used before: refuse, before any work, a run whose boxes (DIR/SEQUENCE/NAME.csv,
    DIR/seed-S/SEQUENCE/NAME.csv with several seeds, under DIR/KIND with several kinds of footage; ``folders``
    the kinds' folders) or recording would replace an earlier run's (the boxes were written over without a
    word)."""
    files = [f"{n}.{ext}" for n in names for ext in ("mcap", "csv")] + [f"opencv_{c}.csv" for c in cv_names]
    for root, seq, seed in ((d, q, s) for d in folders for q in seqs for s in seeds):
        for f in files + ["static_box.csv"]:
            path = _seed_dir(root, seed, seeds) / seq.name / f
            if path.exists():
                raise CliError(f"--out-dir {args.out_dir}: {path} exists (an earlier run's); a run's boxes and "
                               f"recording are never overwritten: give a new folder")


def _plans(args, seqs, names: list[str], first: dict[str, int], stop: int | None, work: Path):
    """Boxes CSV and plan of every (sequence, tracker), or why it is skipped.

    Building every plan first makes a bad model file or option fail before any tracking. A
    tracker that cannot run without a model nobody gave, or that refuses an option another
    selected tracker takes, is skipped with a note; a refusal that would skip every run is an error.
    """
    plans: dict[tuple[str, str], tuple] = {}
    skip: dict[tuple[str, str], str] = {}
    for seq in seqs:
        for name in names:
            planned = _planned(args, seq, name, first[seq.name], stop, work / seq.name)
            if isinstance(planned, str):
                skip[seq.name, name] = planned
            else:
                plans[seq.name, name] = planned
    if not plans:
        _refuse_a_mistake_that_skips_every_run(skip)
    return plans, skip


def _refuse_a_mistake_that_skips_every_run(skip: dict[tuple[str, str], str]) -> None:
    """Raise the mistake (a --set no selected tracker takes, a bad value, an option of another tracker) that
    skips every run, rather than print a table of skips and exit 0. With several trackers each refused in
    words of its own (``--set tracker.nosuch=1`` with the default ``--trackers``), the first is named; runs
    skipped only for a model nobody gave are a note, not a mistake (``--trackers m2`` alone)."""
    mistakes = list(dict.fromkeys(w for w in skip.values() if not w.startswith("skipped: needs ")))
    if not mistakes:
        return
    first = mistakes[0].removeprefix("skipped: ")
    if len(set(skip.values())) == 1:
        raise CliError(first)
    raise CliError(f"{first}; no selected tracker would run")


def _stress_plan_of(args):
    """How each tracker runs on a derived sequence of the stress benchmark: its boxes CSV and plan
    from the first frame on, or why it is skipped."""

    def plan_of(seq, name: str, folder: Path):
        planned = _planned(args, seq, name, 0, None, folder)
        return planned.removeprefix("skipped: ") if isinstance(planned, str) else planned

    return plan_of


def _kinds(text: str | None) -> list[tuple[str, object]]:
    """The kinds of footage ``--variant`` names, each (name, its variant; None for ``none``, the sequences as
    they are): one variant, several separated by commas, or ``all`` (:data:`.variants.SUITE`); [("none",
    None)] without it. A CliError (one line) for an unknown or repeated one."""
    from gflow_core.evaluation.variants import SUITE, select_variant

    if text is None:
        return [("none", None)]
    names = list(SUITE) if text.strip() == "all" else [t.strip() for t in text.split(",")]
    if len(set(names)) != len(names):
        raise CliError(f"--variant {text}: a kind of footage is named twice")
    try:
        return [(n, None if n == "none" else select_variant(n)) for n in names]
    except ValueError as e:
        raise CliError(f"{e}; 'none' is the sequences as they are, 'all' every kind ({', '.join(SUITE)})") from None


def _pick_sequences(seqs, text: str | None):
    """The sequences named in ``--sequences`` (all when not given)."""
    if text is None:
        return seqs
    want = _names(text, [s.name for s in seqs], "sequences", "sequence")
    return [s for s in seqs if s.name in want]


def _seeds(args) -> list[int]:
    """The seeds to run: ``--seeds`` (each a whole benchmark), else ``--seed`` (default 1)."""
    from pipeline.evaluation.seed_means import parse_seeds

    if args.seeds is None:
        return [1 if args.seed is None else args.seed]
    if args.seed is not None:
        raise CliError("give --seed or --seeds, not both (--seeds 1,2,3 runs the benchmark once per seed)")
    try:
        return parse_seeds(args.seeds)
    except ValueError as e:
        raise CliError(str(e)) from None


def _with_seed(args, seed: int):
    """``args`` with ``seed`` as its one seed (the options of one of the runs of ``--seeds``)."""
    one = copy.copy(args)
    one.seed = seed
    return one


def _seed_dir(work: Path, seed: int, seeds: list[int]) -> Path:
    """Where a seed's runs write: ``work`` itself with one seed, ``work/seed-S`` with several."""
    return work if len(seeds) == 1 else work / f"seed-{seed}"


def _refuse_earlier_stress_runs(args, seqs, cases: list[str], seeds: list[int]) -> None:
    """An --out-dir a stress benchmark wrote before: refuse, before any case is derived, a run whose folder
    (DIR[/seed-S]/SEQUENCE/CASE) already holds an earlier run's boxes or recordings (it was said only once the first
    case had been derived and run, and an OpenCV or still box CSV of an earlier run would be written over)."""
    for seq, case, seed in ((q, c, k) for q in seqs for c in cases for k in seeds):
        folder = _seed_dir(Path(args.out_dir), seed, seeds) / seq.name / case
        held = sorted(folder.iterdir()) if folder.is_dir() else []
        if held:
            raise CliError(f"--out-dir {args.out_dir}: {held[0]} exists (an earlier run's); a run's boxes and "
                           f"recordings are never overwritten: give a new folder")


#: frames after the window the stress benchmark needs at least (the "after" score starts 10 frames after it)
AFTER_MIN = 15


def _cmd_stress(args, names: list[str], seqs, donors, seeds: list[int], skipped: list[str]) -> int:
    """``gflow benchmark DATA --stress``: the trackers on stress cases derived from every sequence, once per
    seed (with several, each seed's tables in turn, its runs kept under ``--out-dir``/seed-S); ``skipped``,
    the folders of DATA that are no sequence, are noted once the options are checked."""
    from pipeline.evaluation.sequence_benchmark import note
    from pipeline.evaluation.stress_benchmark import check_sequences, format_stress, run_stress, select_cases, stress_json

    for opt in ("frames", "plot", "precision_plot"):
        if getattr(args, opt):
            raise CliError(f"--{opt.replace('_', '-')} is not used with --stress (each case has its own frames)")
    if args.lead < 1 or args.tail < AFTER_MIN:
        raise CliError(f"--lead needs at least 1 frame and --tail at least {AFTER_MIN} (got {args.lead}, {args.tail})")
    if args.stress_cache and Path(args.stress_cache).exists() and not Path(args.stress_cache).is_dir():
        raise CliError(f"--stress-cache {args.stress_cache} is a file, not a folder")
    cases = select_cases(args.cases)
    check_sequences(seqs)
    if args.out_dir:
        _refuse_earlier_stress_runs(args, seqs, [c.name for c in cases], seeds)
    # CSRT beside every tracker by default, where this OpenCV has it
    cv_names = _opencv_names("csrt" if args.opencv is None else args.opencv)
    cv_missing = _opencv_missing(cv_names)
    with tempfile.TemporaryDirectory(prefix="gflow-benchmark-") as tmp:
        # every tracker's options and model files checked on the original sequences, before any work
        _, skip = _plans(args, seqs, names, {s.name: min(s.groundtruth) for s in seqs}, None, Path(tmp))
    start_work()  # every check done: a bad value met from here on is the benchmark failing (exit 1)
    for line in skipped:  # after the checks: a mistake's error is the one line on stderr
        note(line)
    for c, why in cv_missing.items():  # after them too (it came before a bad --set's error)
        note(f"opencv {c} not measured: {why}")
    for (seq, name), why in sorted(skip.items()):
        note(f"{seq} / {name}: {why}")
    runnable = [n for n in names if not any(k[1] == n for k in skip)]
    meta = {"datasets": list(args.datasets), "sequences": [s.name for s in seqs],
            "mode": "inline" if args.inline else "processes", "lead": args.lead, "tail": args.tail,
            "skipped": sorted({f"{n}: {w}" for (_, n), w in skip.items()}), "opencv_missing": cv_missing}
    done: list[dict] = []
    summaries: list[dict] = []
    interrupted = False
    for seed in seeds:
        one = _with_seed(args, seed)
        if args.out_dir:
            one.out_dir = str(_seed_dir(Path(args.out_dir), seed, seeds))
        if len(seeds) > 1:
            note(f"seed {seed} ({seeds.index(seed) + 1} of {len(seeds)})")
        rows, interrupted, cases = run_stress(one, seqs, runnable, [c for c in cv_names if c not in cv_missing],
                                              _stress_plan_of(one), donors)
        run_meta = dict(meta, seed=seed, interrupted=interrupted)
        done.append(stress_json(rows, run_meta, cases))
        if not interrupted:  # a seed stopped midway is not set beside the others
            summaries.append(done[-1]["summary"])
        if not args.json:
            print((f"\n{'## ' if args.markdown else ''}seed {seed}\n\n" if len(seeds) > 1 else "")
                  + format_stress(rows, markdown=args.markdown))
        if interrupted:
            break
    if args.json:
        print(json.dumps(done[0] if len(seeds) == 1 else dict(meta, seeds=seeds[:len(done)], runs=done)))
    else:
        if len(summaries) > 1:
            from pipeline.evaluation.stress_seeds import format_stress_seeds

            print(f"\n{'## ' if args.markdown else ''}every seed\n\n"
                  + format_stress_seeds(summaries, seeds[:len(summaries)], markdown=args.markdown))
        for line in meta["skipped"] + [f"opencv {c}: {w}" for c, w in cv_missing.items()]:
            print(f"\nnot run: {line}")
    return 130 if interrupted else 0


def _run_seed(args, seqs, names: list[str], cv: tuple[list[str], dict[str, str]], first: dict[str, int],
              stop: int | None, folder: Path, planned: tuple[dict, dict], count: list[int]) -> tuple[list, bool]:
    """Every tracker, OpenCV tracker and the box that never moves on every sequence with ``args.seed``,
    writing under ``folder``; the rows and whether the user interrupted. ``count`` is [runs done, runs in
    all], for the progress lines."""
    from pipeline.evaluation.sequence_benchmark import Row, note, opencv_row, published_rows, static_box, tracker_row

    cv_names, cv_missing = cv
    plans, skip = planned
    keep, mode = bool(args.out_dir), "inline" if args.inline else "processes"
    rows: list[Row] = []
    try:
        for seq in seqs:
            start = first[seq.name]
            gt = seq.truth(start, stop)
            (folder / seq.name).mkdir(parents=True, exist_ok=True)
            for name in names:
                row = Row(seq.name, name, "tracker")
                rows.append(row)
                if (seq.name, name) in skip:
                    row.note = skip[seq.name, name]
                    note(f"{seq.name} / {name}: {row.note}")
                    continue
                out, plan = plans[seq.name, name]
                count[0] += 1
                note(f"[{count[0]}/{count[1]}] {seq.name} / {name}: frames {start}:{'' if stop is None else stop}"
                     + (f" ({plan.total} frames)" if plan.total else "") + f", {mode}, seed {args.seed}")
                tracker_row(row, out, plan, gt, keep)
            for c in cv_names:
                row = Row(seq.name, f"opencv {c}", "opencv", note=cv_missing.get(c, ""))
                rows.append(row)
                if c not in cv_missing:
                    count[0] += 1
                    note(f"[{count[0]}/{count[1]}] {seq.name} / opencv {c}")
                    opencv_row(row, c, seq, start, stop, gt, folder / seq.name / f"opencv_{c}.csv", args.seed, keep)
            rows.extend(published_rows(seq, gt))
            rows.append(static_box(seq, gt, start, folder / seq.name))
            if not keep:
                rows[-1].boxes_csv = None
    except KeyboardInterrupt:
        if rows and rows[-1].score is None and not rows[-1].note:
            rows[-1].note = "interrupted"
        note("interrupted: stopped; the table holds the runs that finished")
        return rows, True
    return rows, False


def _first_frames(args, seqs, first_frame: int) -> dict[str, int]:
    """The first frame to track of each sequence: A of --frames A:B, else its first ground-truth frame
    (a CliError where the sequence has no box for it)."""
    first = {seq.name: first_frame if args.frames else min(seq.groundtruth) for seq in seqs}
    for seq in seqs:
        if first[seq.name] not in seq.groundtruth:
            gt = sorted(seq.groundtruth)
            gaps = ", with gaps" if len(gt) != gt[-1] - gt[0] + 1 else ""
            raise CliError(f"--frames {args.frames}: {seq.path / 'groundtruth.csv'} has no box for frame "
                           f"{first[seq.name]}, the first frame to track (its boxes: frames {gt[0]}..{gt[-1]}{gaps})")
    return first


def _frames_past(args, seqs, first: dict[str, int], stop: int | None) -> list[str]:
    """A note for each sequence whose frames end before B of ``--frames A:B``, with the frames it tracks
    (:func:`range_past_note`): a run of fewer frames was reported as though every frame asked for had been there."""
    if stop is None:
        return []
    lines = []
    for seq in seqs:
        n = source_frames(seq.path)
        if n and first[seq.name] < n:
            lines.append(range_past_note(f"--frames {args.frames}", (first[seq.name], stop), str(seq.path), (0, n - 1),
                                         (first[seq.name], n - 1), "tracking"))
    return lines


def cmd_benchmark(args) -> int:
    from pipeline.evaluation.sequence_benchmark import find_sequences, note
    from pipeline.runtime.versions import versions
    names = _names(args.trackers, sorted(TRACKERS), "trackers", "tracker")
    _refuse_unused_models(args, names)
    if args.list_cases:
        from pipeline.evaluation.stress_benchmark import select_cases

        try:
            chosen = select_cases(args.cases)  # with --cases, the cases it names (a mistyped one is an error)
        except ValueError as e:
            raise CliError(str(e)) from None
        for c in chosen:
            print(f"{c.name:16s} {c.describe()}")
        return 0
    if not args.datasets:
        raise CliError("the following arguments are required: DATASET (a sequence folder or a folder of them)")
    from pipeline.app import parse_sets

    parse_sets(args.set)  # a --set not of the form stage.param=value, before any folder is read
    seeds = _seeds(args)
    args.seed = seeds[0]
    kinds = _kinds(args.variant)
    several = len(kinds) > 1
    if args.stress:
        if args.variant is not None:
            raise CliError("--variant is not used with --stress (run one, then the other)")
        _check_paths(args)
        seqs, skipped = find_sequences(args.datasets)
        return _cmd_stress(args, names, _pick_sequences(seqs, args.sequences), seqs, seeds, skipped)
    for opt, default in (("cases", None), ("stress_cache", None), ("lead", 30), ("tail", 60)):
        if getattr(args, opt) != default:
            raise CliError(f"--{opt.replace('_', '-')} is an option of --stress")
    if several and (args.plot or args.precision_plot):
        raise CliError("--plot and --precision-plot draw one kind of footage: give one --variant")
    cv_names = _opencv_names(args.opencv)
    first_frame, stop = frame_range(args.frames)
    _check_paths(args)
    seqs, skipped = find_sequences(args.datasets)
    seqs = _pick_sequences(seqs, args.sequences)
    first = _first_frames(args, seqs, first_frame)
    cv_missing = _opencv_missing(cv_names)
    cv_run = [c for c in cv_names if c not in cv_missing]
    if args.out_dir:
        _refuse_earlier_runs(args, seqs, names, cv_run, seeds,
                             [_kind_dir(Path(args.out_dir), k, several) for k, _ in kinds])
    done: list[tuple[str, list[list]]] = []
    interrupted = False
    with tempfile.TemporaryDirectory(prefix="gflow-benchmark-") as tmp:
        work = Path(args.out_dir) if args.out_dir else Path(tmp)
        # every tracker's options and model files checked in a folder of this run's own, before a variant is
        # written (a bad --set was said after its note and the work of writing every frame) or --out-dir is
        # touched (a refused benchmark left DIR/SEQUENCE folders behind)
        check = _plans(args, seqs, names, first, stop, Path(tmp) / "check")
        start_work()  # every check done: a bad value met from here on is the benchmark failing (exit 1)
        for s in skipped:  # once every check has passed: a mistake's error is the one line on stderr
            note(s)
        say_notes(*_frames_past(args, seqs, first, stop))
        count = [0, len(kinds) * len(seeds) * (len(check[0]) + len(seqs) * len(cv_run))]
        for kind, variant in kinds:
            if several:
                note(f"footage: {_kind_words(kind)}")
            runs, interrupted = _run_kind(args, variant, seqs, names, (cv_names, cv_missing), first, stop, seeds,
                                          (_kind_dir(work, kind, several), Path(tmp) / f"variant-{kind}"), count)
            if runs:
                done.append((kind, runs))
            if interrupted:
                break
    meta = {"datasets": list(args.datasets), "sequences": [s.name for s in seqs],
            "frames": [first_frame if args.frames else None, stop], "seed": args.seed,
            "mode": "inline" if args.inline else "processes", "skipped": skipped, "interrupted": interrupted,
            "versions": versions()}
    _report_kinds(args, done, seeds, meta, several)
    return 130 if interrupted else 0


def _kind_dir(work: Path, kind: str, several: bool) -> Path:
    """Where a kind of footage's runs write: ``work`` itself with one kind, ``work/KIND`` with several."""
    return work / kind if several else work


def _kind_words(kind: str) -> str:
    return "the sequences as they are" if kind == "none" else f"the {kind} variant of every sequence"


def _run_kind(args, variant, seqs, names: list[str], cv: tuple[list[str], dict[str, str]], first: dict[str, int],
              stop: int | None, seeds: list[int], folders: tuple[Path, Path], count: list[int]
              ) -> tuple[list[list], bool]:
    """One kind of footage: its variant's frames written (under ``folders[1]``, removed after its runs; None:
    the sequences as they are), then every seed's benchmark writing under ``folders[0]``; each finished
    seed's rows, and whether the user interrupted (a seed stopped midway is left out of the means)."""
    from pipeline.evaluation.sequence_benchmark import note

    work, derived = folders
    if variant is not None:
        from pipeline.evaluation.variant_benchmark import derive_variant

        note(f"writing the {variant.name} variant of {len(seqs)} sequence(s)")
        try:
            seqs = [derive_variant(seq, variant, derived, first[seq.name], stop) for seq in seqs]
        except (ValueError, OSError) as e:
            raise CliError(f"--variant {variant.name}: {e}") from None
    try:
        # every seed's plans first: a bad option or model fails before any tracking
        planned = {k: _plans(_with_seed(args, k), seqs, names, first, stop, _seed_dir(work, k, seeds)) for k in seeds}
        runs: list[list] = []
        for seed in seeds:
            rows, interrupted = _run_seed(_with_seed(args, seed), seqs, names, cv, first, stop,
                                          _seed_dir(work, seed, seeds), planned[seed], count)
            runs.append(rows)
            if interrupted:
                if len(runs) > 1:
                    note(f"seed {seed} was interrupted: the tables hold seeds "
                         f"{', '.join(map(str, seeds[:len(runs) - 1]))}")
                    runs = runs[:-1]
                return runs, True
        return runs, False
    finally:
        if variant is not None:
            shutil.rmtree(derived, ignore_errors=True)  # a variant's frames take room: gone once its runs are


def _report_kinds(args, done: list[tuple[str, list[list]]], seeds: list[int], meta: dict, several: bool) -> None:
    """The report of one kind of footage as it always was; of several, each kind's report under a heading
    line, then the summary over every kind (:mod:`pipeline.evaluation.kinds_summary`); with --json one
    object, ``kinds`` (each kind's benchmark) and ``summary``."""
    from pipeline.evaluation.kinds_summary import format_kinds_summary, kinds_json

    if not done:
        return
    if not several:
        kind, runs = done[0]
        _report(args, runs, seeds[:len(runs)], dict(meta, variant=None if kind == "none" else kind))
        return
    full = done[:-1] if meta["interrupted"] else done  # a kind cut short by an interruption is not summed
    if args.json:
        last = len(done) - 1  # only the last kind run can have been interrupted
        print(json.dumps({"kinds": [dict(_json_of(runs, seeds[:len(runs)], dict(
                              meta, variant=kind, interrupted=meta["interrupted"] and i == last)), kind=kind)
                                    for i, (kind, runs) in enumerate(done)],
                          "summary": kinds_json(full, seeds), "seeds": seeds}))
        return
    for i, (kind, runs) in enumerate(done):
        print(("## " if args.markdown else "== ") + _kind_words(kind) + "\n")
        _report(args, runs, seeds[:len(runs)], dict(meta, variant=None if kind == "none" else kind,
                                                   interrupted=meta["interrupted"] and i == len(done) - 1))
        print()
    print(("## " if args.markdown else "== ") + "every kind of footage\n")
    print(format_kinds_summary(full, seeds, markdown=args.markdown))
    if len(full) < len(done):
        print(f"\n{done[-1][0]} was interrupted and is left out of the summary")


def _json_of(runs: list[list], seeds: list[int], meta: dict) -> dict:
    """One kind's benchmark as JSON: of one seed as :func:`.benchmark_tables.to_json` gives it, of several
    as :func:`.seed_means.seeds_json`."""
    from pipeline.evaluation.benchmark_tables import to_json
    from pipeline.evaluation.seed_means import seeds_json

    if len(seeds) > 1:
        common = {k: v for k, v in meta.items() if k != "seed"}
        return seeds_json(runs, [dict(common, seed=s) for s in seeds], seeds, common)
    return to_json(runs[0], meta)


def _report(args, runs: list[list], seeds: list[int], meta: dict) -> None:
    """The benchmark's tables (text, Markdown or JSON) on stdout, and its plots unless interrupted. With
    several seeds: each tracker's AUC with every seed first, then the tables and plots of the means over
    the seeds (:mod:`pipeline.evaluation.seed_means`); the JSON holds every seed's run and the means."""
    from pipeline.runtime.versions import version_text
    from pipeline.evaluation.benchmark_tables import format_tables
    from pipeline.evaluation.seed_means import format_seed_tables, mean_rows
    from pipeline.evaluation.sequence_benchmark import note, plot_precision, plot_success

    several = len(seeds) > 1
    rows = mean_rows(runs, seeds) if several else runs[0]
    if args.json:
        print(json.dumps(_json_of(runs, seeds, meta)))
    else:
        if several:
            print(format_seed_tables(runs, seeds, markdown=args.markdown) + "\n")
        print(format_tables(rows, markdown=args.markdown, fps=not args.no_fps))
        if meta["skipped"]:
            print("\n" + "\n".join(meta["skipped"]))
        which = (f"seeds {', '.join(map(str, seeds))} (the tables after the AUC of each seed: the means over the seeds)"
                 if several else f"seed {args.seed}")
        print(f"\n{meta['mode']}, {which}" + (f", the {meta['variant']} variant of every sequence" if meta["variant"]
                                              else "") + f"; {version_text(meta['versions'])}")
    if not meta["interrupted"]:
        of = " (the means over the seeds)" if several else ""
        for path, plot, what in ((args.plot, plot_success, "success"), (args.precision_plot, plot_precision, "precision")):
            if path:
                plot(rows, path)
                note(f"{what} plot{of}: {path}")


def register(sub) -> None:
    p = sub.add_parser(
        "benchmark", help="run trackers on sequence folders and score them, one table per tracker",
        description="Run every selected tracker on every sequence folder (frames/ and groundtruth.csv, "
                    "optionally results/*.csv of published trackers) from the ground-truth box of the first frame, "
                    "exactly as `gflow track` does, and score it as `gflow eval` does, on the frames that have a "
                    "ground-truth box. Prints one table per tracker, a row per sequence and the mean over them: "
                    "AUC of the OTB success plot (the headline), precision at 20 px, CLE (px), success (IoU > 0.5) "
                    "and fps (frames / wall time of tracking); beside each tracker's figures the AUC of the "
                    "OpenCV trackers run, of a box that never moves and of the best published tracker, each of "
                    "which gets its own table too. --json has every row (also the mean overlap and 'size within "
                    "2x') and the means.",
        epilog="examples: gflow benchmark ../shared/data --trackers chamfer --plot success.png; "
               "gflow benchmark ../shared/data --stress --trackers appearance --inline --markdown; "
               "gflow benchmark ../shared/data --variant all --trackers dcf --opencv csrt,kcf --inline --seeds 1-3 "
               "(every kind of footage, summed up per tracker)")
    p.add_argument("datasets", nargs="*", metavar="DATASET",
                   help="a sequence folder (frames/ + groundtruth.csv) or a folder of them")
    p.add_argument("--trackers", metavar="NAME,...",
                   help=f"trackers to run (default all: {', '.join(sorted(TRACKERS))})")
    p.add_argument("--seed", type=nonnegative_int, help="random seed of every run (default 1)")
    p.add_argument("--seeds", metavar="LIST",
                   help="run the whole benchmark once per seed (1,2,3 or 1-5) and print each tracker's AUC with every "
                        "seed, their mean, lowest and highest, then the usual tables of the means over the seeds "
                        "(with --stress: each seed's tables in turn, then each seed's cases got back and reported states "
                        "side by side); one result can hang on one frame where a "
                        "look-alike takes the target with one seed and not with another")
    p.add_argument("--frames", metavar="A:B", help="track frames A to B-1 only, from the ground-truth box of frame A "
                                                    "(default: every frame from the first ground-truth box)")
    p.add_argument("--inline", action="store_true", help="run each tracker in this process instead of as processes")
    add_model_options(p, "run")
    p.add_argument("--set", action="append", metavar="STAGE.PARAM=VALUE", help="a parameter for every run: of the tracker (tracker.particles=1000) or of one stage; repeatable")
    p.add_argument("--opencv", metavar="NAME,...",
                   help="also run OpenCV trackers (csrt, kcf, mil, ...) where this OpenCV has them (none: no "
                        "OpenCV tracker)")
    form = p.add_mutually_exclusive_group()  # --markdown with --json printed JSON alone, without a word
    form.add_argument("--json", action="store_true", help="print JSON instead of the table")
    form.add_argument("--markdown", action="store_true", help="print the tables as Markdown")
    p.add_argument("--no-fps", action="store_true",
                   help="leave the frames/s out of the tables (for tables kept beside other measurements: speed "
                        "depends on the machine and its load; docs/performance.md measures it)")
    p.add_argument("--plot", metavar="PNG", help="write the success plot (success rate against overlap threshold)")
    p.add_argument("--precision-plot", metavar="PNG", help="write the precision plot (against centre error)")
    p.add_argument("--out-dir", metavar="DIR",
                   help="keep every run's boxes (DIR/SEQUENCE/TRACKER.csv) and recording (.mcap); "
                        "default: a temporary folder, removed at the end")
    p.add_argument("-q", "--quiet", action="store_true", help="no per-frame progress (one line per run still)")
    p.add_argument("--sequences", metavar="NAME,...", help="only these sequences of the datasets (default all)")
    from gflow_core.evaluation.variants import SUITE, VARIANTS

    p.add_argument("--variant", metavar="NAME[,NAME...]",
                   help="run every tracker, OpenCV tracker and the box that never moves on a variant of every "
                        "sequence instead of the sequence itself, its frames written to a temporary folder removed "
                        "at the end (published results are left out: they were made on the originals). "
                        + "; ".join(f"{v.name}: {v.describe}" for v in VARIANTS.values())
                        + ". Several join with '+' and apply in turn: fast+blur is fast motion with blur. Several "
                          "kinds of footage separated by commas run one after another ('none': the sequences as "
                          f"they are; 'all': {', '.join(SUITE)}), each reported as its own run would be (with "
                          "--out-dir under DIR/KIND), then a summary per tracker: its mean AUC on each kind and "
                          "the cells (sequence x seed) where it is below an OpenCV tracker or at or below the "
                          "box that never moves")
    s = p.add_argument_group("stress benchmark (docs/stress.md)")
    s.add_argument("--stress", action="store_true",
                   help="run the trackers on stress cases derived from every sequence (occlusion, roll, change of "
                        "look, darkening, blur, fast motion, leaving the frame) and score how they get the target "
                        "back; OpenCV's CSRT runs beside them unless --opencv says otherwise (--opencv none: no "
                        "OpenCV tracker)")
    s.add_argument("--cases", metavar="NAME,...",
                   help="only these stress cases (a name, or a kind such as occlude or roll-camera; see --list-cases)")
    s.add_argument("--list-cases", action="store_true", help="print the stress cases (with --cases, those it names) "
                                                             "and exit")
    s.add_argument("--lead", type=whole_number, default=30, metavar="N",
                   help="frames tracked before each stress window (default 30)")
    s.add_argument("--tail", type=whole_number, default=60, metavar="N",
                   help="frames tracked after each stress window (default 60; the 'after' score starts 10 frames "
                        "after the window)")
    s.add_argument("--stress-cache", metavar="DIR",
                   help="keep the derived sequences in DIR and reuse them on the next run (default: a temporary "
                        "folder, removed at the end)")
    p.set_defaults(func=cmd_benchmark)
