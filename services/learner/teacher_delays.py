"""Returning people's delay estimates (`--profiles DIR`); the estimate a person's console is sent is
`services.learner.books.delay_message`.

The agent keeps one delay model per teacher (`TeacherDelays`, read as `LearnerCore.delays`;
`common.core.delay_model`). With `profiles DIR`, a named person (`web-alice`: the console's `?name=alice`)
starts from the estimate their last session ended with, `DIR/web-alice.json` (`LearnedDelay.state(window=False)`:
their last density becomes the prior), and the learner writes it back atomically every `save_period` seconds
while it moves and at the end.
Numbered people (`web-1`, `web-2`: whoever opened a page first) are not profiled: the next `web-1` is someone
else. Nor is a fixed delay, which learns nothing.

A profile that cannot be read (damaged, not a learned delay) is set aside as `NAME.json.damaged`, counted, and
the person starts from the prior: a bad file never stops a run, and is never silently overwritten. The file
gives only the estimate; the bins and settings are this run's own (a file never sizes the arrays).
"""

from __future__ import annotations

import dataclasses
import json
import os
import re
import time
from pathlib import Path

from common.core.delay_model import LearnedDelay
from services.common.statefiles import atomic_write_json

NUMBERED = re.compile(r"^.+-\d+$")  # the console's anonymous people: web-1, web-2, ...
SAFE_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.:-]{0,63}")  # a protocol name (checked again: it becomes a file)


def profiled(teacher_id: str) -> bool:
    """True for a named person whose estimate is kept across sessions."""
    return not NUMBERED.match(teacher_id) and bool(SAFE_NAME.fullmatch(teacher_id))


class Profiles:
    """The profile directory: a returning person's model on first use, and every learned model written back."""

    def __init__(self, directory: str | os.PathLike | None, save_period: float = 10.0):
        self.directory = Path(directory) if directory else None
        self.save_period = save_period
        self.returning: set[str] = set()  # teachers who started from their profile
        self.damaged = 0
        self._saved: dict[str, int] = {}  # teacher -> feedbacks its model had when its profile was last written
        self._saved_at = time.monotonic()

    def path(self, teacher_id: str) -> Path | None:
        if self.directory is None or not profiled(teacher_id):
            return None
        return self.directory / f"{teacher_id}.json"

    def load(self, teacher_id: str, fresh):
        """The person's model from their profile (a `LearnedDelay` like `fresh`, the new session's), or `fresh`."""
        path = self.path(teacher_id)
        if path is None or not isinstance(fresh, LearnedDelay) or not path.exists():
            return fresh
        try:
            state = json.loads(path.read_text())
            if not isinstance(state, dict) or state.get("kind") != "learned":
                raise ValueError("not a learned delay's profile")
            model = LearnedDelay.from_state(
                {
                    "kind": "learned",
                    "config": dataclasses.asdict(fresh.config),
                    "probs": state["probs"],
                    "feedbacks": int(state.get("feedbacks", 0)),
                }
            )
        except (OSError, ValueError, KeyError, TypeError) as exc:
            self.damaged += 1
            os.replace(path, path.with_name(path.name + ".damaged"))
            print(f"warning: profile {path} set aside ({str(exc)[:80]}): {teacher_id} starts from the prior")
            return fresh
        self.returning.add(teacher_id)
        self._saved[teacher_id] = model.feedbacks
        return model

    def save(self, models: dict, force: bool = False) -> int:
        """Write the profiles of named people whose learned estimate moved since it was last written (at most every
        `save_period` s, or now with `force`). Returns how many were written."""
        if self.directory is None or (not force and time.monotonic() - self._saved_at < self.save_period):
            return 0
        written = 0
        for teacher_id, model in sorted(models.items()):
            path = self.path(teacher_id)
            if path is None or not isinstance(model, LearnedDelay) or self._saved.get(teacher_id) == model.feedbacks:
                continue
            atomic_write_json(path, model.state(window=False))
            self._saved[teacher_id] = model.feedbacks
            written += 1
        self._saved_at = time.monotonic()
        return written
