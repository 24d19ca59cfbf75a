"""The learner's books: where its inputs lie on the step clock and on a person's screen, and the messages it
publishes about them besides its Weights (a feedback's Credit, a person's DelayEstimate, the log's
WeightsSnapshots). Everything here runs on a step's or a press's path; none of it touches the agent.

The step clock: wall-clock times mapped onto step numbers, so the live system keeps the in-process runner's
virtual-time semantics on real timestamps. Step k's action was taken at wall time t_k; on the step clock it is at
k, and a time between two actions is placed linearly between them: tau(t) = k + (t - t_k) / (t_{k+1} - t_k) for
t_k <= t < t_{k+1}. At a fixed actor rate this is wall time divided by the step period (plus a constant); at "as
fast as possible" it makes step durations irrelevant, so a delay of d steps means d steps whatever the machine's
speed. Only defined where both neighbouring actions are known: a time at or after the newest action is not yet
placeable (the caller holds it until a newer step arrives). The oracle teacher keeps the same clock.

Feedback from a person's screen (the console): a console Feedback lists the steps its person saw (`shown`:
Step.seq and the system time each appeared) and is stamped with the time of the key press or camera frame. The
learner credits it through the agent's one door (`feedback_rounds`, given this `Screen`) with that person's delay
in seconds (`LearnerConfig.screen_delay`: learned per person by default, `common.core.delay_model`), at the moment
each step appeared (`screen_credit` onset) or over its on-screen interval [appeared, next appeared) (interval, Deep
TAMER's). Such a feedback is held until the learner has learned the newest step it lists (the person cannot have
seen a step the actor had not taken, so it comes). Like the step clock, everything here depends only on the order
of the inputs, so `replay retrain` repeats it bit for bit. Whether a press is credited at all, and how, is the
agent's door's (`common.agents.feedback`): this only says what the screen showed.

Snapshots: the actor needs the weights after almost every step (lockstep), on `hitl/<run>/weights`, which the
recorder does not log. The log gets a WeightsSnapshot on `hitl/<run>/snapshot`: the first weights, then every
`snapshot_every` steps learned, at each episode end (summary numbers only, no raw bytes), on request
(`hitl/<run>/request`, at most one per `REQUEST_GAP` s) and the final weights (which `replay retrain` compares with
its own). No learner state is touched: only what is published.
"""

from __future__ import annotations

import bisect
import collections
import math
import time
from collections import deque
from collections.abc import Callable
from typing import Any

import numpy as np

from common.agents.feedback import Screen
from common.protocol import (
    MAX_INGEST_CREDITS,
    Credit,
    CreditedStep,
    DelayEstimate,
    EpisodeSummary,
    Feedback,
    ProtocolError,
    Request,
    TensorSummary,
    WeightsSnapshot,
    credit_key,
)


class StepClock:
    """Recent (step number, wall time) pairs, consecutive numbers, strictly increasing times."""

    def __init__(self, capacity: int = 64):
        if capacity < 2:
            raise ValueError("capacity must be >= 2")
        self.capacity = capacity
        self._index: deque[int] = deque()
        self._time: deque[float] = deque()

    def __len__(self) -> int:
        return len(self._index)

    def reset(self) -> None:
        self._index.clear()
        self._time.clear()

    def push(self, index: int, t_wall: float) -> None:
        """Step `index` acted at `t_wall`. A non-consecutive index or a time not after the previous one starts
        the clock afresh (the steps in between are unknown)."""
        if self._index and (index != self._index[-1] + 1 or not t_wall > self._time[-1]):
            self.reset()
        self._index.append(int(index))
        self._time.append(float(t_wall))
        if len(self._index) > self.capacity:
            self._index.popleft()
            self._time.popleft()

    @property
    def newest_index(self) -> int | None:
        return self._index[-1] if self._index else None

    @property
    def newest_time(self) -> float | None:
        return self._time[-1] if self._time else None

    @property
    def oldest_index(self) -> int | None:
        return self._index[0] if self._index else None

    def placeable(self, t_wall: float) -> bool:
        """True when t_wall lies before the newest action (so its interval is known)."""
        return bool(self._time) and t_wall < self._time[-1]

    def to_steps(self, t_wall: float) -> float:
        """The step-clock time of `t_wall`. Before the oldest held action: one step before it (the credit
        function then finds nothing to credit). Raises ValueError if not `placeable`."""
        if not self.placeable(t_wall):
            raise ValueError("time at or after the newest step is not placeable yet")
        times = self._time
        if t_wall < times[0]:
            return float(self._index[0]) - 1.0
        j = bisect.bisect_right(times, t_wall) - 1  # times[j] <= t_wall < times[j + 1]
        return self._index[j] + (t_wall - times[j]) / (times[j + 1] - times[j])

    def to_wall(self, tau: float) -> float | None:
        """The wall time of step-clock time `tau`, or None while step ceil(tau) has not been seen (or tau is
        older than the clock holds)."""
        if not self._index or not math.isfinite(tau):
            return None
        k = math.floor(tau)
        if k < self._index[0] or k + 1 > self._index[-1]:
            if k == self._index[-1] and tau == k:
                return self._time[-1]
            return None
        j = k - self._index[0]
        t0, t1 = self._time[j], self._time[j + 1]
        return t0 + (tau - k) * (t1 - t0)


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
            "index": list(self.index.items()),  # (pairs: JSON writes them as [seq, index], as before)
            "past_actors": list(self.past_actors),
            "held": [[fb.encode().decode(), pos] for fb, pos in self.held],
        }

    def load(self, state: dict) -> None:
        self.index = collections.OrderedDict((int(k), int(v)) for k, v in state["index"])
        self.seq_of = {i: q for q, i in self.index.items()}
        self.past_actors = [str(a) for a in state["past_actors"]]
        self.held = [(decode_feedback(fb), int(pos)) for fb, pos in state["held"]]


