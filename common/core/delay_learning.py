"""The delay of each trial's teacher when trials differ: a fixed lag distribution per trial (`RowDelays`, for the
batched credit function) or a delay in seconds learned online per trial (`TrialDelays`, on
`common.core.delay_model.LearnedDelay`).

The in-process runner has one simulated teacher per trial; its virtual clock gives each step a duration in
seconds (`step_seconds`), so a trial whose config says `learn_delay` credits its feedback with its own
teacher's learned density in seconds, exactly as the live learner does for each teacher.
"""
from __future__ import annotations

import numpy as np

from common.core.delay_model import LearnedDelay, LearnedDelayConfig


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


class TrialDelays:
    """Per trial: the assumed point-mass lags (zero-padded to the longest; `rows(r)` for credit), and for trials
    whose config says `learn_delay` a `LearnedDelay` in seconds (prior `delay_prior`), `learned[r]`."""

    def __init__(self, configs, step_unit: float = 1.0):
        B, L = len(configs), max(len(c.assumed_delay_probs) for c in configs)
        self.width, self.unit = L, step_unit
        self.assumed = np.zeros((B, L), np.float64)
        for k, c in enumerate(configs):
            self.assumed[k, :len(c.assumed_delay_probs)] = c.assumed_delay_probs
        self.learn = np.array([bool(getattr(c, "learn_delay", False)) for c in configs])
        self.learned: list[LearnedDelay | None] = [
            LearnedDelay(LearnedDelayConfig(prior=c.delay_prior)) if learn else None
            for c, learn in zip(configs, self.learn)]

    def rows(self, rows: np.ndarray) -> RowDelays:
        return RowDelays(self.assumed[rows], self.unit)

    def mean_lag(self, rows: np.ndarray) -> np.ndarray:
        """Mean assumed lag in steps (nan for learning trials: theirs is in seconds, `median_s`)."""
        out = self.assumed[rows] @ np.arange(self.width, dtype=np.float64)
        return np.where(self.learn[rows], np.nan, out)

    def median_s(self, rows: np.ndarray) -> np.ndarray:
        """The learned median delay in seconds (nan for trials that do not learn it)."""
        return np.array([np.nan if self.learned[r] is None else self.learned[r].quantile(0.5) for r in rows])

    def mean_s(self, rows: np.ndarray) -> np.ndarray:
        """The learned mean delay in seconds (nan for trials that do not learn it)."""
        return np.array([np.nan if self.learned[r] is None else self.learned[r].mean() for r in rows])

    def select(self, rows: np.ndarray) -> None:
        self.assumed, self.learn = self.assumed[rows], self.learn[rows]
        self.learned = [self.learned[r] for r in rows]

    def state_dict(self) -> dict:
        return {"learned": [None if d is None else d.state() for d in self.learned]}

    def load_state_dict(self, state: dict) -> None:
        self.learned = [None if s is None else LearnedDelay.from_state(s) for s in state["learned"]]
