"""Per-trial replay memories stored as stacked arrays, so a batch of trials samples in one gather.

Each trial samples with its own generator and only when asked, so its draws are the same alone or
batched. `TransitionReplay` is DQN's experience replay; `FeedbackMemory` is Deep TAMER's D_global.
"""
from __future__ import annotations

import numpy as np


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

    def sample_indices(self, rngs: list[np.random.Generator], mask: np.ndarray, n: int) -> np.ndarray:
        """[B, n] slots; trials outside `mask` get slot 0 and do not touch their generator."""
        idx = np.zeros((len(rngs), n), dtype=np.int64)
        for i in np.flatnonzero(mask):
            idx[i] = rngs[i].integers(0, self.size[i], size=n)
        return idx

    def gather(self, name: str, idx: np.ndarray) -> np.ndarray:
        rows = np.arange(idx.shape[0])[:, None]
        return self.data[name][rows, idx]

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

    def add_reward(self, trial: int, slot: int, amount: float) -> None:
        """Naive reward shaping: feedback added to an already stored transition."""
        self.data["reward"][trial, slot] += amount


class FeedbackMemory(_Ring):
    """D_global: every credited (state, action, feedback, weight) so far (FIFO beyond capacity)."""

    def __init__(self, trials: int, capacity: int, obs_dim: int):
        super().__init__(trials, capacity, {
            "obs": ((obs_dim,), np.float32), "action": ((), np.int64), "feedback": ((), np.float32),
            "weight": ((), np.float32)})