# -- what the learner publishes about each feedback: its Credit, and the person's delay estimate --


def episode_message(run: str, ep) -> EpisodeSummary:
    """The `EpisodeSummary` of an episode the learner has ended (`services.learner.core.EpisodeRecord`)."""
    return EpisodeSummary(
        run=run,
        incarnation=ep.incarnation,
        episode=ep.episode,
        return_=ep.return_,
        steps=ep.steps,
        feedback_received=ep.feedback_received,
        feedback_credited=ep.feedback_credited,
        weights_version=ep.weights_version,
        t_end=ep.t_end,
    )


def credit_message(run: str, result, actor: str | None, t_done: float, delay=None) -> Credit:
    """The `Credit` of one resolved feedback: the steps it was credited to, with their weights (and the teacher's
    delay estimate, `delay`, for a person's console)."""
    fb = result.feedback
    return Credit(
        run=run,
        teacher_id=fb.teacher_id,
        seq=fb.seq,
        value=fb.value,
        status=result.status,
        t_reaction=fb.t_reaction,
        t_credited=t_done,
        actor=fb.actor or actor,
        steps=[CreditedStep(int(q), min(1.0, float(w))) for q, w in heaviest(result.credited)],
        lost_mass=min(1.0, max(0.0, float(result.lost_mass))),
        delay=delay,
        revision=result.revision,
    )


# A Credit lists at most this many steps, so that it stays within its size limit (10 KB) with a delay estimate:
# a feedback credited in seconds over a long history (history_s) can spread over hundreds of steps.
MAX_LISTED_STEPS = 128


def heaviest(credited: list) -> list:
    """[(Step.seq, weight)]: the MAX_LISTED_STEPS of largest weight (ties: the newer), oldest first."""
    if len(credited) <= MAX_LISTED_STEPS:
        return list(credited)
    kept = sorted(credited, key=lambda qw: (-float(qw[1]), -int(qw[0])))[:MAX_LISTED_STEPS]
    return sorted(kept, key=lambda qw: int(qw[0]))


def listed_steps(seq_of: dict[int, int], times, weights) -> list[tuple[int, float]]:
    """[(Step.seq, weight)] of the credited steps (step-clock `times`, their `weights`) whose Step.seq the learner
    still knows (`seq_of`), as `heaviest` lists them: at 250 steps/s a feedback credited in seconds spreads over a
    thousand steps, and choosing in numpy first saves building and sorting a thousand pairs for each feedback."""
    index = np.asarray(times).astype(np.int64)
    w = np.asarray(weights, np.float64)
    kept = []
    for k in np.lexsort((-index, -w)).tolist():  # heaviest first, the newer on ties (Step.seq grows with the index)
        seq = seq_of.get(int(index[k]))
        if seq is not None:
            kept.append((seq, float(w[k])))
            if len(kept) == MAX_LISTED_STEPS:
                break
    return sorted(kept)


INGEST_LISTED_STEPS = 256  # an Ingest goes out once its waiting Credits list this many steps


