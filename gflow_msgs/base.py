"""The building blocks every message uses: the header and arrays as dtype + shape + bytes."""

from __future__ import annotations

import math
from typing import Any, Mapping, cast

import msgspec
import numpy as np

__all__ = ["Header", "NDArray", "MessageError", "Box", "ArrayTable", "checked_arrays", "packed_arrays",
           "packed_fields", "unpacked_fields"]

_ALLOWED_DTYPES = frozenset(
    ["uint8", "int8", "uint16", "int16", "uint32", "int32", "int64", "uint64", "float32", "float64", "bool"]
)


class MessageError(ValueError):
    """A payload that is not a valid gflow message (malformed bytes, wrong schema, bad array)."""


class Header(msgspec.Struct, frozen=True):
    """Stream id, sequence number (frame index, 0-based) and capture time in ns."""

    stream: str
    seq: int
    stamp_ns: int


class NDArray(msgspec.Struct, frozen=True):
    """An ndarray as dtype + shape + raw C-order bytes.

    ``data`` is ``bytes`` in an array packed here (:meth:`of`), and a read-only ``memoryview``
    of the payload in a decoded one: decoding copies no array (a 640x480 frame is 300 KB, and
    the copy cost 50-110 us a hop). Both compare, hash and encode alike.
    """

    dtype: str
    shape: tuple[int, ...]
    data: memoryview

    @classmethod
    def of(cls, arr: np.ndarray) -> "NDArray":
        """Pack an array (copied to C order; byte order native little-endian)."""
        a = np.ascontiguousarray(arr)
        if a.dtype.name not in _ALLOWED_DTYPES:
            raise MessageError(f"dtype {a.dtype} cannot travel in a message; allowed: {sorted(_ALLOWED_DTYPES)}")
        # a copy, not a view: the message must not change when the stage reuses its array
        # bytes here, a memoryview once decoded: both compare, hash and encode alike
        return cls(dtype=a.dtype.name, shape=tuple(int(s) for s in a.shape), data=cast(memoryview, a.tobytes()))

    def array(self) -> np.ndarray:
        """Unpack to a read-only ndarray view of the bytes, checking dtype and size."""
        if self.dtype not in _ALLOWED_DTYPES:
            raise MessageError(f"array dtype {self.dtype!r} is not allowed")
        if any(s < 0 for s in self.shape):
            raise MessageError(f"array shape {self.shape} has a negative dimension")
        dt = np.dtype(self.dtype)
        n = math.prod(self.shape)  # Python integers: a huge shape cannot wrap around to a small size
        if n * dt.itemsize != len(self.data):
            raise MessageError(
                f"array of dtype {self.dtype} and shape {self.shape} needs {n * dt.itemsize} bytes, got {len(self.data)}"
            )
        try:
            return np.frombuffer(self.data, dtype=dt).reshape(self.shape)
        except ValueError as e:  # an empty array with absurd dimensions, say
            raise MessageError(f"array of dtype {self.dtype} and shape {self.shape}: {e}") from None

    def checked(self, name: str, shape: tuple[int, ...], dtype: str) -> np.ndarray:
        """:meth:`array`, which must have ``shape`` and ``dtype`` and, when floating, finite values;
        :class:`MessageError` naming the field ``name`` otherwise."""
        try:
            a = self.array()
        except MessageError as e:
            raise MessageError(f"{name}: {e}") from None
        if a.shape != shape or a.dtype != np.dtype(dtype):
            raise MessageError(f"{name} must be {dtype} {shape}, got {a.dtype} {a.shape}")
        if a.dtype.kind == "f" and not np.isfinite(a).all():
            raise MessageError(f"{name} has NaN or infinite values")
        return a


#: the arrays of a message type, {field: (shape, dtype)}: a dimension is a number or the name of one
#: (``"E"``: the number of experts), given when a message is read (:func:`checked_arrays`)
ArrayTable = Mapping[str, tuple[tuple[int | str, ...], str]]


def checked_arrays(msg: Any, table: ArrayTable, dims: Mapping[str, int]) -> dict[str, np.ndarray]:
    """The arrays of ``msg`` that ``table`` names, each checked (:meth:`NDArray.checked`) with the
    named dimensions ``dims``; :class:`MessageError` naming the first bad one."""
    return {name: getattr(msg, name).checked(name, tuple(dims[d] if isinstance(d, str) else d for d in shape), dtype)
            for name, (shape, dtype) in table.items()}


def packed_arrays(arrays: Mapping[str, Any], table: ArrayTable) -> dict[str, NDArray]:
    """``{field: NDArray}`` of the arrays ``table`` names, each in the table's dtype."""
    return {name: NDArray.of(np.asarray(arrays[name], dtype)) for name, (_, dtype) in table.items()}


Box = tuple[float, float, float, float]


def packed_fields(fields: Mapping[str, Any]) -> dict[str, Any]:
    """``fields`` with each ndarray packed as an :class:`NDArray` (the fields of a snapshot Struct)."""
    return {k: NDArray.of(v) if isinstance(v, np.ndarray) else v for k, v in fields.items()}


def unpacked_fields(fields: Mapping[str, Any]) -> dict[str, Any]:
    """``fields`` with each :class:`NDArray` unpacked (:meth:`NDArray.array`: read-only; MessageError
    for a bad one)."""
    return {k: v.array() if isinstance(v, NDArray) else v for k, v in fields.items()}
