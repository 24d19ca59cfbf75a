"""The people at the console and what their pages send into the run: one `Person` per open page (its teacher
identity, clock offset, screen timeline, rate limits); `PageGate`, which checks everything a page sends before it
reaches the run; the `Ledger`, which numbers each press; and `PageInputs`, the part of the console's `Hub`
(services/console/bridge.py, which owns the state it reads) that publishes the paint time of each step (`Shown`)
and each press (`Feedback`, with the steps the screen showed).

A page message is JSON text: `ping` (clock exchange), `shown` (a step was painted), `feedback` (a key press or
button; with the page's own id and press number, so a press re-sent after a reconnect is recognised), `control`
(pause, resume, pace, end; rate-limited per person). Webcam frames are binary: 8 bytes of little-endian float64 page
time, then a JPEG. Anything else, or out of bounds (sizes, timestamps, rates), is rejected with a reason; the
console counts it (`page_rejected_<reason>`) and drops it. (A page's `?name=` and id are checked at its opening.)

The press ledger gives each press its feedback seq, never the same twice and the same again for a press re-sent
after a reconnect, across a console restart too (docs/console.md, "No press is lost"): per teacher id the next seq
and the person's counts, per page (one per browser tab) its teacher id and its recent presses' seqs, written whole
(`atomic_write_json`) to the `state_file` before each feedback is published.
"""

from __future__ import annotations

import collections
import json
import math
import struct
import time
from dataclasses import dataclass, field
from typing import Any

from common.core.screen import ScreenTimeline
from common.protocol import (
    CONTROL_COMMANDS,
    MAX_RATE,
    TOKEN_PATTERN,
    Feedback,
    Shown,
    feedback_key,
    shown_key,
)
from services.common.statefiles import atomic_write_json, read_json
from services.console.config import ConsoleConfig

MAX_TEXT = 4096  # bytes of one JSON page message
KINDS = ("ping", "shown", "feedback", "control")
FEEDBACK_SOURCES = ("key", "button", "script")
_TOKEN_CHARS = set(chr(c) for c in range(0x21, 0x7F))
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


# -- the press ledger --
MAX_PAGES = 16  # pages remembered (oldest forgotten first); the file is rewritten at each press
MAX_PRESSES = 128  # presses remembered per page (a page re-sends only the ones not yet acknowledged)


class Ledger:
    def __init__(self, state_file: str | None):
        self.path = state_file
        state = read_json(state_file) if state_file else None
        state = state or {}
        self.joined = int(state.get("joined", 0))
        self.teachers: dict[str, dict[str, Any]] = state.get("teachers", {})
        self.pages: collections.OrderedDict[str, dict[str, Any]] = collections.OrderedDict(state.get("pages", {}))
        self.restarted = bool(state)
        self.saved_at = 0.0

    def save(self) -> None:
        if self.path:
            atomic_write_json(self.path, {"joined": self.joined, "teachers": self.teachers, "pages": self.pages})
            self.saved_at = time.monotonic()

    def teacher(self, tid: str) -> dict[str, Any]:
        return self.teachers.setdefault(tid, {"next_seq": 0, "received": 0, "published": 0, "resent": 0, "dropped": {}})

    def page_teacher(self, page_id: str | None) -> str | None:
        """The teacher id this page had before (a reload or a reconnect after a console restart)."""
        page = self.pages.get(page_id) if page_id else None
        return None if page is None else page["teacher"]

    def bind(self, page_id: str | None, tid: str) -> None:
        if page_id is None:
            return
        page = self.pages.get(page_id)
        if page is None or page["teacher"] != tid:
            page = {"teacher": tid, "presses": {}}
        self.pages[page_id] = page
        self.pages.move_to_end(page_id)
        while len(self.pages) > MAX_PAGES:
            self.pages.popitem(last=False)

    def dropped(self, tid: str, reason: str) -> None:
        """A press refused before it got a seq: received, and dropped for `reason`."""
        self.teacher(tid)["received"] += 1
        dropped = self.teacher(tid)["dropped"]
        dropped[reason] = dropped.get(reason, 0) + 1
        if time.monotonic() - self.saved_at > 1.0:  # (a flood of refusals does not rewrite the file each time)
            self.save()

    def seq_for(self, tid: str, page_id: str | None, press: int | None) -> tuple[int, bool]:
        """(the seq this press is published with, whether it is a re-send of one published before). Saved."""
        t = self.teacher(tid)
        page = self.pages.get(page_id) if page_id else None
        key = None if press is None or page is None or page["teacher"] != tid else str(press)
        if key is not None and page is not None and key in page["presses"]:
            t["resent"] += 1
            self.save()
            return int(page["presses"][key]), True
        seq = int(t["next_seq"])
        t["next_seq"] = seq + 1
        t["published"] += 1
        t["received"] += 1  # (a re-send of a press this console never got is its first receipt)
        if key is not None and page is not None:
            page["presses"][key] = seq
            while len(page["presses"]) > MAX_PRESSES:
                del page["presses"][next(iter(page["presses"]))]
        self.save()  # before the publish: a console killed right after never reuses this seq
        return seq, False

    def counters(self, tid: str) -> dict[str, int]:
        """The person's counts for their ServiceStatus (and so the run's summary.json)."""
        t = self.teacher(tid)
        out = {
            "feedback_published": int(t["next_seq"]),
            "presses_received": int(t["received"]),
            "presses_resent": int(t["resent"]),
        }
        out.update({f"presses_dropped_{k}": int(v) for k, v in sorted(t["dropped"].items())})
        return out


