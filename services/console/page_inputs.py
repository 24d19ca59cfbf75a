"""What a person's page sends into the run, as the console's `Hub` publishes it: the paint time of each step
(`Shown`), each press (`Feedback`, with the steps the screen showed), webcam frames, and the person's own
ServiceStatus (`teacher.<id>`). A part of `Hub` (services/console/bridge.py), which owns the state it reads."""

from __future__ import annotations

import collections
import os
import time
from typing import Any

from common.protocol import (
    TEACHER_PREFIX,
    CompressedImage,
    Feedback,
    ServiceStatus,
    Shown,
    Time,
    feedback_key,
    shown_key,
    status_key,
)
from services.console.config import ConsoleConfig
from services.console.ledger import Ledger
from services.console.people import Person


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

    def person_status(self, person: Person, state: str) -> None:
        service = f"{TEACHER_PREFIX}{person.teacher_id}"
        self._publisher(status_key(self.config.run, service)).put(
            ServiceStatus(
                run=self.config.run,
                service=service,
                pid=os.getpid(),
                state=state,
                t=time.time(),
                counters={**self.ledger.counters(person.teacher_id), "frames_published": person.frames_sent},
                incarnation=person.incarnation,
            )
        )

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

    def frame(self, person: Person, t_capture: float, jpeg: bytes) -> None:
        if self.camera_pub is None:
            self.rt.counters["page_rejected_no_camera"] += 1
            return
        if self.actor_stopped:  # the run is over: the perception service may finish
            self.rt.counters["frames_after_end"] += 1
            return
        self.camera_pub.put(
            CompressedImage(
                timestamp=Time.from_seconds(t_capture), frame_id=person.teacher_id, data=jpeg, format="jpeg"
            )
        )
        person.frames_sent += 1
        self.rt.counters["frames_published"] += 1
