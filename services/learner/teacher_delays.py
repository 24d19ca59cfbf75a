"""Each teacher's delay model in seconds (`common.core.delay_model`), and returning people's profiles.

The learner credits a person's screen feedback with their own delay model, made on first use from its
`screen-delay` setting (`learned`, `learned:PRIOR` or a fixed spec). With `profiles DIR`, a named person
(`web-alice`: the console's `?name=alice`) starts from the estimate their last session ended with,
`DIR/web-alice.json` (`LearnedDelay.state(window=False)`: their last density becomes the prior), and the learner
writes it back atomically every `save_period` seconds while it changes and at the end. Numbered people
(`web-1`, `web-2`: whoever opened a page first) are not profiled: the next `web-1` is someone else.

A profile that cannot be read (damaged, another config's bins) is set aside as `NAME.json.damaged`, counted, and
the person starts from the prior: a bad file never stops a run, and is never silently overwritten.
"""
from __future__ import annotations

import dataclasses
import json
import os
import re
import time
from pathlib import Path

import numpy as np

from common.core.delay_model import LearnedDelay, delay_estimate
from common.protocol import DelayEstimate
from services.common.statefiles import atomic_write_json

NUMBERED = re.compile(r"^.+-\d+$")  # the console's anonymous people: web-1, web-2, ...
SAFE_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.:-]{0,63}")  # a protocol name (checked again: it becomes a file)


def profiled(teacher_id: str) -> bool:
    """True for a named person whose estimate is kept across sessions."""
    return not NUMBERED.match(teacher_id)


def delay_message(model, returning: bool = False) -> DelayEstimate:
    """A model's current estimate as sent to the person's console (the density's bins and its quantiles)."""
    edges, probs = model.density()
    s = model.summary()
    return DelayEstimate(median_s=float(s["median_s"]), p10_s=float(s["p10_s"]), p90_s=float(s["p90_s"]),
                         feedbacks=int(s["feedbacks"]), bin_s=float(edges[1] - edges[0]),
                         probs=[round(float(p), 5) for p in np.clip(probs, 0.0, 1.0)], returning=returning)


class TeacherDelays:
    def __init__(self, spec: str, reference: str, profiles: str | os.PathLike | None = None,
                 save_period: float = 10.0):
        self.spec, self.reference = spec, reference
        self.profiles = Path(profiles) if profiles else None
        self.save_period = save_period
        self.models: dict[str, object] = {}
        self.dirty: set[str] = set()  # teachers whose estimate moved since their profile was written
        self.returning: set[str] = set()  # teachers who started from their profile
        self.damaged = 0
        self._saved_at = time.monotonic()

    def model(self, teacher_id: str):
        """The teacher's delay model (made, or read from their profile, on first use)."""
        m = self.models.get(teacher_id)
        if m is None:
            m = self.models[teacher_id] = self._load(teacher_id) or delay_estimate(self.spec, self.reference)
        return m

    def observed(self, teacher_id: str) -> None:
        """The teacher's model learned from a feedback (its profile is due for writing)."""
        self.dirty.add(teacher_id)

    def estimate(self, teacher_id: str) -> DelayEstimate:
        model = self.model(teacher_id)
        return delay_message(model, teacher_id in self.returning)

    def summaries(self) -> dict[str, dict]:
        """{teacher: {median_s, p10_s, p90_s, feedbacks}} for every teacher seen (`summary.json`'s delay block)."""
        return {t: m.summary() for t, m in self.models.items()}

    # -- profiles ------------------------------------------------------------------------------------------------
    def _path(self, teacher_id: str) -> Path | None:
        if self.profiles is None or not profiled(teacher_id) or not SAFE_NAME.fullmatch(teacher_id):
            return None
        return self.profiles / f"{teacher_id}.json"  # (teacher ids are protocol names: no separators)

    def _load(self, teacher_id: str):
        path = self._path(teacher_id)
        fresh = delay_estimate(self.spec, self.reference)
        if path is None or not path.exists() or not isinstance(fresh, LearnedDelay):
            return None
        try:
            state = json.loads(path.read_text())
            if not isinstance(state, dict) or state.get("kind") != "learned" or "rows" in state:
                raise ValueError("not a learned delay's profile")
            # this run's own bins and settings (a file never sizes the arrays); the file gives the estimate
            model = LearnedDelay.from_state({"kind": "learned", "config": dataclasses.asdict(fresh.config),
                                             "probs": state["probs"], "feedbacks": int(state.get("feedbacks", 0))})
        except (OSError, ValueError, KeyError, TypeError) as exc:
            self.damaged += 1
            os.replace(path, path.with_name(path.name + ".damaged"))
            print(f"warning: profile {path} set aside ({str(exc)[:80]}): {teacher_id} starts from the prior")
            return None
        self.returning.add(teacher_id)
        return model

    def save(self, force: bool = False) -> int:
        """Write the profiles of teachers whose estimate moved (every `save_period` s, or now with `force`)."""
        if not self.dirty or (not force and time.monotonic() - self._saved_at < self.save_period):
            return 0
        written = 0
        for teacher_id in sorted(self.dirty):
            path, m = self._path(teacher_id), self.models.get(teacher_id)
            if path is not None and isinstance(m, LearnedDelay):
                atomic_write_json(path, m.state(window=False))
                written += 1
        self.dirty.clear()
        self._saved_at = time.monotonic()
        return written
