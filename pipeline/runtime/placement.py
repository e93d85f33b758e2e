"""Placement: which stages of a graph run on this host.

A graph may give each stage a host label (``host: edge``); ``gflow run GRAPH --host edge`` then
starts only the stages placed on ``edge`` (``--host`` repeats). Every host loads and validates the
whole graph first, so a mistake anywhere in it stops every host before anything starts.
"""

from __future__ import annotations

from pipeline.runtime.graph import GraphError, Plan

__all__ = ["host_labels", "local_stages", "stages_by_host", "describe_hosts"]


def host_labels(plan: Plan) -> list[str]:
    """The host labels of the graph, in the order the stages name them."""
    return list(dict.fromkeys(s.host for s in plan.stages.values() if s.host))


def stages_by_host(plan: Plan) -> dict[str, list[str]]:
    """host label -> the stages placed there ('' for an unplaced graph)."""
    out: dict[str, list[str]] = {}
    for s in plan.stages.values():
        out.setdefault(s.host, []).append(s.name)
    return out


def local_stages(plan: Plan, hosts: list[str] | tuple[str, ...] | None) -> set[str]:
    """The stages this host starts: all of them without ``hosts``, else those placed on ``hosts``.

    An unknown label, or ``hosts`` for a graph that places nothing, is a one-line
    :class:`GraphError` listing the graph's labels."""
    if not hosts:
        return set(plan.stages)
    labels = host_labels(plan)
    if not labels:
        raise GraphError(f"--host {hosts[0]}: the graph {plan.name!r} places no stage on a host "
                         f"(add host: LABEL to its stages, or run it without --host)")
    for h in hosts:
        if h not in labels:
            raise GraphError(f"--host {h}: no stage of the graph {plan.name!r} is placed on {h!r} "
                             f"(its hosts: {', '.join(labels)})")
    return {n for n, s in plan.stages.items() if s.host in hosts}


def describe_hosts(plan: Plan, stages: set[str] | list[str]) -> str:
    """``edge (preprocess, filter); ops (recorder)``: stages grouped by their host."""
    groups: dict[str, list[str]] = {}
    for n in plan.stages:
        if n in stages:
            groups.setdefault(plan.stages[n].host or "this host", []).append(n)
    return "; ".join(f"{h} ({', '.join(ns)})" for h, ns in groups.items())
