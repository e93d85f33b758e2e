"""Helpers of the G-flow pipeline tests: rendered head sequences on disk, plans, and a
direct driver of the two stages (no host) for snapshot tests."""

from __future__ import annotations

from pathlib import Path

import cv2
import msgspec
import numpy as np

from gflow_core.gflow.synthetic_head import SyntheticSequence, synthetic_sequence
from pipeline.runtime.graph import Plan
from pipeline.io.mcap_io import iter_records
from pipeline.cli.trackers.gflow import make_plan
from stages.base import StageContext
from stages.gflow_filter import GFlowFilterParams, GFlowFilterStage
from stages.gflow_proposal import GFlowProposalParams, GFlowProposalStage
from gflow_msgs.messages import Features, Header, NDArray, decode, encode

#: parameters matched to :func:`synthetic_sequence` (as in tests/core/test_gflow_tracking.py)
SYNTH = dict(n_experts=10, n_samples=8, sigma_w=2e-4, psi_v=1e-5, v_init_var=2e-4, depth_ratio=1.0,
             prior_std_rotation=0.1, prior_std_translation=10.0, prior_std_coefficients=2.0,
             model="", contrast_sigma=0.0, texture_decay=1.0, reset_rate=0.0, photometric=True,
             max_rotation_deg=30.0)


def render_folder(folder: Path, n_frames: int = 20, shape=(120, 160), seed: int = 3) -> tuple[SyntheticSequence, np.ndarray]:
    """Render a head sequence and write it as 8-bit PNGs ``000000.png ...``.

    Returns the sequence and the frames as the pipeline sees them, ``(T, H, W)`` float64
    (grey levels / 255).
    """
    seq = synthetic_sequence(np.random.default_rng(seed), n_frames, shape)
    folder.mkdir(parents=True, exist_ok=True)
    grey = np.rint(seq.frames * 255.0).astype(np.uint8)
    for t, g in enumerate(grey):
        assert cv2.imwrite(str(folder / f"{t:06d}.png"), g)
    return seq, grey.astype(np.float64) / 255.0


def plan_for(folder: Path, init, shards: int = 1, filter_extra: dict | None = None, **params) -> Plan:
    """The built-in gflow graph on an image folder, the G-flow parameters in its tracker block (every
    stage takes them), the initial box and the seed in every stage."""
    import dataclasses

    from gflow_core.gflow import GFlowParams

    block = {k: v for k, v in params.items() if k in {f.name for f in dataclasses.fields(GFlowParams)}}
    shared = dict({k: v for k, v in params.items() if k not in block}, init=[float(v) for v in init])
    over = {"source": {"kind": "folder", "path": str(folder)}, "tracker": block, "proposal": dict(shared),
            "filter": dict(shared, shards=shards, **(filter_extra or {}))}
    return make_plan("gflow", over)


def payloads(path, types=("PoseEstimate", "ExpertStates")) -> dict[tuple[str, int], bytes]:
    """(topic, seq) -> payload of the given message types in a recording."""
    return {(r.topic, r.seq): r.data for r in iter_records(path) if r.type in types}


def pose_estimates(path) -> dict[int, object]:
    return {r.seq: decode(r.data) for r in iter_records(path) if r.type == "PoseEstimate"}


def errors(path) -> list:
    return [decode(r.data) for r in iter_records(path) if r.type == "ErrorReport"]


def features_msg(grey: np.ndarray, seq: int, stream: str = "t") -> Features:
    """A Features message carrying only what G-flow reads (the grey image)."""
    z = np.zeros((1, 1), np.uint8)
    return Features(Header(stream, seq, seq * 40_000_000), NDArray.of(np.ascontiguousarray(grey, np.uint8)),
                    NDArray.of(z), NDArray.of(z.astype(np.float32)), "truncated", 100.0)


class Cycle:
    """The proposal -> filter loop driven by hand: messages are encoded and decoded as on the wire."""

    def __init__(self, params: dict, stream: str = "t", filter_extra: dict | None = None) -> None:
        self.params = params
        self.filter_extra = filter_extra or {}
        self.stream = stream
        self.proposal = self._proposal()
        self.filter = self._filter()
        self.state = None

    def _proposal(self):
        p = msgspec.convert(self.params, GFlowProposalParams)
        return GFlowProposalStage(p, StageContext("proposal", self.stream))

    def _filter(self):
        p = msgspec.convert(dict(self.params, **self.filter_extra), GFlowFilterParams)
        return GFlowFilterStage(p, StageContext("filter", self.stream))

    def step(self, seq: int, feat: Features | None) -> dict[str, bytes]:
        wire = lambda m: None if m is None else decode(encode(m))  # noqa: E731
        props = dict(self.proposal.step(seq, {"features": wire(feat), "state": wire(self.state)}))
        out = dict(self.filter.step(seq, {"features": wire(feat), "proposals0": wire(props.get("proposals"))}))
        self.state = out.get("state")
        return {k: encode(v) for k, v in out.items()}

    def restart_from_snapshots(self) -> None:
        """Replace both stages by fresh instances restored from their snapshots."""
        ps, fs = self.proposal.snapshot(), self.filter.snapshot()
        self.proposal, self.filter = self._proposal(), self._filter()
        self.proposal.restore(ps)
        self.filter.restore(fs)
