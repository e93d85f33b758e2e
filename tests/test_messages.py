"""Messages: arrays round-trip without pickle, malformed payloads give clear errors."""

import msgspec
import numpy as np
import pytest

from gflow_msgs.messages import Estimate, Frame, Header, MessageError, NDArray, decode, decode_as, encode, json_schema


def test_ndarray_round_trip_keeps_dtype_shape_and_bytes():
    rng = np.random.default_rng(0)
    for arr in (rng.integers(0, 255, (7, 9, 3), dtype=np.uint8), rng.normal(size=(5, 4)), np.arange(6, dtype=np.int64)):
        back = decode(encode(Frame(Header("s", 3, 10), NDArray.of(arr)))).image.array()
        assert back.dtype == arr.dtype and back.shape == arr.shape and np.array_equal(back, arr)


def test_encoding_is_deterministic():
    m = Frame(Header("s", 1, 2), NDArray.of(np.ones((2, 2), np.uint8)), truth=(1.0, 2.0, 3.0, 4.0))
    assert encode(m) == encode(msgspec.msgpack.decode(encode(m), type=Frame))


def test_malformed_payloads_name_the_problem():
    with pytest.raises(MessageError, match="malformed"):
        decode(b"\x00\x01garbage")
    good = encode(Frame(Header("s", 1, 2), NDArray.of(np.ones((2, 2), np.uint8))))
    with pytest.raises(MessageError, match="malformed Estimate"):
        decode_as(good, Estimate)
    bad = NDArray(dtype="float64", shape=(3, 3), data=b"\x00" * 10)
    with pytest.raises(MessageError, match="needs 72 bytes, got 10"):
        bad.array()
    with pytest.raises(MessageError, match="not allowed"):
        NDArray(dtype="object", shape=(1,), data=b"x").array()


def test_no_pickle_dtype_can_be_sent():
    with pytest.raises(MessageError):
        NDArray.of(np.array([object()]))


def test_json_schema_is_inlined_for_viewers():
    s = json_schema(Frame)
    assert "$ref" not in s and s["type"] == "object" and "header" in s["properties"]
