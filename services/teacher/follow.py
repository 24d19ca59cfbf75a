"""Which actor a teacher is watching, and whether a step is news: the bookkeeping every teacher shares."""

from __future__ import annotations

import collections

from common.protocol import Step


class StepFollower:
    """The actor incarnation followed and the next step seq expected from it (counted into `counters`)."""

    def __init__(self, counters: collections.Counter):
        self.counters = counters
        self.actor: str | None = None
        self.next_seq = 0

    def follow(self, step: Step) -> tuple[bool, bool]:
        """(the actor restarted: reactions to its old incarnation are void, the step is news: not older than
        the one expected; lost steps before it are counted)."""
        restarted = False
        if step.incarnation != self.actor:
            if self.actor is not None:
                self.counters["actor_restarts"] += 1
                restarted = True
            self.actor = step.incarnation
            self.next_seq = step.seq
        if step.seq != self.next_seq:
            self.counters["steps_lost" if step.seq > self.next_seq else "steps_old"] += 1
            if step.seq < self.next_seq:
                return restarted, False
        self.next_seq = step.seq + 1
        return restarted, True
