"""Feedback into the agent: the one door every feedback passes (`TrialBatchAgent` inherits it), whichever the
driver (the in-process runner, the live learner, `replay retrain`).

`feedback_rounds` takes rounds of feedback of many trials at once, each from a named teacher (the runner's one
teacher per trial by default) and, for a person, the screen that showed the steps. The agent's registry of its
teachers' delays (`TeacherDelays`, below) says how each is credited, by one rule (credit over
the intervals the steps were shown, `common.core.credit`):
  on the step clock  a teacher without a delay in seconds: the assumed point-mass lags, batched over the held
                     steps' intervals (the paper's);
  in seconds         a teacher with a delay in seconds (`common.core.delay_model`: learned or fixed; it also
                     learns from the feedback), over the intervals the held steps were shown: on the person's
                     screen (`Screen`) or at the times they were taken (`record_steps`' seconds).
Shaping trials add the value to the reward of the newest step shown at or before the feedback; H trials grow
D_global and take one H step on D_local. A feedback's candidates are the held steps shown before it, whatever
their episode. `credited(k)` says which held steps the latest round's k-th trial credited, with what weight.

The registry (`TeacherDelays`): per trial the assumed point-mass lags of the step clock (`RowDelays` when trials
differ, for the batched credit function), and per teacher a delay in seconds, learned online or fixed. The
in-process runner has one simulated teacher per trial (`DEFAULT_TEACHER`); its virtual clock gives each step a
duration in seconds (`step_seconds`), so a trial whose config says `learn_delay` credits its feedback with its own
teacher's learned density in seconds. The live learner has one trial and many teachers (an oracle, people at
consoles), each with its own entry in the same registry: one place, whichever driver.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from common.agents.memory import BatchCredit, BatchStepHistory, FeedbackMemory, TransitionReplay
from common.agents.networks import SQUARED_SUM, FitJob, ValueNetworks
from common.core.delay import DelayModel, RowDelays
from common.core.delay_model import LearnedDelay, LearnedDelayConfig, estimate_from_state, polarity_likelihood

# Status codes of `feedback_rounds` (the strings of FeedbackOutcome.status, in this order).
IGNORED, CREDITED, STALE = 0, 1, 2
STATUS_NAMES = ("ignored", "credited", "stale")


@dataclass
class FeedbackOutcome:
    """What became of one feedback: credited to `steps` held steps, stale (all mass lost), or ignored."""

    status: str  # "credited" | "stale" | "ignored"
    steps: int = 0
    lost_mass: float = 0.0


@dataclass(frozen=True)
class Screen:
    """What a person's screen showed before their feedback, oldest first: each step's time on the step clock (NaN:
    not known to the learner) and the interval [starts, ends) it was shown, in seconds on the feedback's clock."""

    step_times: np.ndarray
    starts: np.ndarray
    ends: np.ndarray


def within_reach(starts: np.ndarray, ends: np.ndarray, t_feedback: float, reach_s: float) -> slice:
    """The candidate steps (ascending starts and ends) that a feedback at t_feedback can be about with a delay of
    at most reach_s: shown before t_feedback and not ended before t_feedback - reach_s. The others get no weight
    under the delay, so leaving them out changes no credit. All of them when the times are not ascending."""
    if np.count_nonzero(starts[1:] < starts[:-1]) or np.count_nonzero(ends[1:] < ends[:-1]):
        return slice(0, len(starts))
    first = int(np.searchsorted(ends, t_feedback - reach_s, side="right"))
    return slice(first, max(first, int(np.searchsorted(starts, t_feedback, side="right"))))


DEFAULT_TEACHER = "teacher"
"""The teacher of a trial when the driver names none (the in-process runner: one simulated teacher per trial)."""

NewDelay = Callable[[str, bool], Any]
"""A driver's rule for a teacher heard for the first time: (teacher id, on a screen) -> its delay in seconds
(`common.core.delay_model`), or None for the step clock's assumed lags."""


