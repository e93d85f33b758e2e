"""The metadata a run's recording is written with, and what a re-run learns from it.

A recording holds, as MCAP metadata records: ``gflow.graph`` (the graph's name, stream and YAML),
``gflow.config`` (every stage's resolved plan, :meth:`pipeline.runtime.graph.Plan.config_metadata`)
and ``gflow.versions`` (:func:`pipeline.runtime.versions.versions`: gflow, Python, numpy, OpenCV, ... the
system and whether the SIMD kernels were held). The last decides whether a re-run can be identical:
the trackers' particle filters carry the last bits of floating point into their outputs, and another
release of numpy or OpenCV, or another kind of machine, rounds some of them otherwise (dcf on
david_indoor, seed 1, gives success-plot AUC 0.701 with OpenCV 5.0.0 and 0.813 with 5.1.0 on one
machine). So ``gflow rerun`` says when the versions it runs with are not those of the recording.
"""

from __future__ import annotations

from typing import Any

__all__ = ["GRAPH", "CONFIG", "VERSIONS", "KERNEL_KEYS", "run_metadata", "versions_differ"]

GRAPH, CONFIG, VERSIONS = "gflow.graph", "gflow.config", "gflow.versions"

#: what decides the last bits of a run's floating point: the interpreter, the numerical libraries, the
#: system and the SIMD kernels the libraries were held to (:mod:`pipeline.runtime.instruction_sets`)
KERNEL_KEYS = ("python", "numpy", "opencv", "scipy", "os", "simd")


def run_metadata(plan: Any, graph: dict[str, str] | None = None, **extra: dict[str, str]) -> dict[str, dict[str, str]]:
    """The metadata records of a recording of ``plan`` (a :class:`pipeline.runtime.graph.Plan`):
    ``graph`` (a recorded ``gflow.graph`` to keep) or the plan's own, its config, this process's versions,
    and ``extra`` records by name."""
    from pipeline.runtime.versions import versions

    md = {GRAPH: graph if graph is not None else {"name": plan.name, "stream": plan.stream, "yaml": plan.source_text},
          CONFIG: plan.config_metadata(), VERSIONS: versions()}
    md.update(extra)
    return md


def _kernel(key: str, value: str) -> str:
    # a contrib build of OpenCV is the same OpenCV: its version decides, not the extra modules
    return value.split()[0] if key == "opencv" and value else value


def versions_differ(recorded: dict[str, str] | None, here: dict[str, str] | None = None) -> list[str]:
    """``["opencv 5.0.0 -> 5.1.0", ...]``: the :data:`KERNEL_KEYS` whose value in a recording's
    ``gflow.versions`` differs from ``here`` (this process's, by default); [] when they agree or the
    recording does not say (written before it kept them: nothing is known, so nothing is claimed)."""
    if not recorded:
        return []
    if here is None:
        from pipeline.runtime.versions import versions

        here = versions()
    out = []
    for key in KERNEL_KEYS:
        was, now = _kernel(key, recorded.get(key, "")), _kernel(key, here.get(key, ""))
        if was and was != now:
            out.append(f"{key} {was} -> {now or 'unknown'}")
    return out
