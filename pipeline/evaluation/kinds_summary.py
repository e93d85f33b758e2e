"""``gflow benchmark --variant none,grey,fast,...``: several kinds of footage in one run, and where each
tracker falls behind.

A tracker tuned on one kind of footage can lose on another (grey video, a blurring camera, a target
faster than the frames come, a small one), so a change is judged on every kind together: the
sequences as they are (``none``) and each variant of them (:data:`gflow_core.evaluation.variants.SUITE`
with ``--variant all``). Each kind is a whole benchmark, once per seed; this module sums them up.

For each of our trackers, one row per kind: the AUC averaged over the sequences, with every seed and
their mean, and the cells (sequence x seed) where the tracker is *behind*: its AUC below an OpenCV
tracker's of the same run (same sequence, same seed, same frames) or at or below the box that never
moves. A run that failed is counted as behind, named "not scored". A last row sums every kind: the
mean of the kinds' means and the cells behind over all of them. The comparisons are those of this run
only (none is read from elsewhere): without ``--opencv`` trackers the only comparison is the still box,
and the summary says so.
"""

from __future__ import annotations

import numpy as np

from pipeline.evaluation.benchmark_tables import _short, mean_of, names_of, scored, table, title
from pipeline.evaluation.seed_means import _cell
from pipeline.evaluation.sequence_benchmark import Row

__all__ = ["Kind", "behind", "format_kinds_summary", "kinds_json"]

#: a kind of footage and its runs: (name, one list of rows per seed)
Kind = tuple[str, list[list[Row]]]


def behind(rows: list[Row], tracker: str) -> list[tuple[str, float | None, str, float | None]]:
    """The sequences of one run (one seed, one kind) where ``tracker`` is behind (module docstring), each
    as (sequence, its AUC or None if not scored, the comparison it is behind, that comparison's AUC)."""
    ok = {(r.sequence, r.tracker): r for r in scored(rows)}
    out: list[tuple[str, float | None, str, float | None]] = []
    for seq in dict.fromkeys(r.sequence for r in rows if r.tracker == tracker):
        mine = ok.get((seq, tracker))
        if mine is None or mine.auc is None:
            out.append((seq, None, "not scored", None))
            continue
        cv = [r for r in scored(rows) if r.sequence == seq and r.kind == "opencv"]
        best = max(cv, key=lambda r: r.auc or 0.0) if cv else None
        still = ok.get((seq, "static box"))
        if best is not None and best.auc is not None and mine.auc < best.auc:
            out.append((seq, mine.auc, _short(best.tracker), best.auc))
        elif still is not None and still.auc is not None and mine.auc <= still.auc:
            out.append((seq, mine.auc, "still box", still.auc))
    return out


def _mean_auc(rows: list[Row], tracker: str) -> float | None:
    mine = [r for r in rows if r.tracker == tracker]
    m = mean_of(mine, len(mine))
    return None if m is None or m.sequences < len(mine) else m.auc


def _where(cells: list[tuple[int, tuple[str, float | None, str, float | None]]], several: bool) -> str:
    """The cells behind in words: ``david_indoor seed 3 (0.702; CSRT 0.774)``."""
    words = []
    for seed, (seq, auc, what, ref) in cells:
        at = f" seed {seed}" if several else ""
        words.append(f"{seq}{at} (not scored)" if auc is None else f"{seq}{at} ({auc:.3f}; {what} {ref:.3f})")
    return ", ".join(words)


def _tracker_rows(kinds: list[Kind], seeds: list[int], name: str) -> tuple[list[list[str]], list[dict]]:
    """One tracker's summary: a table row and a JSON object per kind, then the row over every kind."""
    cells, objs, all_means = [], [], []
    total, total_of = 0, 0
    for kind, runs in kinds:
        means = [_mean_auc(run, name) for run in runs]
        hits = [(s, b) for s, run in zip(seeds, runs) for b in behind(run, name)]
        n = sum(len([r for r in run if r.tracker == name]) for run in runs)
        got = [m for m in means if m is not None]
        mean = float(np.mean(got)) if got and len(got) == len(means) else None
        if mean is not None:
            all_means.append(mean)
        total, total_of = total + len(hits), total_of + n
        cells.append(["as they are" if kind == "none" else kind, _cell(mean)] + ([_cell(m) for m in means] if len(seeds) > 1 else [])
                     + [f"{len(hits)} of {n}", _where(hits, len(seeds) > 1)])
        objs.append({"kind": kind, "auc": None if mean is None else round(mean, 4),
                     "auc_per_seed": [None if m is None else round(m, 4) for m in means],
                     "behind": [{"sequence": b[0], "seed": s, "auc": None if b[1] is None else round(b[1], 4),
                                 "behind": b[2], "its_auc": None if b[3] is None else round(b[3], 4)} for s, b in hits],
                     "cells": n})
    every = float(np.mean(all_means)) if len(all_means) == len(kinds) else None
    cells.append([f"every kind ({len(kinds)})", _cell(every)] + ([""] * len(seeds) if len(seeds) > 1 else [])
                 + [f"{total} of {total_of}", ""])
    return cells, objs


def format_kinds_summary(kinds: list[Kind], seeds: list[int], markdown: bool = False) -> str:
    """Each of our trackers over every kind of footage of the run (module docstring), one table each."""
    rows = [r for _, runs in kinds for run in runs for r in run]
    cv = names_of(scored(rows), "opencv")  # those that ran: one this OpenCV lacks is no comparison
    against = (f"below {', '.join(_short(c) for c in cv)} or " if cv else "") + "at or below the box that never moves"
    note = "" if cv else " (no OpenCV tracker ran: --opencv csrt,kcf compares with them where OpenCV has them)"
    seed_head = [f"seed {s}" for s in seeds] if len(seeds) > 1 else []
    head = ["footage", "AUC" + (" (mean of the seeds)" if len(seeds) > 1 else "")] + seed_head + ["behind", "where"]
    out = []
    for name in names_of(rows, "tracker"):
        cells, _ = _tracker_rows(kinds, seeds, name)
        what = f"over every kind of footage: the AUC averaged over the sequences; behind: {against}{note}"
        out += [title(name, what, markdown), "", table(head, cells, markdown, left={0, len(head) - 1}), ""]
    return "\n".join(out).rstrip()


def kinds_json(kinds: list[Kind], seeds: list[int]) -> dict:
    """The summary as JSON: per tracker, per kind its mean AUC (and per seed) and the cells behind."""
    rows = [r for _, runs in kinds for run in runs for r in run]
    return {name: _tracker_rows(kinds, seeds, name)[1] for name in names_of(rows, "tracker")}