class TeacherDelays:
    """The agent's one registry of its teachers' delays.

    Per trial: the assumed point-mass lags on the step clock (zero-padded to the longest; `step_delay(rows)` for
    the batched credit), and per teacher a delay in seconds (`models[r][teacher]`): a `LearnedDelay` (prior
    `delay_prior`) made up front for the default teacher of a trial whose config says `learn_delay`, or whatever
    the driver's `new_delay` rule makes when a teacher is first heard (the live learner's: per teacher, from its
    config and a returning person's profile). A teacher without one is credited on the step clock."""

    def __init__(self, configs, step_unit: float = 1.0):
        B, L = len(configs), max(len(c.assumed_delay_probs) for c in configs)
        self.width, self.unit = L, step_unit
        self.assumed = np.zeros((B, L), np.float64)
        for k, c in enumerate(configs):
            self.assumed[k, : len(c.assumed_delay_probs)] = c.assumed_delay_probs
        self.learn = np.array([bool(getattr(c, "learn_delay", False)) for c in configs])
        self.models: list[dict[str, Any]] = [
            {DEFAULT_TEACHER: LearnedDelay(LearnedDelayConfig(prior=c.delay_prior))} if learn else {}
            for c, learn in zip(configs, self.learn)
        ]
        first = configs[0].assumed_delay_probs
        uniform = all(c.assumed_delay_probs == first for c in configs) and not self.learn.any()
        # The paper's one model when every trial assumes the same lags and none learns (the batched fast path).
        self.shared = DelayModel(first, step_unit) if uniform else None
        self.new_delay: NewDelay | None = None

    def step_delay(self, rows: np.ndarray) -> DelayModel | RowDelays:
        """The assumed lags of trials `rows`, for the batched credit function."""
        return self.shared if self.shared is not None else RowDelays(self.assumed[rows], self.unit)

    def of(self, row: int, teacher: str, on_screen: bool = False) -> Any:
        """Trial `row`'s delay in seconds for `teacher` (made on first use by `new_delay`), None: the step clock."""
        model = self.models[row].get(teacher)
        if model is None and self.new_delay is not None:
            model = self.new_delay(teacher, on_screen)
            if model is not None:
                self.models[row][teacher] = model
        return model

    def timed(self, rows: np.ndarray, teachers, screens) -> np.ndarray:
        """Per trial asked about: True where its feedback is credited in seconds (a screen, or a teacher with a
        delay in seconds), False on the step clock."""
        if teachers is None and screens is None and self.new_delay is None:
            return self.learn[rows]  # (the runner: its one teacher per trial; no lookups per tick)
        names = [DEFAULT_TEACHER] * len(rows) if teachers is None else teachers
        on_screen = [False] * len(rows) if screens is None else [s is not None for s in screens]
        return np.array([s or self.of(int(r), t, s) is not None for r, t, s in zip(rows, names, on_screen)], bool)

    def mean_lag(self, rows: np.ndarray) -> np.ndarray:
        """Mean assumed lag in steps (nan for learning trials: theirs is in seconds, `median_s`)."""
        if self.shared is not None:
            return np.full(len(rows), float(np.dot(self.shared.probs, np.arange(len(self.shared.probs)))))
        out = self.assumed[rows] @ np.arange(self.width, dtype=np.float64)
        return np.where(self.learn[rows], np.nan, out)

    def learned(self, row: int) -> LearnedDelay | None:
        """The delay trial `row` learns for its default teacher (None where its config does not learn one)."""
        model = self.models[row].get(DEFAULT_TEACHER)
        return model if isinstance(model, LearnedDelay) else None

    def median_s(self, rows: np.ndarray) -> np.ndarray:
        """The learned median delay in seconds (nan for trials that do not learn it)."""
        return np.array([np.nan if (d := self.learned(int(r))) is None else d.quantile(0.5) for r in rows])

    def mean_s(self, rows: np.ndarray) -> np.ndarray:
        """The learned mean delay in seconds (nan for trials that do not learn it)."""
        return np.array([np.nan if (d := self.learned(int(r))) is None else d.mean() for r in rows])

    def select(self, rows: np.ndarray) -> None:
        self.assumed, self.learn = self.assumed[rows], self.learn[rows]
        self.models = [self.models[r] for r in rows]

    def state_dict(self) -> dict:
        """The teachers' delays as one JSON text (a checkpoint holds arrays, dicts and scalars, not lists), less each
        learned delay's window of rows: those go as arrays, under "<trial>_<k-th teacher by name>"."""
        states = [{t: d.state(arrays=True) for t, d in sorted(m.items())} for m in self.models]
        rows = {
            f"{i}_{k}": st.pop("rows") for i, m in enumerate(states) for k, st in enumerate(m.values()) if "rows" in st
        }
        return {"teachers": json.dumps(states), "rows": rows}

    def load_state_dict(self, state: dict) -> None:
        if "learned" in state:  # (written before the registry: one learned delay per trial, or none)
            teachers = [{} if s is None else {DEFAULT_TEACHER: s} for s in state["learned"]]
        else:
            teachers = json.loads(state["teachers"])
            for key, rows in state.get("rows", {}).items():  # (a checkpoint written before 29 November has none)
                trial, k = (int(n) for n in key.split("_"))
                list(teachers[trial].values())[k]["rows"] = rows
        self.models = [{str(t): estimate_from_state(s) for t, s in m.items()} for m in teachers]


