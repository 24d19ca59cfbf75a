"""The people at the console: one `Person` per open page (its teacher identity, clock offset, screen timeline,
rate limits), and `PageGate`, which checks everything a page sends before it reaches the run.

A page message is JSON text: `ping` (clock exchange), `shown` (a step was painted), `feedback` (a key press or
button), `control` (pause, resume, pace, end). Webcam frames are binary: 8 bytes of little-endian float64 page
time, then a JPEG. Anything else, or anything out of bounds (sizes, timestamps, rates), is rejected with a
reason; the console counts it (`page_rejected_<reason>`) and drops it.
"""
from __future__ import annotations

import json
import math
import struct
import time
from dataclasses import dataclass, field
from typing import Any

from common.protocol import CONTROL_COMMANDS, MAX_RATE, TOKEN_PATTERN
from common.core.screen import ScreenTimeline

MAX_TEXT = 4096  # bytes of one JSON page message
KINDS = ("ping", "shown", "feedback", "control")
FEEDBACK_SOURCES = ("key", "button", "script")
_TOKEN_CHARS = set(chr(c) for c in range(0x21, 0x7F))


class PageError(ValueError):
    def __init__(self, reason: str, detail: str = ""):
        super().__init__(f"{reason}: {detail}" if detail else reason)
        self.reason = reason


class RateLimit:
    """At most `rate` events per second on average, bursts up to `burst` (a token bucket)."""

    def __init__(self, rate: float, burst: float | None = None):
        self.rate, self.burst = rate, burst if burst is not None else max(1.0, rate)
        self.tokens, self.t = self.burst, time.monotonic()

    def take(self) -> bool:
        now = time.monotonic()
        self.tokens = min(self.burst, self.tokens + (now - self.t) * self.rate)
        self.t = now
        if self.tokens >= 1.0:
            self.tokens -= 1.0
            return True
        return False


@dataclass
class Person:
    teacher_id: str
    presses: RateLimit
    frames: RateLimit
    timeline: ScreenTimeline = field(default_factory=ScreenTimeline)
    feedback_seq: int = 0
    frames_sent: int = 0
    offset: float = 0.0  # the page's latest estimate: system time - page time (s)
    rtt: float = 0.0
    clock_ready: bool = False  # the page says its clock offset is estimated (static/console.js)
    incarnation: str = ""
    send: Any = None  # coroutine function: send one JSON-able dict to this page


def _number(msg: dict, name: str, lo: float = -1e12, hi: float = 1e12) -> float:
    v = msg.get(name)
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise PageError("wrong_type", f"{name} must be a number")
    if not math.isfinite(v):
        raise PageError("non_finite", name)
    if not lo <= v <= hi:
        raise PageError("bad_value", f"{name} out of range")
    return float(v)


class PageGate:
    """Checks page messages against the console's limits; returns plain dicts with the system times added."""

    def __init__(self, max_clock_skew: float, max_frame_bytes: int, clock=time.time):
        self.max_clock_skew, self.max_frame_bytes, self.clock = max_clock_skew, max_frame_bytes, clock

    def _system_time(self, msg: dict, person: Person, future_slack: float) -> float:
        t_page = _number(msg, "t_page", 0.0)
        offset = _number(msg, "offset", -1e10, 1e10)
        rtt = _number(msg, "rtt", 0.0, 60.0)
        t_sys = t_page + offset
        now = self.clock()
        if not (now - self.max_clock_skew <= t_sys <= now + future_slack):
            raise PageError("absurd_timestamp", f"{t_sys - now:+.3f} s from the server's clock")
        person.offset, person.rtt = offset, rtt
        return t_sys

    def text(self, data: str, person: Person) -> dict:
        if len(data.encode("utf-8", "surrogatepass")) > MAX_TEXT:
            raise PageError("oversized", f"{len(data)} characters")
        try:
            msg = json.loads(data, parse_constant=lambda c: (_ for _ in ()).throw(PageError("non_finite", c)))
        except PageError:
            raise
        except (ValueError, RecursionError):
            raise PageError("malformed", "not JSON") from None
        if not isinstance(msg, dict):
            raise PageError("malformed", "not an object")
        kind = msg.get("type")
        if kind not in KINDS:
            raise PageError("unknown_kind", str(kind)[:40])
        if kind == "ping":
            return {"type": "ping", "t0": _number(msg, "t0"), "ready": msg.get("ready") is True}
        if kind == "shown":
            seq = msg.get("seq")
            actor = msg.get("actor")
            if isinstance(seq, bool) or not isinstance(seq, int) or not 0 <= seq < 2**53:
                raise PageError("bad_value", "seq")
            if not isinstance(actor, str) or not 1 <= len(actor) <= 128 or not set(actor) <= _TOKEN_CHARS:
                raise PageError("bad_value", f"actor must match {TOKEN_PATTERN}")
            t_sys = self._system_time(msg, person, 0.5)
            return {"type": "shown", "seq": seq, "actor": actor, "t_page": float(msg["t_page"]), "t_sys": t_sys}
        if kind == "feedback":
            value = msg.get("value")
            if value not in (-1, 1) or isinstance(value, bool):
                raise PageError("bad_value", "value must be -1 or +1")
            source = msg.get("source", "key")
            if source not in FEEDBACK_SOURCES:
                raise PageError("bad_value", "source")
            t_sys = self._system_time(msg, person, 0.5)
            if not person.presses.take():
                raise PageError("flood", "too many presses")
            return {"type": "feedback", "value": int(value), "source": source, "t_page": float(msg["t_page"]),
                    "t_sys": t_sys}
        command = msg.get("command")
        if command not in CONTROL_COMMANDS:
            raise PageError("bad_value", "command")
        rate = None
        if command == "pace":
            rate = _number(msg, "rate", 0.1, MAX_RATE)
        return {"type": "control", "command": command, "rate": rate}

    def frame(self, data: bytes, person: Person) -> tuple[float, bytes]:
        """A webcam frame: (capture time on the system clock, JPEG bytes)."""
        if len(data) > self.max_frame_bytes + 8:
            raise PageError("oversized_frame", f"{len(data)} bytes")
        if len(data) < 12 or data[8:10] != b"\xff\xd8":
            raise PageError("bad_frame", "not a JPEG")
        (t_page,) = struct.unpack("<d", data[:8])
        if not math.isfinite(t_page):
            raise PageError("non_finite", "frame time")
        t_sys = t_page + person.offset
        now = self.clock()
        if not (now - self.max_clock_skew <= t_sys <= now + 0.5):
            raise PageError("absurd_timestamp", f"frame {t_sys - now:+.3f} s from the server's clock")
        if not person.frames.take():
            raise PageError("frame_flood", "too many frames")
        return t_sys, bytes(data[8:])
