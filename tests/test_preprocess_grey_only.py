"""Preprocessing for trackers that read only the grey image (G-flow): no edges, no chamfer image."""

from __future__ import annotations

import numpy as np

from pipeline.runtime.stage_host import StageHost
from stages.base import StageContext
from gflow_msgs.messages import Features, Frame, Header, NDArray, decode, encode
from stages.preprocess import PreprocessParams, PreprocessStage


def _features(edges: bool, frame: Frame) -> Features:
    st = PreprocessStage(PreprocessParams(canny_low=50, canny_high=100, edges=edges),
                         StageContext(name="preprocess", stream="s", resources={}))
    [(port, msg)] = st.step(0, {"frames": frame})
    assert port == "features" and isinstance(msg, Features)
    return msg


def test_grey_only_features_carry_the_same_grey_and_empty_edge_arrays():
    img = np.random.default_rng(3).integers(0, 255, (60, 80, 3), dtype=np.uint8)
    frame = Frame(Header("s", 0, 0), NDArray.of(img))
    full, grey = _features(True, frame), _features(False, frame)
    assert grey.grey == full.grey
    assert grey.edges.array().size == 0 and grey.chamfer.array().size == 0
    assert full.edges.array().shape == (60, 80)
    assert len(encode(grey)) < len(encode(full)) // 3


def test_a_host_accepts_grey_only_features_from_a_source_of_known_frame_size():
    img = np.zeros((60, 80), np.uint8)
    msg = _features(False, Frame(Header("s", 4, 0), NDArray.of(img)))
    host = StageHost(PreprocessStage(PreprocessParams(), StageContext(name="p", stream="s", resources={})),
                     {"frames": "t/frames"}, {"features": "t/features"}, "t/errors", lambda *a: None)
    host.frame_shape = (60, 80)
    assert host.check("frames", 4, decode(encode(msg))) == ""
