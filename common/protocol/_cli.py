"""`python -m services protocol`: the protocol's documentation (docs/protocol.md) or one type's JSON Schema."""

from __future__ import annotations

import json
import sys
from dataclasses import dataclass

from common.config import fail, option

from ._base import Message
from ._docs import markdown
from ._keys import MESSAGE_TYPES


@dataclass(frozen=True)
class ProtocolConfig:
    """Print the protocol documentation (Markdown, docs/protocol.md) or the JSON Schema of one message type."""

    markdown: bool = option(False, "print the protocol documentation (Markdown)")
    schema: str | None = option(None, "print the JSON Schema of one type, e.g. Step or hitl.Step")

    def __post_init__(self):
        if self.markdown == (self.schema is not None):
            raise ValueError("give one of --markdown and --schema TYPE")


def protocol_main(args: ProtocolConfig) -> int:
    if args.markdown:
        sys.stdout.write(markdown())
        return 0
    for cls in MESSAGE_TYPES:
        if issubclass(cls, Message) and args.schema in (cls.__name__, cls.TYPE_NAME):
            print(json.dumps(cls.json_schema(), indent=2))
            return 0
    fail(f"unknown type {args.schema!r}; one of {[c.__name__ for c in MESSAGE_TYPES]}")
    return 2
