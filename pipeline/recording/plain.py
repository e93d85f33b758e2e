"""Messages as text: one line per message for ``gflow echo`` and ``gflow step``, and as JSON-ready
data for ``--json`` and the Foxglove export."""

from __future__ import annotations

from typing import Any

from gflow_msgs.messages import MessageError, NDArray, decode

__all__ = ["describe", "to_plain"]


def describe(payload: bytes, full: bool = False) -> str:
    """One line (or a few) about a payload: type, seq and its small fields; arrays as dtype+shape."""
    try:
        m = decode(payload)
    except MessageError as e:
        return f"<undecodable: {e}>"
    parts = [type(m).__name__]
    for name in m.__struct_fields__:
        v = getattr(m, name)
        if name == "header":
            parts.append(f"seq={v.seq} stamp={v.stamp_ns / 1e9:.3f}s")
        elif isinstance(v, NDArray):
            parts.append(f"{name}={v.dtype}{list(v.shape)}")
        elif isinstance(v, float):
            parts.append(f"{name}={v:.4g}")
        elif isinstance(v, tuple) and v and isinstance(v[0], float):
            parts.append(f"{name}=(" + ", ".join(f"{x:.2f}" for x in v) + ")")
        elif v not in (None, "", {}, ()) or full:
            parts.append(f"{name}={v}")
    return " ".join(parts)


def to_plain(msg, max_items: int = 64):
    """A message as JSON-ready data: structs as dicts with their ``type``; arrays of up to
    ``max_items`` values as lists, larger ones as ``{dtype, shape}`` (no pixel dumps)."""
    import msgspec

    if isinstance(msg, NDArray):
        n = 1
        for dim in msg.shape:
            n *= dim
        if n <= max_items:
            try:
                a = msg.array()
                if a.dtype.kind == "f":  # JSON has no NaN / inf
                    import numpy as np

                    a = np.where(np.isfinite(a), a, np.array(None, dtype=object))  # as np.where makes of None
                return {"dtype": msg.dtype, "shape": list(msg.shape), "values": a.tolist()}
            except MessageError:
                pass
        return {"dtype": msg.dtype, "shape": list(msg.shape)}
    if isinstance(msg, msgspec.Struct):
        d: dict[str, Any] = {"type": type(msg).__name__} if type(msg).__struct_config__.tag else {}
        for name in msg.__struct_fields__:
            d[name] = to_plain(getattr(msg, name), max_items)
        return d
    if isinstance(msg, (list, tuple)):
        return [to_plain(v, max_items) for v in msg]
    if isinstance(msg, dict):
        return {str(k): to_plain(v, max_items) for k, v in msg.items()}
    if isinstance(msg, bytes):
        return {"bytes": len(msg)}
    if isinstance(msg, float) and (msg != msg or msg in (float("inf"), float("-inf"))):
        return None
    return msg
