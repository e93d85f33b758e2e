"""The application layer: what ``gflow track`` does, below any command line.

A :class:`TrackRequest` (a frozen value: source, initial box, tracker and its options, seed,
where to record, ...) becomes a :class:`TrackPlan` (:func:`plan_track`: every check that can
be made before anything starts, then the graph with its overrides, the source checked and its
frames counted), and :func:`run` runs it, inline or as processes, yielding each estimate as an
:class:`EstimateSink` takes it from the run's own messages, while the run goes on (closing the
generator stops the run); what the run came to (:class:`TrackResult`: the estimates, time,
report lines, the recording kept) is the generator's return value, and :func:`track` runs a plan
to its end and returns it.

The estimates come from the run, not from reading its recording back: with ``no_record`` no
recorder runs and no MCAP file is written (a live source, whose camera frame numbers and
figures are read from the recording, still records to a temporary file, removed at the end).
A recording, when kept, still fills in an estimate the sink missed.

Commands are shells over this module (``gflow track``, ``gflow benchmark``, ``gflow run``,
``gflow demo``); the tracker registry lives above it, so :func:`plan_track` is handed the
tracker (anything with ``overrides(options) -> (graph, {stage: {param: value}})`` and,
optionally, ``make_plan(graph, overrides)``).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # imported when first asked for (__getattr__ below)
    from pipeline.app.errors import RequestError
    from pipeline.app.request import (TrackPlan, TrackRequest, check_stage_values, parse_sets, plan_track,
                                      sets_as_given, source_params)
    from pipeline.app.recording_target import RecordingTarget, temporary_recording
    from pipeline.app.graph_run import EstimateSink, RunStop, place, run_graph
    from pipeline.app.network import DEFAULT_ENDPOINT, default_listen, default_zenoh
    from pipeline.app.track_run import TrackResult, run, track

#: name -> the module of this package that defines it. A module is imported when one of its names is
#: first asked for, so that ``pipeline.app.errors`` (which the ``gflow`` command names at every start)
#: does not bring the whole application layer (about 0.1 s of CPU) with it.
_WHERE = {"RequestError": "errors",
          **dict.fromkeys(("TrackPlan", "TrackRequest", "check_stage_values", "parse_sets", "plan_track",
                           "sets_as_given", "source_params"), "request"),
          **dict.fromkeys(("RecordingTarget", "temporary_recording"), "recording_target"),
          **dict.fromkeys(("EstimateSink", "RunStop", "place", "run_graph"), "graph_run"),
          **dict.fromkeys(("DEFAULT_ENDPOINT", "default_listen", "default_zenoh"), "network"),
          **dict.fromkeys(("TrackResult", "run", "track"), "track_run")}

__all__ = ["RequestError", "TrackRequest", "TrackPlan", "TrackResult", "EstimateSink", "RunStop", "plan_track", "run",
           "track",
           "run_graph", "RecordingTarget", "place", "source_params", "check_stage_values", "sets_as_given",
           "parse_sets", "default_listen", "default_zenoh", "DEFAULT_ENDPOINT", "temporary_recording"]


def __getattr__(name: str) -> Any:
    where = _WHERE.get(name)
    if where is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{where}"), name)
    globals()[name] = value
    return value
