"""A measurement: the protocol's CPU on a real run's traffic, the engine against the full check alone.

Run `python -m common.protocol.msgspec_bench RUN/session.mcap` (the log of a `services bench` paper phase, say):
every JSON message of the log is decoded and encoded with `decode`/`encode` as they are (msgspec generated from the
specs, `FastDecoder` in `_base.py`, the full check for the rest) and with the hand-written full check alone; CPU
time, best of 3, per step of the log and per message of each type, and how many messages the msgspec decoders took.
Each message counts once: live, a Step is decoded by three services.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from mcap.reader import make_reader

from ._base import Message, fast_decoder, parse_json


def _types(base: type[Message] = Message) -> Iterator[type[Message]]:
    sub: type[Message]
    for sub in base.__subclasses__():
        yield sub
        yield from _types(sub)


def read(path: str) -> list[tuple[type[Message], bytes]]:
    by_name = {cls.TYPE_NAME: cls for cls in _types() if cls.TYPE_NAME}
    out = []
    with open(path, "rb") as f:
        for schema, _, message in make_reader(f).iter_messages():
            cls = by_name.get(schema.name) if schema is not None and schema.encoding == "jsonschema" else None
            if cls is not None:
                out.append((cls, message.data))
    return out


def full_encode(msg: Message) -> bytes:  # (``encode`` before the engine: the object, its full check, the stdlib)
    obj = msg.to_json_obj()
    type(msg).from_json_obj(obj)
    return json.dumps(obj, separators=(",", ":"), allow_nan=False, ensure_ascii=False).encode()


def cpu_s(fn: Callable[[], Any]) -> float:
    best = float("inf")
    for _ in range(3):
        start = time.process_time()
        fn()
        best = min(best, time.process_time() - start)
    return best


def times(records: list[tuple[type[Message], bytes]]) -> tuple[float, float, float, float]:
    """CPU s to decode all (full check, engine) and to encode all (full check, engine)."""
    messages = [cls.decode(data) for cls, data in records]
    return (
        cpu_s(lambda: [cls.from_json_obj(parse_json(data, cls.MAX_BYTES)) for cls, data in records]),
        cpu_s(lambda: [cls.decode(data) for cls, data in records]),
        cpu_s(lambda: [full_encode(m) for m in messages]),
        cpu_s(lambda: [m.encode() for m in messages]),
    )


def report(log: str) -> None:
    if not Path(log).is_file():
        raise SystemExit(f"{log}: no such log (give a run's session.mcap, e.g. from `python -m services bench`)")
    records = read(log)
    steps = sum(1 for cls, _ in records if cls.TYPE_NAME == "hitl.Step") or 1
    dec_full, dec_engine, enc_full, enc_engine = times(records)
    print(f"{len(records)} JSON messages, {steps} steps; microseconds of CPU per step of the log:")
    print(f"  decode: full check {dec_full * 1e6 / steps:.1f}, engine {dec_engine * 1e6 / steps:.1f}")
    print(f"  encode: full check {enc_full * 1e6 / steps:.1f}, engine {enc_engine * 1e6 / steps:.1f}")
    print("\n| type | messages | msgspec took | decode full / engine (us each) | encode full / engine (us each) |")
    print("|---|---|---|---|---|")
    for name in sorted({cls.TYPE_NAME for cls, _ in records}):
        part = [(cls, data) for cls, data in records if cls.TYPE_NAME == name]
        took = sum(1 for cls, data in part if fast_decoder(cls).decode(data) is not None)
        us = [t * 1e6 / len(part) for t in times(part)]
        print(f"| {name} | {len(part)} | {took} | {us[0]:.1f} / {us[1]:.1f} | {us[2]:.1f} / {us[3]:.1f} |")
