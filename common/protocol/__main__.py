"""``python -m common.protocol --markdown`` prints docs/protocol.md; ``--schema NAME`` prints one JSON Schema."""

from __future__ import annotations

import argparse
import json
import sys

from ._docs import markdown
from ._keys import MESSAGE_TYPES


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m common.protocol", description=__doc__)
    group = parser.add_mutually_exclusive_group(required=True)
    group.add_argument("--markdown", action="store_true", help="print the protocol documentation (Markdown)")
    group.add_argument("--schema", metavar="TYPE", help="print the JSON Schema of one type, e.g. Step or hitl.Step")
    args = parser.parse_args(argv)
    if args.markdown:
        sys.stdout.write(markdown())
        return 0
    for cls in MESSAGE_TYPES:
        if args.schema in (cls.__name__, cls.TYPE_NAME):
            print(json.dumps(cls.json_schema(), indent=2))
            return 0
    parser.error(f"unknown type {args.schema!r}; one of {[c.__name__ for c in MESSAGE_TYPES]}")
    return 2


if __name__ == "__main__":
    sys.exit(main())
