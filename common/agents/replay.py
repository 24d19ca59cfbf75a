"""Per-trial replay memories stored as stacked arrays, so a batch of trials adds and samples in one call.

All fields of an entry are stored side by side in one float32 record (`rec`, [B, capacity, width];
integer fields such as the action are small and exact in float32), so a minibatch is one gather;
`data[name]` are views of the columns. An observation is followed by a constant column of ones (the bias
input of the numpy MLP's augmented first layer), so a gathered minibatch holds that input as a view: the
per-update copy that appends it is saved. The agent samples them with counter-based draws (`streams`): the j-th
index of a trial's u-th minibatch is a pure function of (trial key, u, j) and the trial's current size, so
its draws are the same alone or batched. `TransitionReplay` is DQN's experience replay; `FeedbackMemory` is Deep TAMER's
D_global.
"""

from __future__ import annotations

import numpy as np


class _Ring:
    def __init__(
        self, trials: int, capacity: int, fields: dict[str, int], ones_after: tuple[str, ...] = (), coded: bool = False
    ):
        """fields: name -> width (0 for a scalar field). Each field of `ones_after` is followed by a column of
        ones, written with every record: `with_ones[name]` is the field with it, `at[name]` a field's first
        column. coded: the fields of `ones_after` are observations' codes (`sparse.HotCodes`), which hold the bias
        input already: no column is added, `with_ones[name]` is the field itself."""
        self.capacity = capacity
        self.fields = dict(fields)
        self.columns, self.with_ones, o = {}, {}, 0
        for name, width in fields.items():
            self.columns[name] = slice(o, o + max(width, 1))
            o += max(width, 1)
            if name in ones_after and coded:
                self.with_ones[name] = self.columns[name]
            elif name in ones_after:
                self.with_ones[name] = slice(self.columns[name].start, o + 1)
                o += 1
        self.width = o
        self.at = {name: s.start for name, s in self.columns.items()}
        self._added = () if coded else tuple(self.with_ones)  # the fields followed by a column of ones
        self._ones = [self.with_ones[name].stop - 1 for name in self._added]
        self.rec = np.zeros((trials, capacity, o), np.float32)
        self.size = np.zeros(trials, dtype=np.int64)
        self.pos = np.zeros(trials, dtype=np.int64)
        self._make_views()

    def _make_views(self) -> None:
        self.data = {
            name: (self.rec[:, :, self.columns[name]] if w else self.rec[:, :, self.columns[name].start])
            for name, w in self.fields.items()
        }

    def _record(self, n: int, values: dict) -> np.ndarray:
        if values.keys() == self.fields.keys():  # every field: one concatenation in column order
            parts, ones = [], np.ones((n, 1), np.float32)
            for name in self.fields:
                parts.append(np.asarray(values[name], np.float32).reshape(n, -1))
                if name in self._added:
                    parts.append(ones)
            return np.concatenate(parts, axis=1)
        row = np.zeros((n, self.width), np.float32)
        row[:, self._ones] = 1.0
        for name, value in values.items():
            row[:, self.columns[name]] = np.asarray(value, np.float32).reshape(n, -1)
        return row

    def add_rows(self, trials: np.ndarray, **values) -> np.ndarray:
        """Append one entry for each of `trials` (distinct); values are arrays with a leading trial axis."""
        slots = self.pos[trials].copy()
        self.rec[trials, slots] = self._record(len(trials), values)
        self.pos[trials] = (slots + 1) % self.capacity
        self.size[trials] = np.minimum(self.size[trials] + 1, self.capacity)
        return slots

    def add_many(self, trials: np.ndarray, counts: np.ndarray, **values) -> None:
        """Append counts[k] entries for trials[k] (distinct); values[name] is [len(trials), max count, ...]
        and entry j of trial k is values[name][k, j] for j < counts[k]."""
        width = np.asarray(values[next(iter(values))]).shape[1]
        k_idx, j_idx = np.nonzero(np.arange(width)[None, :] < counts[:, None])
        rows = trials[k_idx]
        slots = (self.pos[rows] + j_idx) % self.capacity
        self.rec[rows, slots] = self._record(len(k_idx), {k: np.asarray(v)[k_idx, j_idx] for k, v in values.items()})
        self.pos[trials] = (self.pos[trials] + counts) % self.capacity
        self.size[trials] = np.minimum(self.size[trials] + counts, self.capacity)

    def gather_records(self, trials: np.ndarray, idx: np.ndarray) -> np.ndarray:
        """The records at slots idx [n, m] of trials [n]: [n, m, width] float32."""
        return self.rec[trials[:, None], idx]

    def select(self, trials: np.ndarray) -> None:
        """Keep only `trials` (in that order)."""
        self.rec = self.rec[trials]
        self.size, self.pos = self.size[trials], self.pos[trials]
        self._make_views()

    def state_dict(self) -> dict:
        return {"rec": self.rec.copy(), "size": self.size.copy(), "pos": self.pos.copy()}

    def load_state_dict(self, state: dict) -> None:
        self.rec[...] = state["rec"]
        self.size[...] = state["size"]
        self.pos[...] = state["pos"]


class TransitionReplay(_Ring):
    def __init__(self, trials: int, capacity: int, obs_dim: int, coded: bool = False):
        """obs_dim: an observation's width (its codes' where `coded`)."""
        super().__init__(
            trials,
            capacity,
            {"obs": obs_dim, "action": 0, "reward": 0, "next_obs": obs_dim, "terminated": 0},
            ones_after=("obs", "next_obs"),
            coded=coded,
        )

    def add_reward(self, trial, slot, amount) -> None:
        """Naive reward shaping: feedback added to already stored transitions (arrays allowed)."""
        self.data["reward"][trial, slot] += amount


class FeedbackMemory(_Ring):
    """D_global: every credited (state, action, feedback, weight) so far (FIFO beyond capacity)."""

    def __init__(self, trials: int, capacity: int, obs_dim: int, coded: bool = False):
        super().__init__(
            trials,
            capacity,
            {"obs": obs_dim, "action": 0, "feedback": 0, "weight": 0},
            ones_after=("obs",),
            coded=coded,
        )
