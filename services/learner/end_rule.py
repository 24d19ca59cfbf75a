"""When the learner stops: the actor stopped and all its steps are learned, and every known teacher's feedback has
arrived (or `end_grace` s have passed waiting for it). Fed by the services' statuses; wall-clock only, so it decides
when the service ends, never what it learned."""

from __future__ import annotations

import time

from common.protocol import ServiceStatus, teacher_id_of
from services.common.runtime import ServiceRuntime
from services.learner.core import LearnerCore


class EndRule:
    """The actor's and each teacher's final counts, from their "stopped" statuses."""

    def __init__(self, wait_teachers: tuple[str, ...], end_grace: float, rt: ServiceRuntime):
        self.end_grace, self.rt = end_grace, rt
        self.actor_final: int | None = None
        self.teachers_final: dict[str, int] = {}
        self.teachers_known: set[str] = set(wait_teachers)
        self.caught_up_at: float | None = None

    def on_status(self, st: ServiceStatus, actor: str | None) -> None:
        teacher = teacher_id_of(st.service)
        if teacher is not None:
            self.teachers_known.add(teacher)
        if st.state != "stopped":
            return
        if st.service == "actor" and (st.incarnation is None or st.incarnation == actor):
            self.actor_final = int(st.counters.get("steps_published", 0))
        elif teacher is not None:
            self.teachers_final[teacher] = int(st.counters.get("feedback_published", 0))

    def finished(self, core: LearnerCore, waiting_inputs: int, actor: str | None) -> bool:
        """True once the run may end (see the module's docstring)."""
        if self.actor_final is None or waiting_inputs or core.next_seq < self.actor_final or core.actor != actor:
            return False
        if self.caught_up_at is None:
            self.caught_up_at = time.monotonic()
        waiting = [
            t
            for t in sorted(self.teachers_known)
            if t not in self.teachers_final or core.teacher_next.get(t, 0) < self.teachers_final[t]
        ]
        if not waiting:
            return True
        if time.monotonic() - self.caught_up_at > self.end_grace:
            self.rt.log(f"end: stopped waiting for teacher(s) {waiting} after {self.end_grace} s")
            self.rt.counters["end_grace_expired"] += 1
            return True
        return False
