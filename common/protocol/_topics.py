"""Log topics: the key without its run, so one Foxglove layout fits every run's log.

A key ``hitl/<run>/<kind>[/<name>]`` is logged on topic ``/<kind>[/<name>]``; the run is in the log's
metadata (``hitl.run``) and its first message. Readers put the run back to get the key.
"""

from __future__ import annotations

from ._keys import ROOT, parse_key, validate_name
from ._spec import ProtocolError


def log_topic(key: str) -> str:
    """``hitl/<run>/step`` -> ``/step``; ``hitl/<run>/feedback/oracle`` -> ``/feedback/oracle``."""
    parsed = parse_key(key)
    return "/" + key.split("/", 2)[2] if parsed else key


def key_from_topic(topic: str, run: str) -> str:
    """The key a log topic stands for in `run`. A topic that is already a whole key (logs written before
    topics dropped the run) is returned as it is."""
    if topic.startswith(ROOT + "/"):
        return topic
    if not topic.startswith("/"):
        raise ProtocolError("unknown_key", f"log topic {topic[:120]!r}")
    validate_name(run, "run")
    return f"{ROOT}/{run}{topic}"


def topics_table() -> list[str]:
    """Markdown rows: every log topic, its key, schema and message encoding (docs/protocol.md)."""
    from ._keys import KEYS

    rows = ["| topic | key | MCAP schema (encoding) | message encoding |", "|---|---|---|---|"]
    for spec in KEYS.values():
        cls = spec.message
        tail = f"/<{spec.param}>" if spec.param else ""
        schema_encoding = getattr(cls, "SCHEMA_ENCODING", "jsonschema")
        rows.append(
            f"| `/{spec.kind}{tail}` | `{spec.pattern()}` | `{cls.TYPE_NAME}` ({schema_encoding}) "
            f"| `{cls.MESSAGE_ENCODING}` |"
        )
    return rows
