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


def test_a_table_of_arrays_packs_and_checks_a_message_s_arrays_by_named_dimensions():
    from gflow_msgs.base import checked_arrays, packed_arrays
    from gflow_msgs.gflow import EXPERT_ARRAYS, ExpertStates

    E, P, n = 3, 6, 5
    arrays = {"poses": np.zeros((E, P), np.float32), "tex_mean": np.ones((E, n)), "tex_var": np.ones((E, n)),
              "log_credibility": np.zeros(E), "parents": [0, 1, 2]}
    packed = packed_arrays(arrays, EXPERT_ARRAYS)
    assert packed["poses"].dtype == "float64" and packed["parents"].dtype == "int64"  # the table's dtypes
    msg = ExpertStates(header=Header("s", 0, 0), **packed, image_shape=(8, 8), config_digest="d")
    got = checked_arrays(msg, EXPERT_ARRAYS, {"E": E, "P": P, "n": n})
    assert got["tex_mean"].shape == (E, n) and got["parents"].tolist() == [0, 1, 2]
    with pytest.raises(MessageError, match=r"^poses must be float64 \(4, 6\), got float64 \(3, 6\)$"):
        checked_arrays(msg, EXPERT_ARRAYS, {"E": 4, "P": P, "n": n})
    bad = NDArray.of(np.array([0.0, np.nan, 1.0]))
    with pytest.raises(MessageError, match="^log_credibility has NaN or infinite values$"):
        bad.checked("log_credibility", (3,), "float64")
    with pytest.raises(MessageError, match="^parents: array of dtype int64 and shape"):
        NDArray(dtype="int64", shape=(3,), data=memoryview(b"x")).checked("parents", (3,), "int64")


def test_a_snapshot_s_fields_pack_their_arrays_and_unpack_them_alone():
    from gflow_msgs.base import packed_fields, unpacked_fields

    fields = {"grey": np.arange(6, dtype=np.uint8).reshape(2, 3), "seq": 4, "table": None}
    packed = packed_fields(fields)
    assert isinstance(packed["grey"], NDArray) and packed["seq"] == 4 and packed["table"] is None
    back = unpacked_fields(packed)
    assert back["grey"].dtype == np.uint8 and np.array_equal(back["grey"], fields["grey"]) and back["seq"] == 4
    with pytest.raises(MessageError):
        unpacked_fields({"grey": NDArray(dtype="uint8", shape=(2, 3), data=memoryview(b"abc"))})
