"""The agent's memories of steps, per trial of a batch, as stacked arrays so that a batch of trials adds, samples
and reads in one call: the replay memories Q and H learn from, and the recent steps that credit reads.

Replay (`TransitionReplay`, DQN's experience replay; `FeedbackMemory`, Deep TAMER's D_global): all fields of an
entry are stored side by side in one float32 record (`rec`, [B, capacity, width]; integer fields such as the
action are small and exact in float32), so a minibatch is one gather; `data[name]` are views of the columns. An
observation is followed by a constant column of ones (the bias input of the numpy MLP's augmented first layer),
so a gathered minibatch holds that input as a view: the per-update copy that appends it is saved. The agent
samples them with counter-based draws (`explorer.UniformBlocks`): the j-th index of a trial's u-th minibatch is a
pure function of (trial key, u, j) and the trial's current size, so its draws are the same alone or batched.

The step history (`BatchStepHistory`): ring buffers of time, seconds, episode, obs, action, the teacher rule's
polarity and replay slot of the last `capacity` steps, and credit by timestamp over them. Step k is shown from its
time to the next step's. The weights of a fixed delay come from `common.core.credit.credit_weights`, batched over
trials; a learned delay (`common.core.delay_model`) reads the held steps by time (`held`, `find`) and weighs them
itself. Either way a feedback's candidates are the held steps shown before it, whatever their episode (a reaction
to the goal-reaching move lands after the reset).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from common.core.credit import credit_weights


class _Ring:
    def __init__(
        self, trials: int, capacity: int, fields: dict[str, int], ones_after: tuple[str, ...] = (), coded: bool = False
    ):
        """fields: name -> width (0 for a scalar field). Each field of `ones_after` is followed by a column of
        ones, written with every record: `with_ones[name]` is the field with it, `at[name]` a field's first
        column. coded: the fields of `ones_after` are observations' codes (`mlp.HotCodes`), which hold the bias
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
            k = int(older.nonzero()[0][0])
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
