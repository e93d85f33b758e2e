"""The tables and the JSON of ``gflow benchmark``: one table per tracker, AUC as the headline, the mean
over sequences.

Each of our trackers gets a table whose rows are the sequences and whose columns are the
OTB success-plot AUC (the headline), precision at 20 px, centre location error, success
(IoU > 0.5) and frames/s, with a last row of the mean over the sequences it was scored on.
Beside its figures, on the same row, stand the AUCs of what a user compares it with: every
OpenCV tracker that ran, the box that never moves, and the best published tracker on that
sequence where the data has published results. Then each of those gets a table of its own in
the same columns, the published trackers one table together, and a last table gives every
tracker's means side by side.

The means are plain averages over sequences (each sequence counts once, however long); a
tracker that was not scored on every sequence says over how many. The comparison columns of a
mean row average over the same sequences as the tracker's own mean.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from gflow_core.evaluation.metrics import OVERLAP_THRESHOLDS

from pipeline.evaluation.sequence_benchmark import PRECISION_AT, Row

__all__ = ["format_tables", "means_json", "to_json", "Mean", "mean_of", "scored", "names_of", "table", "title"]


@dataclass(frozen=True)
class Mean:
    """A tracker's figures averaged over the sequences it was scored on."""

    sequences: int  # scored on
    of: int  # in the run
    auc: float
    precision: float  # at PRECISION_AT px
    cle: float
    success: float

    def to_json(self) -> dict:
        return {"sequences": self.sequences, "of": self.of, "auc": round(self.auc, 4),
                f"precision_{PRECISION_AT}": round(self.precision, 4), "cle_px": round(self.cle, 3),
                "success_rate_0.5": round(self.success, 4)}


def scored(rows: list[Row]) -> list[Row]:
    return [r for r in rows if r.score is not None and r.auc is not None and r.precision_at is not None]


def mean_of(rows: list[Row], of: int) -> Mean | None:
    """The mean of the scored ``rows`` (one tracker, one row per sequence), or None if none is scored."""
    ok = scored(rows)
    if not ok:
        return None
    return Mean(sequences=len(ok), of=of, auc=float(np.mean([r.auc for r in ok])),
                precision=float(np.mean([r.precision_at for r in ok])),
                cle=float(np.mean([r.score.cle for r in ok if r.score is not None])),
                success=float(np.mean([r.score.success for r in ok if r.score is not None])))


def _f(v: float | None, fmt: str) -> str:
    return "-" if v is None or not math.isfinite(v) else format(v, fmt)


def names_of(rows: list[Row], kind: str) -> list[str]:
    return list(dict.fromkeys(r.tracker for r in rows if r.kind == kind))


def _short(name: str) -> str:
    """A comparison's column name: ``opencv csrt`` -> ``CSRT``."""
    return name.removeprefix("opencv ").upper() if name.startswith("opencv ") else name


def _best_published(rows: list[Row], seq: str) -> Row | None:
    pub = [r for r in scored(rows) if r.sequence == seq and r.kind == "published"]
    return max(pub, key=lambda r: r.auc or 0.0) if pub else None


def _figures(r: Row | None, fps: bool) -> list[str]:
    s = None if r is None else r.score
    cells = ["-" if s is None else str(s.frames), _f(None if r is None else r.auc, ".3f"),
             _f(None if r is None else r.precision_at, ".3f"), _f(None if s is None else s.cle, ".2f"),
             _f(None if s is None else s.success, ".3f")]
    return cells + ([_f(None if r is None else r.fps, ".1f")] if fps else [])


def _mean_figures(m: Mean | None, fps: bool) -> list[str]:
    if m is None:
        return ["-"] * (6 if fps else 5)
    cells = ["", _f(m.auc, ".3f"), _f(m.precision, ".3f"), _f(m.cle, ".2f"), _f(m.success, ".3f")]
    return cells + (["-"] if fps else [])


def _mean_label(m: Mean | None, n: int) -> str:
    if m is None or m.sequences == n:
        return f"mean of {n}"
    return f"mean of {m.sequences} (of {n})"


def _head(fps: bool) -> list[str]:
    return ["sequence", "frames scored", "AUC", f"prec@{PRECISION_AT}", "CLE px", "success"] + (["fps"] if fps else [])


