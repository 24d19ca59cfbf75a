"""The people at the console: one `Person` per open page (its teacher identity, clock offset, screen timeline,
rate limits), and `PageGate`, which checks everything a page sends before it reaches the run.

A page message is JSON text: `ping` (clock exchange), `shown` (a step was painted), `feedback` (a key press or
button; with the page's own id and press number, so a press re-sent after a reconnect is recognised), `control`
(pause, resume, pace, end; rate-limited per person). Webcam frames are binary: 8 bytes of little-endian float64 page
time, then a JPEG. Anything else, or anything out of bounds (sizes, timestamps, rates), is rejected with a
reason; the console counts it (`page_rejected_<reason>`) and drops it.
"""

from __future__ import annotations

import json
import math
import re
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
PAGE_ID = re.compile(r"^[A-Za-z0-9_-]{8,64}$")  # a page's own id (console.js: one per browser tab)
PERSON_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,31}$")  # ?name=: becomes the teacher id <prefix>-<name>
MAX_PRESS_NO = 2**31


class PageError(ValueError):
    def __init__(self, reason: str, detail: str = ""):
        super().__init__(f"{reason}: {detail}" if detail else reason)
        self.reason, self.detail = reason, detail
        self.kind: str | None = None  # "feedback": a press was dropped (its page is told which)
        self.press: int | None = None


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
    frames_sent: int = 0
    offset: float = 0.0  # the page's latest estimate: system time - page time (s)
    rtt: float = 0.0
    clock_ready: bool = False  # the page says its clock offset is estimated (static/console.js)
    incarnation: str = ""
    send: Any = None  # coroutine function: send one JSON-able dict to this page
    controls: RateLimit = field(default_factory=lambda: RateLimit(2.0, 5.0))
    page_id: str | None = None  # the page's own id (kept across its reconnects and reloads)
    last_heard: float = field(default_factory=time.monotonic)  # the page's latest message (monotonic s)
    close: Any = None  # closes this page's socket (a full console makes room by closing silent pages)


def check_name(name: str | None) -> str | None:
    """`?name=` as given, if it is a safe ASCII name; raises PageError (with the rule) otherwise."""
    if name is None or name == "":
        return None
    if not PERSON_NAME.match(name):
        raise PageError(
            "bad_name", "a name is 1-32 ASCII letters, digits, '_', '.' or '-', starting with a letter or digit"
        )
    return name


def check_page_id(page_id: str | None) -> str | None:
    if page_id is None or page_id == "":
        return None
    if not PAGE_ID.match(page_id):
        raise PageError("bad_value", "page id")
    return page_id


def _number(msg: dict, name: str, lo: float = -1e12, hi: float = 1e12) -> float:
    v = msg.get(name)
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise PageError("wrong_type", f"{name} must be a number")
    try:
        v = float(v)  # an integer beyond float's range (10**400) is out of bounds, not an OverflowError
    except OverflowError:
        raise PageError("bad_value", f"{name} out of range") from None
    if not math.isfinite(v):
        raise PageError("non_finite", name)
    if not lo <= v <= hi:
        raise PageError("bad_value", f"{name} out of range")
    return float(v)


class PageGate:
    """Checks page messages against the console's limits; returns plain dicts with the system times added."""

    def __init__(self, max_clock_skew: float, max_frame_bytes: int, clock=time.time, resend_window: float = 300.0):
        self.max_clock_skew, self.max_frame_bytes, self.clock = max_clock_skew, max_frame_bytes, clock
        self.resend_window = resend_window  # how old a press re-sent after a reconnect may be

    def _system_time(self, msg: dict, person: Person, future_slack: float, past: float | None = None) -> float:
        t_page = _number(msg, "t_page", 0.0)
        offset = _number(msg, "offset", -1e10, 1e10)
        rtt = _number(msg, "rtt", 0.0, 60.0)
        t_sys = t_page + offset
        now = self.clock()
        if not (now - (past or self.max_clock_skew) <= t_sys <= now + future_slack):
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
            # A paint cannot be later than its report's arrival: one stamped ahead (a page whose clock estimate is
            # being corrected, docs/console.md) is placed at its arrival, not dropped; an absurd one still is. A
            # paint re-sent after a reconnect (to rebuild a restarted console's timeline) may be older.
            resend = msg.get("resend") is True
            past = self.resend_window if resend else None
            t_sys = min(self._system_time(msg, person, self.max_clock_skew, past), self.clock())
            t_action = _number(msg, "t_action", 0.0, self.clock()) if resend and "t_action" in msg else None
            return {
                "type": "shown",
                "seq": seq,
                "actor": actor,
                "t_page": float(msg["t_page"]),
                "t_sys": t_sys,
                "resend": resend,
                "t_action": t_action,
            }
        if kind == "feedback":
            try:
                return self._feedback(msg, person)
            except PageError as e:  # the page holds its press until told: say which one was dropped
                press = msg.get("press")
                e.press = press if isinstance(press, int) and not isinstance(press, bool) else None
                e.kind = "feedback"
                raise
        command = msg.get("command")
        if command not in CONTROL_COMMANDS:
            raise PageError("bad_value", "command")
        if not person.controls.take():
            raise PageError("control_flood", "too many controls")
        rate = None
        if command == "pace":
            rate = _number(msg, "rate", 0.1, MAX_RATE)
        return {"type": "control", "command": command, "rate": rate}

    def _feedback(self, msg: dict, person: Person) -> dict:
        value = msg.get("value")
        if value not in (-1, 1) or isinstance(value, bool):
            raise PageError("bad_value", "value must be -1 or +1")
        source = msg.get("source", "key")
        if source not in FEEDBACK_SOURCES:
            raise PageError("bad_value", "source")
        press = msg.get("press")
        if press is not None and (
            isinstance(press, bool) or not isinstance(press, int) or not 0 <= press < MAX_PRESS_NO
        ):
            raise PageError("bad_value", "press")
        resend = msg.get("resend") is True and press is not None
        t_sys = self._system_time(msg, person, 0.5, self.resend_window if resend else None)
        if not person.presses.take():  # (the page paces its re-sends below this rate)
            raise PageError("flood", "too many presses")
        return {
            "type": "feedback",
            "value": int(value),
            "source": source,
            "t_page": float(msg["t_page"]),
            "t_sys": t_sys,
            "press": press,
            "resend": resend,
        }

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
