"""Compare two recordings topic by topic (``gflow diff``).

Messages are paired by (topic, sequence number, occurrence). Per topic: how many are
identical, how many differ and in which fields (with the largest difference), how many
are only in one file, and the first frame where they diverge. For estimates, the box
centre distance, the overlap and the pose difference are given per frame.
Two runs of one graph record under streams that differ by their run ids (``gflow/demo-43159e/estimate``,
``gflow/demo-a1b2c3/estimate``); when that is all that tells the recordings' topics apart, topics are
paired by their name without the run id (``gflow/demo/estimate``), and :attr:`TopicDiff.topic_a` /
:attr:`TopicDiff.topic_b` say which topics were compared.
Heartbeats and control messages (``_status``, ``_control``) carry wall-clock times and
are left out unless named with ``topics``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from gflow_core.evaluation.metrics import centre_error, iou
from gflow_msgs.messages import Estimate, MessageError, PoseEstimate, decode

from pipeline.recording.compare import field_diffs
from pipeline.recording.topics import streams_paired_across_run_ids, without_run_id
from pipeline.io.mcap_io import iter_records

__all__ = ["TopicDiff", "EstimateDiff", "diff_recordings"]


@dataclass
class EstimateDiff:
    seq: int
    centre_px: float
    overlap: float
    pose: float  # max |difference| of the pose / alpha vector


@dataclass
class TopicDiff:
    topic: str
    types: set[str] = field(default_factory=set)
    same: int = 0
    differ: int = 0
    only_a: int = 0
    only_b: int = 0
    first_divergence: int | None = None
    fields: dict[str, float] = field(default_factory=dict)  # field path (no index) -> max |difference|
    estimates: list[EstimateDiff] = field(default_factory=list)
    topic_a: str = ""  # the topic of A compared ("" when A has none), differs from ``topic`` across run ids
    topic_b: str = ""

    @property
    def identical(self) -> bool:
        return self.differ == 0 and self.only_a == 0 and self.only_b == 0

    def _diverge(self, seq: int) -> None:
        self.first_divergence = seq if self.first_divergence is None else min(self.first_divergence, seq)


def _index(path: str | Path, topics: list[str] | None) -> dict[str, dict[tuple[int, int], tuple[str, bytes]]]:
    out: dict[str, dict[tuple[int, int], tuple[str, bytes]]] = {}
    for r in iter_records(path, topics=topics):
        if topics is None and ("/_status/" in r.topic or r.topic.endswith("/_control")):
            continue
        d = out.setdefault(r.topic, {})
        n = 0
        while (r.seq, n) in d:
            n += 1
        d[(r.seq, n)] = (r.type, r.data)
    return out


def _estimate_diff(seq: int, a: bytes, b: bytes) -> EstimateDiff | None:
    try:
        ma, mb = decode(a), decode(b)
    except MessageError:
        return None
    if not (isinstance(ma, (Estimate, PoseEstimate)) and isinstance(mb, type(ma))):
        return None
    ba, bb = np.array([ma.box]), np.array([mb.box])
    va = np.array(ma.alpha if isinstance(ma, Estimate) else ma.pose)
    vb = np.array(mb.alpha if isinstance(mb, Estimate) else mb.pose)
    pose = float(np.max(np.abs(va - vb))) if va.shape == vb.shape else float("inf")
    return EstimateDiff(seq, float(centre_error(ba, bb)[0]), float(iou(ba, bb)[0]), pose)


def diff_recordings(a: str | Path, b: str | Path, topics: list[str] | None = None) -> dict[str, TopicDiff]:
    """Per-topic differences between recordings ``a`` and ``b``."""
    ia, ib = _index(a, topics), _index(b, topics)
    names_a, names_b = {t: t for t in ia}, {t: t for t in ib}
    if streams_paired_across_run_ids(ia, ib) is not None:  # two runs of one graph: pair by name without run id
        names_a, names_b = {without_run_id(t): t for t in ia}, {without_run_id(t): t for t in ib}
    out: dict[str, TopicDiff] = {}
    for topic in sorted(set(names_a) | set(names_b)):
        ta_, tb_ = names_a.get(topic, ""), names_b.get(topic, "")
        da, db = ia.get(ta_, {}), ib.get(tb_, {})
        td = out[topic] = TopicDiff(topic, topic_a=ta_, topic_b=tb_)
        for key in sorted(set(da) | set(db)):
            seq = key[0]
            if key not in db:
                td.only_a += 1
                td._diverge(seq)
                td.types.add(da[key][0])
                continue
            if key not in da:
                td.only_b += 1
                td._diverge(seq)
                td.types.add(db[key][0])
                continue
            (ta, pa), (_, pb) = da[key], db[key]
            td.types.add(ta)
            if ta in ("Estimate", "PoseEstimate"):
                ed = _estimate_diff(seq, pa, pb)
                if ed is not None:
                    td.estimates.append(ed)
            if pa == pb:
                td.same += 1
                continue
            td.differ += 1
            td._diverge(seq)
            for fd in field_diffs(pa, pb):
                name = fd.path.split("[")[0]
                mag = fd.magnitude if np.isfinite(fd.magnitude) else float("nan")
                prev = td.fields.get(name)
                td.fields[name] = mag if prev is None or np.isnan(prev) else max(prev, mag if not np.isnan(mag) else prev)
    return out