def table(head: list[str], cells: list[list[str]], markdown: bool, left: set[int]) -> str:
    """A table as Markdown or as aligned text (columns in ``left`` left-aligned, the others right); a
    last column ``note`` that is empty on every row is left out."""
    if head[-1] == "note" and not any(c[-1] for c in cells):
        head, cells = head[:-1], [c[:-1] for c in cells]
    if markdown:
        return "\n".join(["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
                         + ["| " + " | ".join(c) + " |" for c in cells])
    widths = [max(len(h), *(len(c[i]) for c in cells)) if cells else len(h) for i, h in enumerate(head)]

    def line(c: list[str]) -> str:
        return "  ".join(v.ljust(w) if i in left else v.rjust(w) for i, (v, w) in enumerate(zip(c, widths))).rstrip()

    return "\n".join([line(head), line(["-" * w for w in widths])] + [line(c) for c in cells])


def title(name: str, what: str, markdown: bool) -> str:
    return f"**{name}** ({what})" if markdown else f"{name} ({what})"


def _tracker_table(rows: list[Row], name: str, seqs: list[str], others: list[str], has_published: bool,
                   markdown: bool, fps: bool) -> str:
    """One of our trackers: its figures per sequence, the comparisons' AUC beside them, the mean."""
    by = {(r.sequence, r.tracker): r for r in rows}
    head = _head(fps) + [f"{_short(o)} AUC" for o in others] + (["best published AUC"] if has_published else []) \
        + ["note"]
    cells = []
    for seq in seqs:
        r = by.get((seq, name))
        best = _best_published(rows, seq)
        cells.append([seq] + _figures(r, fps) + [_f(getattr(by.get((seq, o)), "auc", None), ".3f") for o in others]
                     + ([f"{best.tracker} {best.auc:.3f}" if best is not None and best.auc is not None else "-"]
                        if has_published else []) + [r.note if r is not None else ""])
    mine = [by[seq, name] for seq in seqs if (seq, name) in by]
    m = mean_of(mine, len(seqs))
    on = [r.sequence for r in scored(mine)]
    beside = []
    for o in others:
        theirs = [by[s, o] for s in on if (s, o) in by]
        mo = mean_of(theirs, len(on))
        beside.append("-" if mo is None or mo.sequences < len(on) else f"{mo.auc:.3f}")
    cells.append([_mean_label(m, len(seqs))] + _mean_figures(m, fps) + beside + (["-"] if has_published else [])
                 + [""])
    return table(head, cells, markdown, left={0, len(head) - 1})


def _plain_table(rows: list[Row], name: str, seqs: list[str], markdown: bool, fps: bool) -> str:
    """A comparison tracker (OpenCV's, the box that never moves): its figures per sequence and the mean."""
    by = {r.sequence: r for r in rows if r.tracker == name}
    head = _head(fps) + ["note"]
    cells = [[seq] + _figures(by.get(seq), fps) + [by[seq].note if seq in by else ""] for seq in seqs if seq in by]
    m = mean_of(list(by.values()), len(seqs))
    cells.append([_mean_label(m, len(seqs))] + _mean_figures(m, fps) + [""])
    return table(head, cells, markdown, left={0, len(head) - 1})


def _published_table(rows: list[Row], markdown: bool) -> str:
    head = ["sequence", "tracker"] + _head(False)[1:] + ["note"]
    cells = [[r.sequence, r.tracker] + _figures(r, False) + [r.note] for r in rows if r.kind == "published"]
    return table(head, cells, markdown, left={0, 1, len(head) - 1})


def _means_table(rows: list[Row], seqs: list[str], markdown: bool) -> str:
    """Every tracker's means side by side; for ours, on how many sequences its AUC is above the
    static box's, and on which it is below each comparison's."""
    auc = {(r.sequence, r.tracker): float(r.auc) for r in scored(rows) if r.auc is not None}
    still = {r.sequence: auc[r.sequence, r.tracker] for r in scored(rows) if r.kind == "baseline"}
    others = names_of(rows, "opencv") + names_of(rows, "baseline")
    head = ["tracker", "kind", "sequences", "AUC", f"prec@{PRECISION_AT}", "CLE px", "success", "AUC above static box"] \
        + [f"AUC below {_short(o)} on" for o in others]
    cells = []
    for kind in ("tracker", "opencv", "baseline"):
        for name in names_of(rows, kind):
            m = mean_of([r for r in rows if r.tracker == name], len(seqs))
            mine = {q: a for (q, n), a in auc.items() if n == name}
            above = sum(q in still and a > still[q] for q, a in mine.items())
            vs = "-" if kind == "baseline" else f"{above} of {sum(q in still for q in mine)}"
            below = [", ".join(q for q, a in mine.items() if (q, o) in auc and auc[q, o] > a) or "none"
                     if kind == "tracker" else "-" for o in others]
            cells.append([name, kind, "0" if m is None else str(m.sequences)] + _mean_figures(m, False)[1:] + [vs]
                         + below)
    return table(head, cells, markdown, left={0, 1} | set(range(8, len(head))))


def format_tables(rows: list[Row], markdown: bool = False, fps: bool = True) -> str:
    """Every table of a benchmark run (see the module docstring); ``fps=False`` leaves out frames/s."""
    seqs = list(dict.fromkeys(r.sequence for r in rows))
    ours, cv = names_of(rows, "tracker"), names_of(rows, "opencv")
    others = cv + names_of(rows, "baseline")
    has_published = any(r.kind == "published" for r in rows)
    out: list[str] = []
    beside = ", ".join(_short(o) for o in others) + (", best published" if has_published else "")
    for name in ours:
        out += [title(name, "tracker" + (f"; beside it the AUC of {beside}" if beside else ""), markdown), "",
                _tracker_table(rows, name, seqs, others, has_published, markdown, fps), ""]
    for name in others:
        kind = next(r.kind for r in rows if r.tracker == name)
        out += [title(name, {"opencv": "OpenCV", "baseline": "the first box, held still"}.get(kind, kind), markdown),
                "", _plain_table(rows, name, seqs, markdown, fps), ""]
    if has_published:
        out += [title("published trackers", "their published boxes, scored the same way", markdown), "",
                _published_table(rows, markdown), ""]
    if len(ours) + len(others) > 1:
        out += [title("means over the sequences", "every tracker", markdown), "",
                _means_table(rows, seqs, markdown), ""]
    return "\n".join(out).rstrip()


def means_json(rows: list[Row]) -> dict:
    """Each tracker's (ours, OpenCV's, the box that never moves) mean over the sequences, for the JSON."""
    seqs = list(dict.fromkeys(r.sequence for r in rows))
    out = {}
    for kind in ("tracker", "opencv", "baseline"):
        for name in names_of(rows, kind):
            m = mean_of([r for r in rows if r.tracker == name], len(seqs))
            out[name] = None if m is None else m.to_json()
    return out


def to_json(rows: list[Row], meta: dict) -> dict:
    """The benchmark as JSON: ``meta`` plus one object per row (scores as ``gflow eval --json``)."""
    out = []
    for r in rows:
        d: dict = {"sequence": r.sequence, "tracker": r.tracker, "kind": r.kind}
        if r.score is not None:
            d.update(r.score.to_json())
            auc = r.auc
            assert auc is not None and r.curve is not None  # score_row gives a scored row its curve
            d["auc"] = round(auc, 4)
            d["success_curve"] = [round(float(v), 4) for v in r.curve]
            d["size_within_2x"] = None if r.size_2x is None else round(r.size_2x, 4)
            d[f"precision_{PRECISION_AT}"] = None if r.precision_at is None else round(r.precision_at, 4)
        d["fps"] = None if r.fps is None else round(r.fps, 2)
        if r.seconds is not None:
            d["seconds"] = round(r.seconds, 3)
        if r.seconds_total is not None:
            d["seconds_total"] = round(r.seconds_total, 3)
        if r.note:
            d["note"] = r.note
        if r.boxes_csv:
            d["boxes"] = r.boxes_csv
        d.update(r.extra)
        out.append(d)
    return dict(meta, overlap_thresholds=[round(float(t), 4) for t in OVERLAP_THRESHOLDS], rows=out,
                means=means_json(rows))
