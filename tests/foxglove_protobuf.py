"""Decode a protobuf message with the FileDescriptorSet of its channel's schema, as the Foxglove
app does (google.protobuf, independent of foxglove-sdk, which only encodes)."""

from __future__ import annotations

from typing import Any


def decode_with_schema(schema_name: str, schema_data: bytes, payload: bytes) -> dict[str, Any]:
    """The message as plain data with the .proto field names: timestamps as {"sec", "nsec"} (as
    Foxglove shows them), enums as numbers, bytes as bytes, empty ``metadata`` lists left out."""
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

    pool = descriptor_pool.DescriptorPool()
    for f in descriptor_pb2.FileDescriptorSet.FromString(schema_data).file:
        pool.Add(f)
    cls = message_factory.GetMessageClass(pool.FindMessageTypeByName(schema_name))
    return _plain(cls.FromString(payload))


def _plain(v: Any) -> Any:
    if hasattr(v, "DESCRIPTOR"):
        if v.DESCRIPTOR.full_name == "google.protobuf.Timestamp":
            return {"sec": v.seconds, "nsec": v.nanos}
        out = {f.name: _plain(getattr(v, f.name)) for f in v.DESCRIPTOR.fields}
        if out.get("metadata") == []:
            del out["metadata"]
        return out
    if isinstance(v, (str, bytes, int, float, bool)):
        return v
    return [_plain(x) for x in v]  # a repeated field
