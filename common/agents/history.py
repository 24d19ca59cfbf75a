"""The recent steps of every trial in a batch (ring buffers of time, episode, obs, action, replay slot of the
last `capacity` steps), and credit by timestamp over them for one feedback per trial at once.

The weights come from `common.core.credit.credit_weights`, the one credit function: step k is shown from its
action time to the next one, and a feedback is credited only within the episode of the newest step shown
at or before its stamp.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from common.core.credit import credit_weights
from common.core.util import nz

@dataclass
class BatchCredit:
    """Credit of one feedback per trial (rows = the trials asked about, in order)."""

    counts: np.ndarray     # [n] held steps credited (weight > 0)
    lost: np.ndarray       # [n] assumed-delay mass that fell before the oldest held step
    positions: np.ndarray  # [n, L] ring positions of the credited steps, oldest first (valid: j < counts)
    weights: np.ndarray    # [n, L] their weights (0 beyond counts)


class BatchStepHistory:
    def __init__(self, trials: int, capacity: int, obs_dim: int):
        self.capacity = capacity
        self.times = np.zeros((trials, capacity), np.float64)
        self.episode = np.zeros((trials, capacity), np.int64)
        self.obs = np.zeros((trials, capacity, obs_dim), np.float32)
        self.action = np.zeros((trials, capacity), np.int64)
        self.slot = np.zeros((trials, capacity), np.int64)
        self.count = np.zeros(trials, np.int64)
        self.head = np.zeros(trials, np.int64)  # next write position

    def push(self, trials: np.ndarray, t: np.ndarray, obs: np.ndarray, action: np.ndarray,
             slot: np.ndarray, episode: np.ndarray) -> None:
        """Trial trials[k] took action[k] at time t[k] in its episode episode[k] (trials distinct)."""
        pos, count = self.head[trials], self.count[trials]
        newest = self.times[trials, (pos - 1) % self.capacity]
        older = (count > 0) & (t < newest)
        if np.count_nonzero(older):
            k = int(nz(older)[0])
            raise ValueError(f"step time {t[k]} is older than the previous step {newest[k]}")
        self.times[trials, pos] = t
        self.episode[trials, pos] = episode
        self.obs[trials, pos] = obs
        self.action[trials, pos] = action
        self.slot[trials, pos] = slot
        self.head[trials] = (pos + 1) % self.capacity
        self.count[trials] = np.minimum(count + 1, self.capacity)

    def clear(self, trials) -> None:
        self.count[trials] = 0

    def _chronological(self, trials: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Ring positions oldest first [n, capacity] and the held times there (+inf where nothing is held)."""
        j = np.arange(self.capacity)[None, :]
        count = self.count[trials][:, None]
        pos = (self.head[trials][:, None] - count + j) % self.capacity
        times = np.where(j < count, self.times[trials[:, None], pos], np.inf)
        return pos, times

    def latest_at(self, trials: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Ring position of the newest step taken at or before t[k] for each trial, -1 if none."""
        pos, times = self._chronological(trials)
        k = (times <= t[:, None]).sum(axis=1) - 1
        return np.where(k >= 0, pos[np.arange(len(trials)), np.maximum(k, 0)], -1)

    def steps_at_lags(self, trials: np.ndarray, t_feedback: np.ndarray,
                      lags: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """For each trial and lag: the ring position of the newest held step taken at or before
        t_feedback - lag ([n, L]), and whether there is one in the episode of the newest step shown at or
        before t_feedback ([n, L] bool; as credit, never across an episode)."""
        pos, times = self._chronological(trials)
        rows = np.arange(len(trials))[:, None]
        k = (times[:, None, :] <= (t_feedback[:, None] - lags[None, :])[:, :, None]).sum(axis=2) - 1
        at = pos[rows, np.maximum(k, 0)]
        current = self.episode[trials[:, None], at[:, :1]]
        valid = (k >= 0) & (k[:, :1] >= 0) & (self.episode[trials[:, None], at] == current)
        return np.where(valid, at, 0), valid

    def credit(self, trials: np.ndarray, t_feedback: np.ndarray, delay, width: int) -> BatchCredit:
        """Credit one feedback per trial; at most `width` steps can get weight (the assumed delay's point
        masses, or the capacity for a continuous delay)."""
        n = len(trials)
        pos, times = self._chronological(trials)
        episodes = self.episode[trials[:, None], pos]
        w, lost = credit_weights(t_feedback, times, delay, episodes=episodes)
        credited = w > 0
        counts = credited.sum(axis=1)
        order = np.argsort(~credited, axis=1, kind="stable")[:, :width]
        valid = np.arange(width)[None, :] < counts[:, None]
        picked = (np.arange(n)[:, None], order)
        weights = np.where(valid, w[picked], 0.0)
        positions = np.where(valid, pos[picked], 0)
        return BatchCredit(counts, lost, positions, weights)

    def select(self, trials: np.ndarray) -> None:
        for name in ("times", "episode", "obs", "action", "slot", "count", "head"):
            setattr(self, name, getattr(self, name)[trials])

    def state_dict(self) -> dict:
        return {name: getattr(self, name).copy() for name in ("times", "episode", "obs", "action", "slot",
                                                              "count", "head")}

    def load_state_dict(self, state: dict) -> None:
        for name, value in state.items():
            getattr(self, name)[...] = value
