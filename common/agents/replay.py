"""Per-trial replay memories stored as stacked arrays, so a batch of trials adds and samples in one call.

Sampling is counter-based (`streams`): the j-th index of a trial's u-th minibatch is a pure function of
(trial key, u, j) and the trial's current size, so its draws are the same alone or batched.
`TransitionReplay` is DQN's experience replay; `FeedbackMemory` is Deep TAMER's D_global.
"""
from __future__ import annotations

import numpy as np

from common.agents import streams


class _Ring:
    def __init__(self, trials: int, capacity: int, fields: dict[str, tuple[tuple[int, ...], type]]):
        self.capacity = capacity
        self.data = {name: np.zeros((trials, capacity, *shape), dtype=dtype)
                     for name, (shape, dtype) in fields.items()}
        self.size = np.zeros(trials, dtype=np.int64)
        self.pos = np.zeros(trials, dtype=np.int64)

    def add(self, trial: int, **values) -> int:
        """Append one entry for `trial`; returns its slot (overwriting the oldest when full)."""
        slot = int(self.pos[trial])
        for name, value in values.items():
            self.data[name][trial, slot] = value
        self.pos[trial] = (slot + 1) % self.capacity
        self.size[trial] = min(self.size[trial] + 1, self.capacity)
        return slot

    def add_rows(self, trials: np.ndarray, **values) -> np.ndarray:
        """Append one entry for each of `trials` (distinct); values are arrays with a leading trial axis."""
        slots = self.pos[trials].copy()
        for name, value in values.items():
            self.data[name][trials, slots] = value
        self.pos[trials] = (slots + 1) % self.capacity
        self.size[trials] = np.minimum(self.size[trials] + 1, self.capacity)
        return slots

    def add_many(self, trials: np.ndarray, counts: np.ndarray, **values) -> None:
        """Append counts[k] entries for trials[k] (distinct); values[name] is [len(trials), max count, ...]
        and entry j of trial k is values[name][k, j] for j < counts[k]."""
        k_idx, j_idx = np.nonzero(np.arange(values[next(iter(values))].shape[1])[None, :] < counts[:, None])
        rows = trials[k_idx]
        slots = (self.pos[rows] + j_idx) % self.capacity
        for name, value in values.items():
            self.data[name][rows, slots] = value[k_idx, j_idx]
        self.pos[trials] = (self.pos[trials] + counts) % self.capacity
        self.size[trials] = np.minimum(self.size[trials] + counts, self.capacity)

    def sample_indices(self, keys: np.ndarray, draws: np.ndarray, trials: np.ndarray, n: int) -> np.ndarray:
        """[len(trials), n] slots: trial k's minibatch number draws[k], drawn with its key keys[k]."""
        counters = draws[:, None] * n + np.arange(n)[None, :]
        return streams.integers(keys[:, None], counters, self.size[trials][:, None])

    def gather(self, name: str, trials: np.ndarray, idx: np.ndarray) -> np.ndarray:
        return self.data[name][trials[:, None], idx]

    def select(self, trials: np.ndarray) -> None:
        """Keep only `trials` (in that order)."""
        self.data = {k: v[trials] for k, v in self.data.items()}
        self.size, self.pos = self.size[trials], self.pos[trials]

    def state_dict(self) -> dict:
        return {"data": {k: v.copy() for k, v in self.data.items()}, "size": self.size.copy(), "pos": self.pos.copy()}

    def load_state_dict(self, state: dict) -> None:
        for k, v in state["data"].items():
            self.data[k][...] = v
        self.size[...] = state["size"]
        self.pos[...] = state["pos"]


class TransitionReplay(_Ring):
    def __init__(self, trials: int, capacity: int, obs_dim: int):
        super().__init__(trials, capacity, {
            "obs": ((obs_dim,), np.float32), "action": ((), np.int64), "reward": ((), np.float32),
            "next_obs": ((obs_dim,), np.float32), "terminated": ((), np.float32)})

    def add_reward(self, trial, slot, amount) -> None:
        """Naive reward shaping: feedback added to already stored transitions (arrays allowed)."""
        self.data["reward"][trial, slot] += amount


class FeedbackMemory(_Ring):
    """D_global: every credited (state, action, feedback, weight) so far (FIFO beyond capacity)."""

    def __init__(self, trials: int, capacity: int, obs_dim: int):
        super().__init__(trials, capacity, {
            "obs": ((obs_dim,), np.float32), "action": ((), np.int64), "feedback": ((), np.float32),
            "weight": ((), np.float32)})
