"""Field-by-field comparison of two encoded messages: which field differs, and by how much."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import msgspec
import numpy as np

from gflow_msgs.messages import MessageError, NDArray, decode

__all__ = ["FieldDiff", "field_diffs", "first_field_diff"]


@dataclass(frozen=True)
class FieldDiff:
    """One differing field: its path (``alpha[12, 0]``, ``header.stamp_ns``) and the size of the difference."""

    path: str
    detail: str
    magnitude: float = float("nan")


def _num(v: Any) -> str:
    """A number as a user reads it: ``0.25``, not ``np.float64(0.25)``."""
    return repr(v.item()) if isinstance(v, np.generic) else repr(v)


def _array_diff(path: str, a: NDArray, b: NDArray) -> FieldDiff | None:
    if a.dtype != b.dtype or tuple(a.shape) != tuple(b.shape):
        return FieldDiff(path, f"{a.dtype}{list(a.shape)} vs {b.dtype}{list(b.shape)}")
    if a.data == b.data:
        return None
    x, y = a.array(), b.array()
    if x.dtype.kind in "fiub":
        xf, yf = x.astype(np.float64), y.astype(np.float64)
        d = np.abs(xf - yf)
        d = np.where(np.isnan(xf) & np.isnan(yf), 0.0, np.nan_to_num(d, nan=np.inf))
        idx = np.unravel_index(int(np.argmax(d)), d.shape) if d.size else ()
        n = int(np.count_nonzero(d))
        return FieldDiff(f"{path}[{', '.join(map(str, idx))}]",
                         f"{n} of {d.size} elements differ, max |diff| {float(d.max()):.6g} "
                         f"({_num(xf[idx])} vs {_num(yf[idx])})", float(d.max()))
    return FieldDiff(path, "bytes differ")


#: values longer than this are summarised, not printed (a snapshot's bytes run to megabytes)
_SHOW = 60


def _text_diff(path: str, a: bytes | str, b: bytes | str) -> FieldDiff:
    """Two differing byte or text values: both in full when short, else their lengths and where
    they first differ."""
    if len(a) <= _SHOW and len(b) <= _SHOW:
        return FieldDiff(path, f"{a!r} vs {b!r}")
    n = min(len(a), len(b))
    i = next((k for k in range(n) if a[k] != b[k]), n)
    unit = "bytes" if isinstance(a, bytes) else "characters"
    return FieldDiff(path, f"{len(a)} vs {len(b)} {unit}, first different at {i}: "
                           f"{a[i:i + 16]!r}... vs {b[i:i + 16]!r}...")


def _walk(path: str, a: Any, b: Any, out: list[FieldDiff]) -> None:
    if isinstance(a, NDArray) and isinstance(b, NDArray):
        d = _array_diff(path, a, b)
        if d:
            out.append(d)
    elif isinstance(a, msgspec.Struct) and isinstance(b, msgspec.Struct):
        if type(a) is not type(b):
            out.append(FieldDiff(path or "type", f"{type(a).__name__} vs {type(b).__name__}"))
            return
        for f in a.__struct_fields__:
            _walk(f"{path}.{f}" if path else f, getattr(a, f), getattr(b, f), out)
    elif isinstance(a, (tuple, list)) and isinstance(b, (tuple, list)):
        if len(a) != len(b):
            out.append(FieldDiff(path, f"length {len(a)} vs {len(b)}"))
            return
        for i, (x, y) in enumerate(zip(a, b)):
            _walk(f"{path}[{i}]", x, y, out)
    elif isinstance(a, dict) and isinstance(b, dict):
        for k in sorted(set(a) | set(b), key=str):
            _walk(f"{path}.{k}", a.get(k), b.get(k), out)
    elif isinstance(a, (bytes, str)) and isinstance(b, (bytes, str)) and type(a) is type(b) and a != b:
        out.append(_text_diff(path, a, b))
    elif a != b and not (isinstance(a, float) and isinstance(b, float) and np.isnan(a) and np.isnan(b)):
        mag = abs(a - b) if isinstance(a, (int, float)) and isinstance(b, (int, float)) else float("nan")
        out.append(FieldDiff(path, f"{_num(a)} vs {_num(b)}", float(mag)))


def field_diffs(a: bytes, b: bytes) -> list[FieldDiff]:
    """Every differing field of two payloads (empty if the bytes are equal)."""
    if a == b:
        return []
    try:
        ma, mb = decode(a), decode(b)
    except MessageError as e:
        return [FieldDiff("payload", f"cannot decode: {e}")]
    out: list[FieldDiff] = []
    _walk("", ma, mb, out)
    return out or [FieldDiff("payload", "bytes differ but every decoded field is equal (encoding changed)")]


def first_field_diff(a: bytes, b: bytes) -> FieldDiff | None:
    d = field_diffs(a, b)
    return d[0] if d else None
