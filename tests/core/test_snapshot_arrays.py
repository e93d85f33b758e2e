"""Snapshots as one msgspec Struct with ``np.ndarray`` fields (gflow_core.m2.snapshot_arrays): the
bytes are those of the same Struct with the pipeline's message arrays, arrays come back equal and
writable, and a malformed array is a decode error naming the field."""

from __future__ import annotations

import msgspec
import numpy as np
import pytest

from gflow_core.m2.snapshot_arrays import snapshot_codec
from gflow_msgs.messages import NDArray


class _State(msgspec.Struct, frozen=True):
    version: int
    a: np.ndarray
    b: np.ndarray | None = None
    bank: dict[str, np.ndarray] = {}


class _AsMessages(msgspec.Struct, frozen=True):
    version: int
    a: NDArray
    b: NDArray | None = None
    bank: dict[str, NDArray] = {}


encode, decode = snapshot_codec(_State)


def test_the_bytes_are_those_of_message_arrays_and_arrays_come_back_writable() -> None:
    a = np.arange(12, dtype=np.float32).reshape(3, 4)[:, ::2]  # not C-contiguous
    bank = {"k": np.array([3, 1, 2], dtype=np.int64), "empty": np.zeros((0, 2), dtype=np.uint8)}
    state = _State(version=1, a=a, bank=bank)
    data = encode(state)
    as_msgs = _AsMessages(version=1, a=NDArray.of(a), bank={k: NDArray.of(v) for k, v in bank.items()})
    assert data == msgspec.msgpack.encode(as_msgs)
    back = decode(data)
    assert np.array_equal(back.a, a) and back.a.dtype == np.float32 and back.b is None
    assert all(np.array_equal(back.bank[k], v) and back.bank[k].dtype == v.dtype for k, v in bank.items())
    back.a[0, 0] = 7.0  # a copy, not a view of the bytes
    assert decode(msgspec.msgpack.encode(as_msgs)).a.shape == (3, 2)


def test_bad_arrays_are_refused() -> None:
    with pytest.raises(ValueError, match="dtype complex128"):
        encode(_State(version=1, a=np.zeros(2, dtype=np.complex128)))
    short = msgspec.msgpack.encode({"version": 1, "a": {"dtype": "float64", "shape": [3], "data": b"\0" * 16}})
    with pytest.raises(msgspec.ValidationError, match=r"\$\.a"):
        decode(short)
    odd = msgspec.msgpack.encode({"version": 1, "a": {"dtype": "object", "shape": [1], "data": b"\0" * 8}})
    with pytest.raises(msgspec.ValidationError, match="not an array"):
        decode(odd)


class _Loose(msgspec.Struct, frozen=True):
    a: np.ndarray
    extra: object = None


def test_a_value_that_is_no_array_is_not_encoded() -> None:
    """A value of a type the snapshot does not hold is refused by the encoder with a TypeError naming the
    type, instead of written as something a decoder could not read back."""
    enc, _ = snapshot_codec(_Loose)
    with pytest.raises(TypeError, match="object is not part of a snapshot"):
        enc(_Loose(a=np.zeros(2), extra=object()))
    assert enc(_Loose(a=np.zeros(2), extra=3))  # a value msgspec encodes itself never reaches the hook


class _Odd:
    pass


class _WithOdd(msgspec.Struct, frozen=True):
    a: np.ndarray
    odd: _Odd | None = None


def test_a_field_of_a_type_that_is_no_array_is_a_decode_error_naming_it() -> None:
    _, dec = snapshot_codec(_WithOdd)
    data = msgspec.msgpack.encode({"a": {"dtype": "uint8", "shape": [1], "data": b"\0"}, "odd": {"x": 1}})
    with pytest.raises(msgspec.ValidationError, match=r"not part of a snapshot - at `\$\.odd`"):
        dec(data)
