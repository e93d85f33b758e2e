"""The building blocks every message uses: the header and arrays as dtype + shape + bytes."""

from __future__ import annotations

import math
from typing import cast

import msgspec
import numpy as np

__all__ = ["Header", "NDArray", "MessageError", "Box"]

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


Box = tuple[float, float, float, float]


