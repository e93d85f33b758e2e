"""Fuzzing message decoding and the stage host with hypothesis: whatever the bytes, decoding
raises only MessageError, and a host given them never raises, never steps on them, and
counts every one it rejects."""

from __future__ import annotations

import msgspec
import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from pipeline.runtime.stage_host import StageHost
from stages.base import StageContext
from gflow_msgs.messages import MESSAGE_TYPES, Frame, Header, MessageError, NDArray, Particles, decode, encode
from stages.particle_filter import FilterParams, FilterStage
from stages.particle_proposal import ProposalParams, ProposalStage
from stages.preprocess import PreprocessParams, PreprocessStage

FUZZ = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])

scalars = st.one_of(st.none(), st.booleans(), st.integers(-2**63, 2**64 - 1), st.floats(allow_nan=True),
                    st.text(max_size=8), st.binary(max_size=32))
values = st.recursive(scalars, lambda c: st.one_of(st.lists(c, max_size=4),
                                                   st.dictionaries(st.text(max_size=6), c, max_size=4)),
                      max_leaves=12)
type_tags = st.sampled_from(sorted(MESSAGE_TYPES) + ["Bogus", ""])
shapes = st.lists(st.one_of(st.integers(-3, 8), st.integers(2**31, 2**64 - 1)), max_size=5)
dtypes = st.sampled_from(["uint8", "float32", "float64", "int64", "object", "<U3", "nope"])


@st.composite
def tagged(draw):
    """A msgpack map with a real or bogus type tag, plausible field names and random values."""
    tag = draw(type_tags)
    fields = draw(st.dictionaries(st.sampled_from(["header", "image", "alpha", "k", "log_w", "kind", "seq",
                                                   "stream", "stamp_ns", "data", "shape", "dtype"]), values,
                                  max_size=6))
    if draw(st.booleans()):
        fields["header"] = {"stream": "s", "seq": draw(st.integers(-5, 2**40)), "stamp_ns": 0}
    return msgspec.msgpack.encode({"type": tag, **fields})


@st.composite
def arrays_messages(draw):
    """Well-formed msgpack of Frame / Particles whose arrays lie about their shape, dtype or values."""
    arr = {"dtype": draw(dtypes), "shape": draw(shapes), "data": draw(st.binary(max_size=64))}
    seq = draw(st.integers(0, 20))
    if draw(st.booleans()):
        return msgspec.msgpack.encode({"type": "Frame", "header": {"stream": "s", "seq": seq, "stamp_ns": 0},
                                       "image": arr})
    n = draw(st.integers(0, 4))
    good = {"dtype": "float64", "shape": [n, 4], "data": np.full((n, 4), draw(st.floats()), np.float64).tobytes()}
    return msgspec.msgpack.encode({"type": "Particles", "header": {"stream": "s", "seq": seq, "stamp_ns": 0},
                                   "kind": "posterior", "alpha": draw(st.sampled_from([arr, good])),
                                   "k": {"dtype": "int64", "shape": [n], "data": bytes(8 * n)},
                                   "log_w": {"dtype": "float64", "shape": [n], "data": bytes(8 * n)}})


payloads = st.one_of(st.binary(max_size=200), tagged(), arrays_messages())


@FUZZ
@given(payloads)
def test_decode_raises_only_message_error(payload):
    try:
        msg = decode(payload)
    except MessageError:
        return
    for name in getattr(msg, "__struct_fields__", ()):
        arr = getattr(msg, name)
        if isinstance(arr, NDArray):
            try:
                arr.array()
            except MessageError:
                pass


class _Sink:
    def __init__(self) -> None:
        self.errors = 0
        self.outputs = 0

    def __call__(self, topic, payload, seq, type_name=""):
        if topic == "errors":
            self.errors += 1
        else:
            self.outputs += 1


def _hosts(sink):
    pre = PreprocessStage(PreprocessParams(canny_low=20, canny_high=60), StageContext("preprocess", "s"))
    prop = ProposalStage(ProposalParams(), StageContext("proposal", "s"))
    filt = FilterStage(FilterParams(init=(2, 2, 4, 4), particles=10), StageContext("filter", "s"))
    hosts = [StageHost(pre, {"frames": "frames"}, {"features": "features"}, "errors", sink, window=8),
             StageHost(prop, {"particles": "particles"}, {"proposals": "proposals"}, "errors", sink, window=8),
             StageHost(filt, {"features": "features", "proposals": "proposals"},
                       {"particles": "particles", "estimate": "estimate"}, "errors", sink, window=8)]
    for h in hosts:
        h.source_seq = 10
        h.frame_shape = (4, 6)
    return hosts


@FUZZ
@given(st.lists(payloads, min_size=1, max_size=6))
def test_a_host_never_raises_and_counts_what_it_rejects(batch):
    sink = _Sink()
    for h in _hosts(sink):
        for topic in h.topics_in.values():
            for payload in batch:
                h.deliver(topic, payload)  # must not raise
        rejected = sum(h.stats.rejected.values())
        assert rejected <= sum(h.stats.received.values())
    assert sink.errors >= 0


@FUZZ
@given(st.integers(0, 30), st.sampled_from([np.nan, np.inf, -np.inf]))
def test_non_finite_particles_never_reach_the_proposal_stage(seq, bad):
    sink = _Sink()
    h = _hosts(sink)[1]
    alpha = np.zeros((3, 4))
    alpha[1, 2] = bad
    msg = Particles(Header("s", seq, 0), "posterior", NDArray.of(alpha), NDArray.of(np.zeros(3, np.int64)),
                    NDArray.of(np.zeros(3)))
    h.deliver("particles", encode(msg))
    assert sink.outputs == 0 and sum(h.stats.rejected.values()) == 1


def test_a_frame_whose_shape_overflows_int64_is_rejected_before_allocation():
    f = Frame(Header("s", 1, 0), NDArray("uint8", (2**32, 2**32), b""))
    try:
        f.image.array()
        raise AssertionError("a (2^32, 2^32) array from 0 bytes was accepted")
    except MessageError as e:
        assert "needs" in str(e)