class FeedbackDoor:
    """The feedback methods of `TrialBatchAgent` (they use its parts: history, replay, h, feedback_memory)."""

    # What the agent gives them (`TrialBatchAgent.__init__`).
    history: BatchStepHistory
    replay: TransitionReplay
    feedback_memory: FeedbackMemory
    h: ValueNetworks
    delays: TeacherDelays
    shaping: np.ndarray
    train_h: np.ndarray
    h_updates: np.ndarray
    local_width: int
    last_credit: tuple[np.ndarray, BatchCredit] | None
    last_timed: dict[int, tuple[np.ndarray, np.ndarray]]

    def mean_lag(self, rows: np.ndarray) -> np.ndarray:
        """Mean of the lag distribution (in steps) credit uses now for trials `rows` (nan where it is learned in
        seconds: `median_delay_s`)."""
        return self.delays.mean_lag(rows)

    def median_delay_s(self, rows: np.ndarray, mean: bool = False) -> np.ndarray:
        """The learned median (or `mean`) delay (s) of each trial's teacher (nan where it is not learned)."""
        return self.delays.mean_s(rows) if mean else self.delays.median_s(rows)

    def delay_summary(self, i: int) -> dict | None:
        """Trial i's learned delay (`LearnedDelay.summary`), None where it is not learned."""
        learned = self.delays.learned(i)
        return None if learned is None else learned.summary()

    def give_feedback(self, events: list[tuple[int, float, int]]) -> list[FeedbackOutcome]:
        """One round of feedback, at most one event per trial: (trial, t_feedback, value +-1)."""
        seen = set()
        for i, _, value in events:
            if i in seen:
                raise ValueError(f"trial {i} has two feedbacks in one round")
            seen.add(i)
            if value not in (-1, 1):
                raise ValueError(f"feedback must be -1 or +1, got {value!r}")
        if not events:
            return []
        status, steps, lost = self.feedback_rounds(
            np.array([e[0] for e in events], np.int64),
            np.array([e[1] for e in events], np.float64),
            np.array([[e[2]] for e in events], np.int64),
            np.ones(len(events), np.int64),
        )
        return [FeedbackOutcome(STATUS_NAMES[s], int(n), float(m)) for s, n, m in zip(status, steps, lost)]

    def feedback_rounds(
        self,
        rows: np.ndarray,
        t_feedback: np.ndarray,
        values: np.ndarray,
        counts: np.ndarray,
        seconds: np.ndarray | None = None,
        teachers: list[str] | None = None,
        screens: list[Screen | None] | None = None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The one door. Rounds of feedback stamped at the same times: round r gives values[k, r] (+-1, not
        checked) to trial rows[k] if counts[k] > r, from `teachers[k]` (default: the trial's one teacher), stamped
        t_feedback[k] on the step clock and `seconds[k]` on the teacher's clock (default t_feedback), seen on
        `screens[k]` (None: no screen). A teacher with a delay in seconds (or a screen) is credited by its posterior
        in seconds, one round at a time; the others on the step clock: shaping trials add the value to the newest
        step's reward; H trials credit it by timestamp (computed once: nothing is recorded between rounds), grow
        D_global and update H on D_local, one update per round, in order. Returns (status, steps, lost) per trial."""
        n = len(rows)
        self.last_credit, self.last_timed = None, {}
        status = np.full(n, IGNORED, np.int64)
        steps = np.zeros(n, np.int64)
        lost = np.zeros(n, np.float64)
        timed = self.delays.timed(rows, teachers, screens)
        shaping = self.shaping[rows] & ~timed
        if np.count_nonzero(shaping):
            self._shape(rows, t_feedback, values, counts, shaping.nonzero()[0], status, steps, lost)
        if np.count_nonzero(timed):
            stamps = t_feedback if seconds is None else seconds
            for k in timed.nonzero()[0]:
                teacher = DEFAULT_TEACHER if teachers is None else teachers[k]
                screen = None if screens is None else screens[k]
                status[k], steps[k], lost[k] = self._credit_timed(
                    int(k), int(rows[k]), float(stamps[k]), values[k, : counts[k]], teacher, screen
                )
        learn = self.train_h[rows] & ~self.shaping[rows] & ~timed
        if np.count_nonzero(learn):
            self._credit_h(rows, t_feedback, values, counts, learn.nonzero()[0], status, steps, lost)
        return status, steps, lost

    def credited(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """The held steps (ring positions) the latest round's k-th trial credited, oldest first, and their weights."""
        if k in self.last_timed:
            return self.last_timed[k]
        if self.last_credit is not None and k in self.last_credit[0]:
            j = int(np.flatnonzero(self.last_credit[0] == k)[0])
            c = self.last_credit[1]
            n = int(c.counts[j])
            return c.positions[j, :n], c.weights[j, :n]
        return np.zeros(0, np.int64), np.zeros(0)

    def _credit_timed(
        self, k: int, row: int, t: float, values: np.ndarray, teacher: str, screen: Screen | None
    ) -> tuple[int, int, float]:
        """Each round of trial `row`'s feedback (the k-th asked about) credited in seconds with its teacher's delay,
        over the intervals its screen showed the steps or, without one, the held steps' own times. Returns the last
        round's (status code, steps, lost mass)."""
        delay = self.delays.of(row, teacher, screen is not None)
        if delay is None:
            raise ValueError(f"teacher {teacher!r} gave feedback on a screen but has no delay in seconds")
        if screen is None:
            positions, times = self.history.held(np.array([row]))
            positions = positions[0][np.isfinite(times[0])]
            starts = self.history.seconds[row, positions]
            ends = np.append(starts[1:], np.inf)
        else:
            positions, starts, ends = self.history.find(row, screen.step_times), screen.starts, screen.ends
        result = FeedbackOutcome("ignored")
        for value in values:
            result, weights = self._credit_in_seconds(row, t, int(value), positions, starts, ends, delay)
            credited = (weights > 0) & (positions >= 0)
            self.last_timed[k] = (positions[credited], weights[credited])
        return STATUS_NAMES.index(result.status), result.steps, result.lost_mass

    def _credit_in_seconds(
        self, row: int, t_feedback: float, value: int, positions, starts, ends, delay
    ) -> tuple[FeedbackOutcome, np.ndarray]:
        """A feedback on steps shown during [starts, ends) (oldest first; seconds on the clock of t_feedback):
        `positions` are the history's ring positions of those steps (`history.find`; -1: no longer held).
        `delay` (`common.core.delay_model`: learned or fixed) gives each its credit and learns from the
        feedback on the task rule's polarity of the candidates. Shaping trials add the value to the reward of
        the newest held step shown at or before t_feedback. Returns the outcome and each listed step's weight."""
        if value not in (-1, 1):
            raise ValueError(f"feedback must be -1 or +1, got {value!r}")
        positions, starts = np.asarray(positions, np.int64), np.asarray(starts, np.float64)
        ends = np.asarray(ends, np.float64)
        weights = np.zeros(len(positions))
        held = (positions >= 0) & (starts <= t_feedback)  # nothing shown after the press is a candidate
        r = np.array([row], np.int64)
        if self.shaping[row]:  # the newest held step shown before it, by the step clock's one shaping rule
            newest = np.flatnonzero(held)[-1:]
            t_step = self.history.times[row, positions[newest]] if len(newest) else np.array([-np.inf])
            shaped, steps, lost_now = np.zeros(1, np.int64), np.zeros(1, np.int64), np.zeros(1)
            self._shape(
                r, t_step, np.array([[value]]), np.ones(1, np.int64), np.zeros(1, np.int64), shaped, steps, lost_now
            )
            weights[newest] = steps[0]
            return FeedbackOutcome(STATUS_NAMES[shaped[0]], int(steps[0]), float(lost_now[0])), weights
        if not self.train_h[row]:
            return FeedbackOutcome("ignored"), weights
        if not held.any():
            return FeedbackOutcome("stale", 0, 1.0), weights
        # Only the steps the delay can reach: at a high rate the history holds thousands, all weightless.
        near = within_reach(starts, ends, t_feedback, delay.reach_s())
        held_near, positions_near = held[near], positions[near]
        weights[near] = np.where(held_near, delay.weights(t_feedback, starts[near], ends[near]), 0.0)
        polarity = np.where(held_near, self.history.polarity[row, np.maximum(positions_near, 0)], 0)
        delay.observe(t_feedback, starts[near], ends[near], polarity_likelihood(value, polarity))
        k = np.flatnonzero(weights > 0)
        lost = max(0.0, 1.0 - float(weights.sum()))
        if not len(k):
            return FeedbackOutcome("stale", 0, lost), weights
        p = positions[k][None, :]
        obs, act = self.history.obs[r[:, None], p], self.history.action[r[:, None], p]
        self._learn_local(
            r,
            np.array([len(k)]),
            obs,
            act,
            np.full((1, len(k)), value, np.float32),
            weights[k][None, :].astype(np.float32),
        )
        return FeedbackOutcome("credited", int(len(k)), lost), weights

    def _shape(self, rows, t_feedback, values, counts, k, status, steps, lost) -> None:
        """Naive reward shaping: each round's value added to the reward of the newest step at t_feedback."""
        r = rows[k]
        pos = self.history.latest_at(r, t_feedback[k])
        hit = pos >= 0
        status[k] = np.where(hit, CREDITED, STALE)
        steps[k] = hit.astype(np.int64)
        lost[k] = np.where(hit, 0.0, 1.0)
        for rnd in range(values.shape[1]):
            g = hit & (counts[k] > rnd)
            self.replay.add_reward(r[g], self.history.slot[r[g], pos[g]], values[k[g], rnd].astype(np.float32))

    def _credit_h(self, rows, t_feedback, values, counts, k, status, steps, lost) -> None:
        """Credit by timestamp: D_local, added to D_global, and an H step on D_local (summed) per round."""
        r = rows[k]
        credit = self.history.credit(r, t_feedback[k], self.delays.step_delay(r), self.local_width)
        self.last_credit = (k, credit)
        ok = credit.counts > 0
        status[k] = np.where(ok, CREDITED, STALE)
        steps[k] = credit.counts
        lost[k] = credit.lost
        if not np.count_nonzero(ok):
            return
        k, r, pos, cnt = k[ok], r[ok], credit.positions[ok], credit.counts[ok]
        w32 = credit.weights[ok].astype(np.float32)
        obs = self.history.obs[r[:, None], pos]
        act = self.history.action[r[:, None], pos]
        for rnd in range(values.shape[1]):
            g = (counts[k] > rnd).nonzero()[0]
            if not len(g):
                break
            fb = np.repeat(values[k[g], rnd].astype(np.float32)[:, None], pos.shape[1], axis=1)
            self._learn_local(r[g], cnt[g], obs[g], act[g], fb, w32[g])

    def _learn_local(self, rows, counts, obs, act, fb, w32) -> None:
        """D_local of one feedback per trial: into D_global, and one H step on it (its loss summed)."""
        self.feedback_memory.add_many(rows, counts, obs=obs, action=act, feedback=fb, weight=w32)
        self.h.fit(FitJob(self.h, rows, obs, act, fb, w32, SQUARED_SUM))
        self.h_updates[rows] += 1
