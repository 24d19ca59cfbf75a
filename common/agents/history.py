"""The recent steps of every trial in a batch (ring buffers of time, seconds, episode, obs, action, the teacher
rule's polarity and replay slot of the last `capacity` steps), and credit by timestamp over them.

Step k is shown from its time to the next step's. The weights of a fixed delay come from
`common.core.credit.credit_weights`, batched over trials; a learned delay (`common.core.delay_model`) reads
the held steps by time (`held`, `find`) and weighs them itself. Either way a feedback's candidates are the
held steps shown before it, whatever their episode (a reaction to the goal-reaching move lands after the reset).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from common.core.credit import credit_weights
from common.core.util import nz


@dataclass
class BatchCredit:
    """Credit of one feedback per trial (rows = the trials asked about, in order)."""

    counts: np.ndarray  # [n] held steps credited (weight > 0)
    lost: np.ndarray  # [n] assumed-delay mass that fell before the oldest held step
    positions: np.ndarray  # [n, L] ring positions of the credited steps, oldest first (valid: j < counts)
    weights: np.ndarray  # [n, L] their weights (0 beyond counts)


class BatchStepHistory:
    FIELDS = ("times", "seconds", "polarity", "episode", "obs", "action", "slot", "count", "head")

    def __init__(self, trials: int, capacity: int, obs_dim: int):
        self.capacity = capacity
        self.times = np.zeros((trials, capacity), np.float64)
        self.seconds = np.zeros((trials, capacity), np.float64)  # when it was shown, in seconds (teacher's clock)
        self.polarity = np.zeros((trials, capacity), np.int8)  # the task's teacher rule on it (0: unknown)
        self.episode = np.zeros((trials, capacity), np.int64)
        self.obs = np.zeros((trials, capacity, obs_dim), np.float32)
        self.action = np.zeros((trials, capacity), np.int64)
        self.slot = np.zeros((trials, capacity), np.int64)
        self.count = np.zeros(trials, np.int64)
        self.head = np.zeros(trials, np.int64)  # next write position

    def push(
        self,
        trials: np.ndarray,
        t: np.ndarray,
        obs: np.ndarray,
        action: np.ndarray,
        slot: np.ndarray,
        episode: np.ndarray,
        seconds: np.ndarray | None = None,
        polarity: np.ndarray | None = None,
    ) -> None:
        """Trial trials[k] took action[k] at time t[k] in its episode episode[k] (trials distinct); where a delay
        is learned in seconds, the driver also gives `seconds[k]` (when it was shown) and the task rule's
        polarity[k] of it (+-1, 0 unknown)."""
        pos, count = self.head[trials], self.count[trials]
        newest = self.times[trials, (pos - 1) % self.capacity]
        older = (count > 0) & (t < newest)
        if np.count_nonzero(older):
            k = int(nz(older)[0])
            raise ValueError(f"step time {t[k]} is older than the previous step {newest[k]}")
        self.times[trials, pos] = t
        if seconds is not None:  # (kept only by drivers that credit in seconds: a learned delay)
            self.seconds[trials, pos] = seconds
            self.polarity[trials, pos] = 0 if polarity is None else polarity
        self.episode[trials, pos] = episode
        self.obs[trials, pos] = obs
        self.action[trials, pos] = action
        self.slot[trials, pos] = slot
        self.head[trials] = (pos + 1) % self.capacity
        self.count[trials] = np.minimum(count + 1, self.capacity)

    def clear(self, trials) -> None:
        self.count[trials] = 0

    def held(self, trials: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Ring positions of the held steps oldest first [n, capacity], and their times there (+inf where
        nothing is held)."""
        j = np.arange(self.capacity)[None, :]
        count = self.count[trials][:, None]
        pos = (self.head[trials][:, None] - count + j) % self.capacity
        times = np.where(j < count, self.times[trials[:, None], pos], np.inf)
        return pos, times

    def find(self, trial: int, times) -> np.ndarray:
        """Ring position of trial's held step recorded at each of `times` (-1 where none is held)."""
        pos, held = self.held(np.array([trial]))
        times = np.asarray(times, np.float64)
        k = np.searchsorted(held[0], times)
        k = np.minimum(k, self.capacity - 1)
        return np.where(held[0, k] == times, pos[0, k], -1)

    def times_at(self, trial: int, positions) -> np.ndarray:
        """The times at which trial's held steps at ring `positions` were taken (the inverse of `find`)."""
        return self.times[trial, np.asarray(positions, np.int64)]

    def latest_at(self, trials: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Ring position of the newest step taken at or before t[k] for each trial, -1 if none."""
        pos, times = self.held(trials)
        k = (times <= t[:, None]).sum(axis=1) - 1
        return np.where(k >= 0, pos[np.arange(len(trials)), np.maximum(k, 0)], -1)

    def credit(self, trials: np.ndarray, t_feedback: np.ndarray, delay, width: int) -> BatchCredit:
        """Credit one feedback per trial; at most `width` steps can get weight (the assumed delay's point
        masses, or the capacity for a continuous delay)."""
        n = len(trials)
        pos, times = self.held(trials)
        w, lost = credit_weights(t_feedback, times, delay)
        credited = w > 0
        counts = credited.sum(axis=1)
        order = np.argsort(~credited, axis=1, kind="stable")[:, :width]
        valid = np.arange(width)[None, :] < counts[:, None]
        picked = (np.arange(n)[:, None], order)
        weights = np.where(valid, w[picked], 0.0)
        positions = np.where(valid, pos[picked], 0)
        return BatchCredit(counts, lost, positions, weights)

    def select(self, trials: np.ndarray) -> None:
        for name in self.FIELDS:
            setattr(self, name, getattr(self, name)[trials])

    def state_dict(self) -> dict:
        return {name: getattr(self, name).copy() for name in self.FIELDS}

    def forget_shown_before(self, trial: int, seconds: float) -> None:
        """Let trial's held steps shown before `seconds` go, oldest first (a history sized in seconds: the live
        learner's, which does not know the actor's rate)."""
        count, head = int(self.count[trial]), int(self.head[trial])
        while count and self.seconds[trial, (head - count) % self.capacity] < seconds:
            count -= 1
        self.count[trial] = count

    def load_state_dict(self, state: dict) -> None:
        """A state of another capacity (a checkpoint taken with another history size) keeps its newest held steps
        that fit, oldest first from ring position 0."""
        stored = np.asarray(state["times"]).shape[1]
        if stored != self.capacity:
            state = _resized(state, stored, self.capacity)
        for name, value in state.items():
            getattr(self, name)[...] = value


def _resized(state: dict, stored: int, capacity: int) -> dict:
    """`state` of a ring of `stored` steps per trial, as a ring of `capacity`: each trial's newest held steps."""
    count = np.minimum(np.asarray(state["count"], np.int64), capacity)
    head = np.asarray(state["head"], np.int64)
    trials = np.arange(len(count))[:, None]
    j = np.arange(capacity)[None, :]
    source = (head[:, None] - count[:, None] + np.minimum(j, stored - 1)) % stored  # oldest kept first
    out = {"count": count, "head": count % capacity}
    for name in BatchStepHistory.FIELDS[:-2]:
        value = np.asarray(state[name])[trials, source]
        mask = (j < count[:, None]).reshape(len(count), capacity, *(1,) * (value.ndim - 2))
        out[name] = np.where(mask, value, np.zeros_like(value))
    return out
