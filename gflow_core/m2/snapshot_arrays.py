"""Snapshots of a tracker's state as one msgspec Struct whose arrays are ``np.ndarray`` fields.

An array is encoded as a map of ``dtype`` (its name), ``shape`` and ``data`` (the C-order bytes):
the bytes the pipeline's message arrays (``gflow_msgs.messages.NDArray``) encode to, so a Struct of this
kind and the same Struct with message arrays are the same bytes, and either decodes as the other.
Decoded arrays are writable copies.
"""

from __future__ import annotations

import math
from typing import Any, Callable, TypeVar

import msgspec
import numpy as np

__all__ = ["snapshot_codec", "DTYPES"]

#: the dtypes an array in a snapshot may have (those of the pipeline's messages)
DTYPES = frozenset(["uint8", "int8", "uint16", "int16", "uint32", "int32", "int64", "uint64", "float32", "float64",
                    "bool"])

T = TypeVar("T")


# msgspec's hooks: a TypeError says "not a type I encode / decode"; msgspec passes the encoder's on as it is
# and turns the decoder's into a ValidationError naming the field
def _enc(obj: Any) -> Any:
    if isinstance(obj, np.ndarray):
        a = np.ascontiguousarray(obj)
        if a.dtype.name not in DTYPES:
            raise ValueError(f"an array of dtype {a.dtype} cannot be in a snapshot")
        return {"dtype": a.dtype.name, "shape": tuple(int(s) for s in a.shape), "data": a.tobytes()}
    raise TypeError(f"{type(obj).__name__} is not part of a snapshot")


def _dec(kind: type, obj: Any) -> Any:
    if kind is not np.ndarray:
        raise TypeError(f"{kind} is not part of a snapshot")
    try:
        dtype, shape, data = obj["dtype"], tuple(int(s) for s in obj["shape"]), obj["data"]
        if dtype not in DTYPES or min(shape, default=0) < 0 or math.prod(shape) * np.dtype(dtype).itemsize != len(data):
            raise ValueError
        return np.frombuffer(data, dtype=dtype).reshape(shape).copy()
    except (KeyError, TypeError, ValueError):
        raise ValueError("not an array (dtype, shape, data of that size)") from None


def snapshot_codec(struct: type[T]) -> tuple[Callable[[T], bytes], Callable[[bytes], T]]:
    """(encode, decode) of the msgspec Struct ``struct``: msgpack bytes of one, and the one of msgpack
    bytes (``msgspec.DecodeError`` for anything else)."""
    encoder = msgspec.msgpack.Encoder(enc_hook=_enc)
    decoder = msgspec.msgpack.Decoder(struct, dec_hook=_dec)
    return encoder.encode, decoder.decode
