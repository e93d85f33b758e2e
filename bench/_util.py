"""Small helpers shared by the benchmarks (percentiles, tables)."""

from __future__ import annotations

import numpy as np


def pct(values, q) -> float:
    return float(np.percentile(np.asarray(values, dtype=np.float64), q)) if len(values) else float("nan")


def table(rows: list[list], header: list[str]) -> str:
    cols = [header] + [[str(c) for c in r] for r in rows]
    widths = [max(len(r[i]) for r in cols) for i in range(len(header))]
    lines = ["  ".join(h.ljust(w) for h, w in zip(header, widths)), "  ".join("-" * w for w in widths)]
    lines += ["  ".join(c.ljust(w) for c, w in zip(r, widths)) for r in cols[1:]]
    return "\n".join(lines)


def scratch(prefix: str, keep: str | None = None):
    """A temporary folder for what a benchmark writes (frames, recordings, models), deleted when
    the benchmark exits, also on an error or Ctrl-C. ``keep`` (or GFLOW_BENCH_KEEP=1) keeps it."""
    import atexit
    import os
    import shutil
    import tempfile
    from pathlib import Path

    if keep:
        p = Path(keep)
        p.mkdir(parents=True, exist_ok=True)
        return p
    p = Path(tempfile.mkdtemp(prefix=prefix))
    if not os.environ.get("GFLOW_BENCH_KEEP"):
        atexit.register(shutil.rmtree, p, ignore_errors=True)
    return p


def every_nth(series: dict, frames: int, fmt, step: int = 20) -> list[list]:
    """Rows ``[frame, cell per series]`` every ``step``-th frame: ``fmt(values)`` of the runs' values at
    that frame (``series``: name -> list of per-run (frames,) arrays)."""
    rows = []
    for f in range(0, frames, step):
        rows.append([f] + [fmt(np.array([e[f] for e in runs])) for runs in series.values()])
    return rows



def gflow_plan(source: dict, params: dict, **filter_extra):
    """The plan of the built-in gflow graph on ``source``: the G-flow parameters among ``params`` go to
    its tracker block (set once for every stage, as ``--set tracker.NAME=V`` sets them), the others
    (``init``, ``seed``) to the proposal and filter stages; ``filter_extra`` (``shards``) to the filter."""
    import dataclasses

    from gflow_core.gflow import GFlowParams
    from pipeline.cli.trackers.gflow import make_plan

    names = {f.name for f in dataclasses.fields(GFlowParams)}
    block = {k: v for k, v in params.items() if k in names}
    stage = {k: v for k, v in params.items() if k not in names}
    return make_plan("gflow", {"source": source, "tracker": block, "proposal": dict(stage),
                               "filter": dict(stage, **filter_extra)})


def gflow_sets(items: list[str]) -> dict:
    """The G-flow parameters of ``--gflow-set NAME=VALUE`` items (values read as YAML scalars, converted as
    ``gflow track`` converts them); one that is not NAME=VALUE, names no G-flow parameter or gives it a
    value G-flow refuses (the settings together) exits with a one-line error, before any work."""
    import dataclasses

    import msgspec
    import yaml

    from gflow_core.gflow import GFlowParams
    from pipeline.runtime.tracker_block import plain_type_error

    known = {f.name for f in dataclasses.fields(GFlowParams)}
    values = {}
    for it in items:
        name, eq, value = it.partition("=")
        if not eq:
            raise SystemExit(f"--gflow-set expects NAME=VALUE, got {it!r}")
        if name.strip() not in known:
            raise SystemExit(f"--gflow-set {it}: G-flow has no parameter {name.strip()!r} (`gflow info gflow` lists them)")
        try:
            values[name.strip()] = yaml.safe_load(value)
        except yaml.YAMLError:
            raise SystemExit(f"--gflow-set {it}: {value!r} is not a value") from None
    try:
        # as `gflow track` converts them (pipeline.runtime.tracker_block: not strict), so 3e-3, which YAML
        # reads as a string, is the number it is there too
        converted = msgspec.convert(values, GFlowParams, strict=False)
    except (msgspec.ValidationError, ValueError, TypeError) as e:
        raise SystemExit(f"--gflow-set {' '.join(items)}: {plain_type_error(str(e), values)}") from None
    return {k: getattr(converted, k) for k in values}


def checkout(ap, path: str):
    """``--compare DIR`` resolved, or ``ap.error`` (one line, before any work) when DIR is not a gflow checkout:
    a run there would import the installed gflow instead and compare this code with itself."""
    from pathlib import Path

    p = Path(path).resolve()
    if not (p / "pipeline" / "cli" / "main.py").is_file():
        ap.error(f"--compare {path}: not a gflow checkout (no pipeline/cli/main.py there)")
    return p
