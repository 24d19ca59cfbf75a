"""The agent's teachers' delays (`TeacherDelays`): per trial the assumed point-mass lags of the step clock
(`RowDelays` when trials differ, for the batched credit function), and per teacher a delay in seconds
(`common.core.delay_model`), learned online or fixed.

The in-process runner has one simulated teacher per trial (`DEFAULT_TEACHER`); its virtual clock gives each step
a duration in seconds (`step_seconds`), so a trial whose config says `learn_delay` credits its feedback with its
own teacher's learned density in seconds. The live learner has one trial and many teachers (an oracle, people at
consoles), each with its own entry in the same registry: one place, whichever driver.
"""

from __future__ import annotations

import json
from typing import Any
from collections.abc import Callable

import numpy as np

from common.core.delay import DelayModel
from common.core.delay_model import LearnedDelay, LearnedDelayConfig, estimate_from_state


class RowDelays:
    """A point-mass lag distribution per trial, for the credit function (`common.core.credit`): rows of `probs`
    [n, L] over lags 0, unit, 2 unit, ...; `mass_between(low, high)` takes [n, ...] arrays whose leading
    axis is the row. Same arithmetic as `DelayModel.mass_between`, one distribution per row."""

    def __init__(self, probs: np.ndarray, unit: float = 1.0):
        self.probs = np.asarray(probs, np.float64)
        self.lags = np.arange(self.probs.shape[1], dtype=np.float64) * unit

    def mass_between(self, low, high):
        low, high = np.asarray(low, np.float64)[..., None], np.asarray(high, np.float64)[..., None]
        inside = (low < self.lags) & (self.lags <= high)
        p = self.probs.reshape(self.probs.shape[:1] + (1,) * (low.ndim - 2) + self.probs.shape[1:])
        return np.where(inside, p, 0.0).sum(axis=-1)

    def point_masses(self) -> tuple[np.ndarray, np.ndarray]:
        return self.lags, self.probs

    def cdf(self, x):
        return self.mass_between(np.full(np.shape(x), -np.inf), x)


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
        """The teachers' delays as one JSON text (a checkpoint holds arrays, dicts and scalars, not lists)."""
        return {"teachers": json.dumps([{t: d.state() for t, d in sorted(m.items())} for m in self.models])}

    def load_state_dict(self, state: dict) -> None:
        if "learned" in state:  # (written before the registry: one learned delay per trial, or none)
            teachers = [{} if s is None else {DEFAULT_TEACHER: s} for s in state["learned"]]
        else:
            teachers = json.loads(state["teachers"])
        self.models = [{str(t): estimate_from_state(s) for t, s in m.items()} for m in teachers]
