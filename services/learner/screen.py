"""Feedback from a person's screen (the console): credit in seconds over the intervals each step was shown.

A console Feedback lists the steps its person saw (`shown`: Step.seq and the system time each appeared) and is
stamped with the time of the key press or camera frame. The learner credits it through the agent's one door
(`feedback_rounds`, given this `Screen`) with that person's delay in seconds (`LearnerConfig.screen_delay`:
learned per person by default, `common.core.delay_model`), at the moment each step appeared (`screen_credit`
onset) or over its on-screen interval [appeared, next appeared) (interval, Deep TAMER's).

Such a feedback is held until the learner has learned the newest step it lists (the person cannot have
seen a step the actor had not taken, so it comes). Like the step clock, everything here depends only on the
order of the inputs, so `replay retrain` repeats it bit for bit. Whether a press is credited at all, and how, is the
agent's door's (`common.agents.feedback`): this only says what the screen showed.
"""

from __future__ import annotations

import collections

import numpy as np

from common.agents.feedback import Screen
from common.protocol import Feedback


def decode_feedback(text: str) -> Feedback:
    """A Feedback from its checkpointed JSON text (a ValueError if it is another message)."""
    message = Feedback.decode(text.encode())
    if not isinstance(message, Feedback):
        raise ValueError(f"checkpoint: expected a Feedback, got {type(message).__name__}")
    return message


class ScreenCredit:
    """The learner's map from the actor's Step.seq to its step index, and the screen feedback waiting for a step."""

    def __init__(self, capacity: int):
        self.capacity = capacity
        self.index: collections.OrderedDict[int, int] = collections.OrderedDict()  # seq -> step-clock index
        self.seq_of: dict[int, int] = {}  # the inverse: step-clock index -> seq
        self.held: list[tuple[Feedback, int]] = []  # (feedback, ingest position), arrival order
        self.past_actors: list[str] = []  # incarnations replaced by a restart (their feedback cannot be placed)

    def reset(self, retired_actor: str | None = None) -> None:
        self.index.clear()
        self.seq_of.clear()
        if retired_actor is not None:
            self.past_actors = (self.past_actors + [retired_actor])[-16:]

    def learned(self, seq: int, index: int) -> None:
        self.index[int(seq)] = int(index)
        self.seq_of[int(index)] = int(seq)
        while len(self.index) > self.capacity:
            self.seq_of.pop(self.index.popitem(last=False)[1], None)

    def forget_before(self, index: int) -> None:
        """Forget the steps before step-clock `index` (they have left the agent's history)."""
        while self.index and next(iter(self.index.values())) < index:
            self.seq_of.pop(self.index.popitem(last=False)[1], None)

    def must_wait(self, fb: Feedback, actor: str | None, next_seq: int) -> bool:
        """True while the newest step the person saw is not learned yet (or its actor not yet seen)."""
        if fb.actor != actor:
            return fb.actor not in self.past_actors
        return fb.shown[-1].seq >= next_seq if fb.shown else False

    def release(self, actor: str | None, next_seq: int) -> list[tuple[Feedback, int]]:
        """Held feedback that can be credited now, in arrival order."""
        ready = [h for h in self.held if not self.must_wait(h[0], actor, next_seq)]
        if ready:
            self.held = [h for h in self.held if self.must_wait(h[0], actor, next_seq)]
        return ready

    def of(self, fb: Feedback) -> Screen:
        """What `fb`'s person saw (`fb.shown`), for the agent's door: each step's step-clock index (NaN: no longer
        held) and the interval it was on screen, [appeared, next appeared)."""
        if fb.shown is None:
            raise ValueError("a feedback without a screen has no steps shown")
        starts = np.array([s.t for s in fb.shown], np.float64)
        times = np.array([self.index.get(s.seq, np.nan) for s in fb.shown], np.float64)
        return Screen(times, starts, np.append(starts[1:], np.inf))

    def state(self) -> dict:
        return {
            "index": [[k, v] for k, v in self.index.items()],
            "past_actors": list(self.past_actors),
            "held": [[fb.encode().decode(), pos] for fb, pos in self.held],
        }

    def load(self, state: dict) -> None:
        self.index = collections.OrderedDict((int(k), int(v)) for k, v in state["index"])
        self.seq_of = {i: q for q, i in self.index.items()}
        self.past_actors = [str(a) for a in state["past_actors"]]
        self.held = [(decode_feedback(fb), int(pos)) for fb, pos in state["held"]]
