"""Foxglove's own scene schema on our keys: bytes made by the `foxglove-sdk` package, decoded (validated) with
the FileDescriptorSet that the same package publishes, so nothing of Foxglove's schema is copied by hand.

A message of one of these types is a protobuf message (`foxglove.SceneUpdate`); in a log its channel has
message encoding `protobuf` and its schema is the FileDescriptorSet (schema encoding `protobuf`), which is
what Foxglove reads natively. Decoding returns the protobuf message object (fields as in Foxglove's docs).
"""

from __future__ import annotations

import functools
from typing import Any, ClassVar

from ._spec import ProtocolError


class FoxgloveProto:
    """Base of a Foxglove protobuf type carried on one of our keys."""

    TYPE_NAME: ClassVar[str]  # Foxglove's schema name, e.g. "foxglove.SceneUpdate"
    SDK_NAME: ClassVar[str]  # the class name in foxglove.messages
    MAX_BYTES: ClassVar[int] = 1024 * 1024
    CONTENT_TYPE: ClassVar[str] = "application/x-protobuf"
    MESSAGE_ENCODING: ClassVar[str] = "protobuf"
    SCHEMA_ENCODING: ClassVar[str] = "protobuf"

    @classmethod
    def sdk_class(cls) -> Any:
        import foxglove.messages

        return getattr(foxglove.messages, cls.SDK_NAME)

    @classmethod
    def schema_data(cls) -> bytes:
        """The FileDescriptorSet of the type, as foxglove-sdk publishes it."""
        return bytes(cls.sdk_class().get_schema().data)

    @classmethod
    def message_class(cls) -> Any:
        return _message_class(cls.TYPE_NAME, cls.schema_data())

    @classmethod
    def json_schema(cls) -> dict:
        """What docs and tools that expect a JSON Schema get: where the real schema comes from."""
        return {
            "title": cls.TYPE_NAME,
            "description": (
                f"Foxglove's {cls.TYPE_NAME}, protobuf-encoded by foxglove-sdk; the MCAP schema is its "
                "FileDescriptorSet (schema encoding `protobuf`)."
            ),
        }

    @classmethod
    def decode(cls, data: bytes) -> Any:
        if not isinstance(data, (bytes, bytearray, memoryview)):
            raise ProtocolError("wrong_type", f"{cls.TYPE_NAME}: expected bytes")
        if len(data) > cls.MAX_BYTES:
            raise ProtocolError("oversized", f"{len(data)} bytes > {cls.MAX_BYTES}")
        msg = cls.message_class()()
        try:
            msg.ParseFromString(bytes(data))
        except Exception as e:  # google.protobuf.message.DecodeError and friends
            raise ProtocolError("malformed", f"{cls.TYPE_NAME}: {str(e)[:100]}") from None
        return msg


@functools.cache
def _message_class(type_name: str, fds: bytes) -> Any:
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

    pool = descriptor_pool.DescriptorPool()  # our own pool: no clash with other users of the default one
    for f in descriptor_pb2.FileDescriptorSet.FromString(fds).file:
        pool.Add(f)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(type_name))


class SceneUpdate(FoxgloveProto):
    """Entities of a 3D scene (`foxglove.SceneUpdate`): the environment's layout, the agent, feedback marks.
    Built by `common.logs.scene` with foxglove-sdk; Foxglove's 3D panel draws it."""

    TYPE_NAME: ClassVar[str] = "foxglove.SceneUpdate"
    SDK_NAME: ClassVar[str] = "SceneUpdate"
