"""A person's run controls as the actor obeys them (Control messages from the console on `hitl/<run>/control`):
pause, resume, pace (steps per second) and end. Malformed ones are counted by reason and dropped."""

from __future__ import annotations

import time

from common.protocol import Control, ProtocolError


class RunControl:
    """The actor's pace and pause state, fed by a Control inbox (a `common.wire.transport` subscription)."""

    def __init__(self, rate: float, counters, log, paused: bool = False):
        self.period = 1.0 / rate if rate > 0 else 0.0
        self.paused = paused
        self.end = False
        self.counters, self.log = counters, log
        self._paused_at: float | None = time.monotonic() if paused else None
        if paused:
            self.log("paused until a resume (a console resumes when its first page opens)")

    def take(self, inbox) -> bool:
        """Apply what arrived. True if the pace or the pause state changed (the caller restarts its tick)."""
        changed = False
        for item in inbox.drain():
            try:
                msg = item.decode()
            except ProtocolError as e:
                self.counters[f"control_rejected_{e.reason}"] += 1
                continue
            if not isinstance(msg, Control):
                self.counters["control_rejected_wrong_type"] += 1
                continue
            self.counters[f"control_{msg.command}"] += 1
            if msg.command == "pause" and not self.paused:
                self.paused, self._paused_at, changed = True, time.monotonic(), True
                self.log(f"paused by {msg.source}")
            elif msg.command == "resume" and self.paused:
                self.paused, changed = False, True
                if self._paused_at is not None:
                    self.counters["paused_ms"] += int((time.monotonic() - self._paused_at) * 1e3)
                self.log(f"resumed by {msg.source}")
            elif msg.command == "pace" and msg.rate is not None:  # (Control's check: a pace carries a rate)
                self.period, changed = 1.0 / float(msg.rate), True
                self.log(f"pace {msg.rate:g} steps/s (asked by {msg.source})")
            elif msg.command == "end":
                self.end, changed = True, True
                self.log(f"run ended by {msg.source}")
        return changed