# -- what a page sends, published --
class PageInputs:
    """Hub's methods for a page's input (the attributes below are Hub's)."""

    config: ConsoleConfig
    rt: Any
    ledger: Ledger
    recent: collections.OrderedDict[tuple[str, int], float]
    span: float
    camera_pub: Any
    actor_stopped: bool
    pubs: dict[str, Any]
    pub: Any

    def _publisher(self, key: str) -> Any:
        if key not in self.pubs:
            self.pubs[key] = self.pub(key)
        return self.pubs[key]

    def shown(self, person: Person, m: dict) -> None:
        t_action = self.recent.get((m["actor"], m["seq"]))
        if m.get("resend"):  # painted before this console started: rebuilds the timeline only (logged then)
            t_action = t_action if t_action is not None else m.get("t_action")
            t_shown = m["t_sys"] if t_action is None else max(m["t_sys"], t_action)
            added = person.timeline.add(m["actor"], m["seq"], t_shown)
            self.rt.counters["shown_resent" if added else "shown_resent_known"] += 1
            return
        if t_action is None:
            self.rt.counters["page_rejected_unknown_step"] += 1
            return
        if m["t_sys"] < t_action:  # painted before the action on the estimated clock: the estimate is off
            self.rt.counters["shown_before_action"] += 1
        t_shown = max(m["t_sys"], t_action)
        if not person.timeline.add(m["actor"], m["seq"], t_shown):
            self.rt.counters["page_rejected_out_of_order"] += 1
            return
        self._publisher(shown_key(self.config.run, person.teacher_id)).put(
            Shown(
                run=self.config.run,
                screen=person.teacher_id,
                actor=m["actor"],
                seq=m["seq"],
                t_action=t_action,
                t_shown=t_shown,
                t_page=max(0.0, m["t_page"]),
                offset=person.offset,
                rtt=min(60.0, person.rtt),
            )
        )
        self.rt.samples["action_to_shown_s"].append(t_shown - t_action)

    def feedback(self, person: Person, m: dict) -> dict:
        """Publish a press (a re-sent one with the seq it had: the learner drops it if it was consumed, and its
        duplicate Credit acknowledges it to the page)."""
        seq, again = self.ledger.seq_for(person.teacher_id, person.page_id, m["press"])
        actor, shown = person.timeline.window(m["t_sys"], self.span)
        fb = Feedback(
            run=self.config.run,
            teacher_id=person.teacher_id,
            seq=seq,
            t_reaction=m["t_sys"],
            value=m["value"],
            source=m["source"],
            t_page=max(0.0, m["t_page"]),
            actor=actor,
            shown=shown if actor is not None else None,
        )
        self._publisher(feedback_key(self.config.run, person.teacher_id)).put(fb)
        self.rt.counters["feedback_resent" if again else "feedback_published_all"] += 1
        return {
            "type": "sent",
            "seq": fb.seq,
            "press": m["press"],
            "value": fb.value,
            "t_reaction": fb.t_reaction,
            "steps_listed": len(shown),
            "resent": again,
        }

    def press_dropped(self, person: Person, reason: str) -> None:
        """A press the page gate refused (flood, absurd time, ...): counted for the person's summary."""
        self.ledger.dropped(person.teacher_id, reason)