def take_credits(pending: list[Credit]) -> tuple[list[Credit], int]:
    """The oldest waiting Credits for one Ingest (removed from `pending`) and the steps they list: at least one,
    then while they list fewer than INGEST_LISTED_STEPS. Encoding costs about 3 us a listed step; at 250 steps/s
    one Ingest of 13 Credits listed 1,700 steps, 10-18 ms of the learner's loop that the steps behind it waited for."""
    n, listed = 0, 0
    while n < min(len(pending), MAX_INGEST_CREDITS) and (n == 0 or listed < INGEST_LISTED_STEPS):
        listed += len(pending[n].steps)
        n += 1
    taken = pending[:n]
    del pending[:n]
    return taken, listed


def publish_credit(session, pubs: dict, credit: Credit) -> None:
    """A Credit on its own key, `hitl/<run>/credit/<teacher_id>` (a publisher per teacher, made once)."""
    from common.wire.transport import MessagePublisher

    pub = pubs.get(credit.teacher_id)
    if pub is None:
        pub = pubs[credit.teacher_id] = MessagePublisher(session, credit_key(credit.run, credit.teacher_id))
    pub.put(credit)


def delay_message(model, returning: bool = False) -> DelayEstimate:
    """A model's current estimate as sent to the person's console (the density's bins and its quantiles)."""
    edges, probs = model.density()
    s = model.summary()
    return DelayEstimate(
        median_s=float(s["median_s"]),
        p10_s=float(s["p10_s"]),
        p90_s=float(s["p90_s"]),
        feedbacks=int(s["feedbacks"]),
        bin_s=float(edges[1] - edges[0]),
        probs=[round(float(p), 5) for p in np.clip(probs, 0.0, 1.0)],
        returning=returning,
    )


# -- the log's WeightsSnapshots --


REQUEST_GAP = 0.5  # s between two snapshots made on request


def tensor_summaries(tensors: dict[str, np.ndarray]) -> list[TensorSummary]:
    """Mean, std, min, max and norm of each tensor, in float64: the numbers of `a.mean()`, `a.std()`, ... bit for
    bit, computed with the reductions those make (at every episode end their call overhead was the cost)."""
    out = []
    for name, t in tensors.items():
        a = np.asarray(t, np.float64)
        n = a.size
        if not n:
            out.append(TensorSummary(name, list(a.shape), 0.0, 0.0, 0.0, 0.0, 0.0))
            continue
        mean = np.add.reduce(a, axis=None) / n
        d = a - mean
        d *= d
        out.append(
            TensorSummary(
                name,
                list(a.shape),
                float(mean),
                float(np.sqrt(np.add.reduce(d, axis=None) / n)),
                float(np.minimum.reduce(a, axis=None)),
                float(np.maximum.reduce(a, axis=None)),
                float(np.sqrt(np.add.reduce(a * a, axis=None))),
            )
        )
    return out


class Snapshots:
    """Decides and publishes WeightsSnapshots. `publish(message)` sends one (the service's publish_kept)."""

    def __init__(self, run: str, incarnation: str, every: int, publish: Callable[[WeightsSnapshot], object]):
        self.run, self.incarnation, self.every, self._publish = run, incarnation, every, publish
        self.last_version: int | None = None  # of the last snapshot with raw weights
        self._last_request = 0.0
        self.counts: dict[str, int] = {}

    def _send(self, reason: str, version: int, tensors: dict[str, np.ndarray], raw: bytes | None) -> None:
        self._publish(
            WeightsSnapshot(
                run=self.run,
                incarnation=self.incarnation,
                version=version,
                reason=reason,
                t_published=time.time(),
                tensors=tensor_summaries(tensors),
                weights=raw,
            )
        )
        self.counts[reason] = self.counts.get(reason, 0) + 1
        if raw is not None:
            self.last_version = version

    def on_weights(self, version: int, tensors: dict[str, np.ndarray], raw: bytes) -> None:
        """After each Weights publication: a snapshot if it is the first or `every` steps have passed."""
        if self.last_version is None:
            self._send("start", version, tensors, raw)
        elif version - self.last_version >= self.every:
            self._send("every", version, tensors, raw)

    def on_episode(self, version: int, tensors: dict[str, np.ndarray]) -> None:
        self._send("episode", version, tensors, None)

    def on_requests(self, items: list[Any], version: int, weights: Callable[[], tuple[dict, bytes]]) -> None:
        """Requests received (inbox items); answers at most one per REQUEST_GAP s."""
        asked = False
        for it in items:
            try:
                asked |= isinstance(it.decode(), Request)
            except ProtocolError:
                continue
        if asked and time.monotonic() - self._last_request >= REQUEST_GAP:
            self._last_request = time.monotonic()
            tensors, raw = weights()
            self._send("request", version, tensors, raw)

    def final(self, version: int, tensors: dict[str, np.ndarray], raw: bytes) -> None:
        self._send("final", version, tensors, raw)
