"""Where a run of the application layer records (:class:`RecordingTarget`).
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Iterable

from pipeline.runtime.graph import Plan
from pipeline.app.request import RequestError

__all__ = ["RecordingTarget", "temporary_recording"]

def _refuse_unmatched(plan: Plan, patterns: list[str]) -> None:
    """Refuse a ``--record-topics`` pattern that names no topic of the run (a mistyped name would
    otherwise keep only the errors and heartbeats, and say so only when the recording is read)."""
    import fnmatch

    full = {plan.error_topic, plan.control_topic}
    for name, sp in plan.stages.items():
        full |= {*sp.outputs.values(), plan.snapshot_topic(name), plan.status_topic(name)}
    from pipeline.runtime.live_plan import SKIPPED_TOPIC, live_source

    names = sorted(t.split("/", 2)[2] for t in full if t.count("/") >= 2) + ["captures"]
    if live_source(plan) is not None:
        names.append(SKIPPED_TOPIC)  # the frames a live source skips: published when it is recorded
    for pat in patterns:
        if not any(fnmatch.fnmatchcase(n, pat) for n in names):
            raise RequestError(f"--record-topics: {pat!r} names no topic of the run (its topics: "
                               f"{', '.join(n for n in names if not n.startswith('_'))})")


# -- where a run records --------------------------------------------------------------------------


class RecordingTarget:
    """Where a run records: ``record`` (a path; None: ``default``, or the graph's own name made when
    the run starts), ``no_record`` and ``record_topics`` (shell patterns).

    ``needed`` are topics read back after the run: they are always recorded, and with
    ``no_record`` they go to a temporary file that :meth:`cleanup` deletes; with nothing needed,
    ``no_record`` removes the recorder stage. ``path`` is what to pass to the launcher (None: no
    recorder).
    """

    def __init__(self, plan: Plan, record: str | None, no_record: bool, record_topics: Iterable[str],
                 default: str | None, needed: tuple[str, ...] = ()) -> None:
        import tempfile

        self.tmpdir: str | None = None
        self.temporary = False
        self.given = bool(record)
        rec = plan.recorder()
        items = list(record_topics)
        pats = [p.strip() for item in items for p in item.split(",") if p.strip()]
        if items and not pats:  # --record-topics '' (an empty shell variable): it chose nothing, not everything
            raise RequestError(f"--record-topics {','.join(items)!r} names no topic (give shell patterns, e.g. "
                               "'estimate,particles', or '*' for every topic)")
        if pats and no_record:  # the patterns would be dropped without a word
            raise RequestError("--record-topics chooses the topics of the recording, and --no-record keeps none: "
                               "give one or the other")
        if rec is None:
            if pats or needed:
                raise RequestError(f"the graph {plan.name!r} has no recorder stage, so there is nothing to "
                                   + ("select topics of" if pats else "read the results from"))
            self.path = None
            return
        if no_record:
            if not needed:
                del plan.stages[rec.name]
                self.path = None
                return
            self.tmpdir = tempfile.mkdtemp(prefix="gflow-norecord-")
            self.temporary = True
            self.path = str(Path(self.tmpdir) / "run.mcap")
            rec.params["topics"] = list(needed)
            return
        if pats:
            _refuse_unmatched(plan, pats)
            rec.params["topics"] = pats + [t for t in needed if t not in pats]
        self.path = record or default
        from pipeline.io.recording_files import refuse_existing, warn_mb
        from pipeline.runtime.preflight import check_writable

        try:  # read once the recording is written (its folder's size): a bad value is refused before any work
            warn_mb()
        except ValueError as e:
            raise RequestError(str(e)) from None

        if self.path:  # a recording never overwrites a file (the recorder also creates it exclusively)
            refuse_existing(self.path, "--record" if record else "the recording")
        path = self.path or plan.recording_path()  # None: named when the run starts, with its run id
        assert path is not None  # the plan has its recorder
        # the default recordings/ folder is made; a typed one must exist
        check_writable(path, "--record" if record else "the recording", make_folder=not record)  # before any work

    @property
    def kept(self) -> str:
        """How to name the recording to the user."""
        return "none (--no-record)" if self.temporary or self.path is None else str(self.path)

    def written(self, path: str | None) -> None:
        """The path the run recorded to (a default one is named when the run starts); a note when
        its folder holds more than ``GFLOW_RECORDINGS_WARN_MB`` of recordings."""
        if not self.temporary and path:
            self.path = path
            from pipeline.io.recording_files import size_warning

            note = size_warning(Path(path).parent)
            if note:
                print(note, file=sys.stderr)

    def cleanup(self) -> None:
        if self.tmpdir:
            import shutil

            shutil.rmtree(self.tmpdir, ignore_errors=True)
            self.tmpdir = None


def temporary_recording(path: str | None) -> bool:
    """A recording :class:`RecordingTarget` made for ``no_record`` (read back, then removed)."""
    return bool(path) and Path(str(path)).parent.name.startswith("gflow-norecord-")
