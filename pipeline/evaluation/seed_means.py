"""``gflow benchmark --seeds 1,2,3``: the benchmark run once per seed, and what the seeds agree on.

A particle filter's result on one sequence can hang on one frame where the posterior is split
between the target and a look-alike: one seed keeps the target, the next takes the look-alike, and
a change judged on one seed may be judged on that frame alone. So the benchmark can run every
tracker once per seed and report, per tracker and sequence, the AUC of every seed, their mean, the
lowest and the highest; and one table per tracker in the usual form (:mod:`.benchmark_tables`) of the
means over the seeds.

The mean of a row over the seeds averages its success curve, its precision curve, its CLE, mean
overlap and success rate, and its frames/s; the AUC of the mean curve is the mean of the seeds'
AUCs (the AUC is the curve's mean). A row that was not scored on every seed (a run that failed) is
not averaged: its mean row says on which seeds it was not scored, so a mean never hides a failure.
The box that never moves and the published trackers do not depend on the seed; they are averaged as
the rest (the same figures).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from gflow_core.evaluation.metrics import TrackScore

from pipeline.evaluation.benchmark_tables import mean_of, names_of, scored, table, title, to_json
from pipeline.evaluation.sequence_benchmark import Row

__all__ = ["parse_seeds", "mean_rows", "format_seed_tables", "seeds_json"]

#: at most this many seeds in one run (each is a whole benchmark)
MAX_SEEDS = 100


def parse_seeds(text: str) -> list[int]:
    """The seeds of ``--seeds``: comma-separated whole numbers >= 0 and ranges ``A-B`` (inclusive):
    ``1,2,3``, ``1-5``, ``0,4-6``. ValueError (one line) for anything else, a repeated seed or more than
    :data:`MAX_SEEDS`."""
    seeds: list[int] = []
    for part in (p.strip() for p in text.split(",")):
        a, sep, b = part.partition("-")
        try:
            lo, hi = (int(a), int(b)) if sep else (int(part), int(part))
        except ValueError:
            raise ValueError(f"--seeds {text}: {part!r} is not a seed (a whole number >= 0) or a range A-B") from None
        if lo < 0 or hi < lo:
            raise ValueError(f"--seeds {text}: {part!r} is not a seed >= 0 or a range A-B with A <= B")
        if hi - lo >= MAX_SEEDS:
            raise ValueError(f"--seeds {text}: more than {MAX_SEEDS} seeds")
        seeds += range(lo, hi + 1)
    twice = sorted({s for s in seeds if seeds.count(s) > 1})
    if twice:
        raise ValueError(f"--seeds {text}: seed {twice[0]} is given twice")
    if len(seeds) > MAX_SEEDS:
        raise ValueError(f"--seeds {text}: more than {MAX_SEEDS} seeds")
    return seeds


def _mean_row(rows: list[Row | None], seeds: list[int]) -> Row:
    """One (sequence, tracker)'s rows of every seed (None: absent on that seed) as one row of their means."""
    first = next(r for r in rows if r is not None)
    missing = [s for s, r in zip(seeds, rows) if r is None or r.curve is None or r.score is None or r.precision is None]
    if missing:
        why = next((r.note for r in rows if r is not None and r.note), "")
        note = f"not scored with seed {', '.join(map(str, missing))}" + (f" ({why})" if why else "")
        return Row(first.sequence, first.tracker, first.kind, note=note)
    ok = [r for r in rows if r is not None]
    sc = [r.score for r in ok if r.score is not None]
    score = TrackScore(frames=sc[0].frames, cle=float(np.mean([s.cle for s in sc])),
                       mean_overlap=float(np.mean([s.mean_overlap for s in sc])),
                       success=float(np.mean([s.success for s in sc])),
                       missing=int(round(float(np.mean([s.missing for s in sc])))))
    fps = [r.fps for r in ok if r.fps is not None]
    size = [r.size_2x for r in ok if r.size_2x is not None]
    curves = [r.curve for r in ok if r.curve is not None]
    precisions = [r.precision for r in ok if r.precision is not None]
    return replace(first, score=score, curve=np.mean(curves, axis=0), precision=np.mean(precisions, axis=0),
                   size_2x=float(np.mean(size)) if len(size) == len(ok) else None,
                   fps=float(np.mean(fps)) if len(fps) == len(ok) else None, seconds=None, seconds_total=None,
                   note="", boxes_csv=None, extra={})


