"""The console's press ledger: which feedback seq each person's press became, kept across a console restart.

A teacher's feedback seq must never be used twice (the learner drops a seq it has consumed as a duplicate), also
when the console is restarted (SIGKILL, crash) or a named person comes back (`?name=alice` twice). And a press
that a page re-sends after a reconnect (it keeps every press until the learner's credit acknowledges it) must
become the same seq again, so the learner credits it at most once.

So the ledger keeps, per teacher id, the next seq and the person's counts (presses received, published,
re-sent, dropped by reason), and per page (its own id, one per browser tab) its teacher id and the seq of each of
its recent presses. With a `state_file` (the launcher gives one) it is written whole (`atomic_write_json`) before
each feedback is published: a console restarted after a SIGKILL continues every teacher's seq and recognises
re-sent presses.
"""

from __future__ import annotations

import collections
import time
from typing import Any

from services.common.statefiles import atomic_write_json, read_json

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