def mean_rows(runs: list[list[Row]], seeds: list[int]) -> list[Row]:
    """The rows of one benchmark run per seed (``runs[i]`` with ``seeds[i]``) as one list of rows of their
    means over the seeds, in the first run's order (see the module docstring)."""
    keys = list(dict.fromkeys((r.sequence, r.tracker) for run in runs for r in run))
    by = [{(r.sequence, r.tracker): r for r in run} for run in runs]
    return [_mean_row([b.get(k) for b in by], seeds) for k in keys]


def _auc(r: Row | None) -> float | None:
    return None if r is None or r.auc is None else r.auc


def _cell(v: float | None) -> str:
    return "-" if v is None or not math.isfinite(v) else f"{v:.3f}"


def _auc_table(runs: list[list[Row]], seeds: list[int], name: str, markdown: bool) -> str:
    """One tracker's AUC on every sequence with every seed, their mean, lowest and highest; a last row of
    the mean over the sequences of each seed (over those scored on every seed)."""
    seqs = list(dict.fromkeys(r.sequence for run in runs for r in run))
    by = [{r.sequence: r for r in run if r.tracker == name} for run in runs]
    head = ["sequence"] + [f"seed {s}" for s in seeds] + ["mean", "lowest", "highest"]
    cells, every = [], []
    for seq in seqs:
        a = [_auc(b.get(seq)) for b in by]
        got = [v for v in a if v is not None]
        full = len(got) == len(a)
        if full:
            every.append(seq)
        cells.append([seq] + [_cell(v) for v in a] + ([_cell(float(np.mean(got))), _cell(min(got)), _cell(max(got))]
                                                       if full else ["-", "-", "-"]))
    per_seed = [mean_of([b[q] for q in every], len(every)) for b in by]
    means = [m.auc for m in per_seed if m is not None]
    if every and len(means) == len(seeds):
        cells.append([f"mean of {len(every)}" + (f" (of {len(seqs)})" if len(every) < len(seqs) else "")]
                     + [_cell(v) for v in means] + [_cell(float(np.mean(means))), _cell(min(means)), _cell(max(means))])
    return table(head, cells, markdown, left={0})


def format_seed_tables(runs: list[list[Row]], seeds: list[int], markdown: bool = False) -> str:
    """The AUC of every seed, one table per tracker (ours and OpenCV's) that ran (see the module docstring)."""
    rows = [r for run in runs for r in run]
    out: list[str] = []
    for kind in ("tracker", "opencv"):
        for name in names_of(rows, kind):
            if not scored([r for r in rows if r.tracker == name]):
                continue
            out += [title(name, f"AUC with each seed: {', '.join(map(str, seeds))}", markdown), "",
                    _auc_table(runs, seeds, name, markdown), ""]
    return "\n".join(out).rstrip()


def seeds_json(runs: list[list[Row]], metas: list[dict], seeds: list[int], meta: dict) -> dict:
    """The benchmark of several seeds as JSON: ``meta``, ``seeds``, ``runs`` (each seed's benchmark as
    :func:`.benchmark_tables.to_json` gives it) and ``mean`` (the rows of the means over the seeds, in the
    same form)."""
    return dict(meta, seeds=seeds, runs=[to_json(rows, m) for rows, m in zip(runs, metas)],
                mean=to_json(mean_rows(runs, seeds), dict(meta, seeds=seeds)))
