"""How the agent chooses: the mixture argmax(alpha_q Q + alpha_h H), epsilon-greedy exploration, the agent's acting
methods (`Acting`, which `TrialBatchAgent` inherits), and the counter-based random numbers behind its draws
(exploration's here, and the replay minibatches' in `agent`).

Mixture and exploration are functions of each trial's step count (not running products), so the actor and the
learner, and a restarted process, agree on their value at any step without sharing state. Step t of trial i
explores when u(i, 2t) < epsilon(t), with action floor(u(i, 2t + 1) * n_actions), whatever else runs in the batch.

Counter-based random numbers: a uniform draw u(key, counter) is a pure function of (key, counter). The agent's
random choices are indexed by what they are for: trial key, step or update number, draw number. A draw therefore
does not depend on any other trial, on the order in which trials are visited, nor on hidden generator state, so a
batch of trials can draw for all of them in one vectorised call, a batch can be shrunk or reordered between steps,
and a restarted learner continues the same sequence from its counters alone (nothing to save but the counters).
The mixing function is SplitMix64's finaliser (Steele, Lea and Flood 2014) applied to key + counter *
golden-gamma; the 53 high bits give a double in [0, 1).
"""

from __future__ import annotations

import numpy as np

from common.agents.mlp import HotCodes, with_ones
from common.agents.networks import ValueNetworks

_GAMMA = np.uint64(0x9E3779B97F4A7C15)
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_S30, _S27, _S31, _S11 = np.uint64(30), np.uint64(27), np.uint64(31), np.uint64(11)
_TO_UNIT = 1.0 / float(1 << 53)


def mix64(z: np.ndarray) -> np.ndarray:
    """SplitMix64 finaliser on uint64 arrays (wrapping arithmetic)."""
    z = (z ^ (z >> _S30)) * _M1
    z = (z ^ (z >> _S27)) * _M2
    return z ^ (z >> _S31)


def uniforms(keys: np.ndarray, counters: np.ndarray) -> np.ndarray:
    """Doubles in [0, 1): u[k] = f(keys[k], counters[k]) (the arrays broadcast together)."""
    with np.errstate(over="ignore"):
        k = np.asarray(keys, dtype=np.uint64)
        c = np.asarray(counters, dtype=np.int64).astype(np.uint64)
        z = mix64(k + c * _GAMMA)
    return (z >> _S11).astype(np.float64) * _TO_UNIT


def to_integers(u: np.ndarray, high: np.ndarray) -> np.ndarray:
    """floor(u * high) for uniforms u in [0, 1), kept below high."""
    out = np.floor(u * np.asarray(high, dtype=np.float64)).astype(np.int64)
    return np.minimum(out, np.asarray(high, dtype=np.int64) - 1)


class UniformBlocks:
    """u(key_i, c * width + j) for j < width, served from blocks of `block` consecutive counters c per
    row, computed in one vectorised call when a row's counter leaves its block. The values are exactly
    `uniforms`' (so results do not change); only the number of calls does. Rows can be dropped with
    `select`, like the rest of a batch's state; nothing needs saving (the blocks are recomputed)."""

    def __init__(self, keys: np.ndarray, width: int, block: int | None = None):
        self.keys = np.asarray(keys, dtype=np.uint64)
        self.width = width
        self.block = block if block is not None else max(8, 2048 // width)
        self.base = np.full(len(self.keys), -1 << 62, dtype=np.int64)
        self.values = np.zeros((len(self.keys), self.block, width), np.float64)

    def get(self, rows: np.ndarray, counters: np.ndarray) -> np.ndarray:
        """[len(rows), width] for counter counters[k] of row rows[k] (rows distinct)."""
        off = counters - self.base[rows]
        stale = (off < 0) | (off >= self.block)
        if np.count_nonzero(stale):  # (a C call: a quarter of .any()'s cost, per step)
            r = rows[stale]
            c0 = counters[stale]
            c = (c0[:, None, None] + np.arange(self.block)[None, :, None]) * self.width + np.arange(self.width)
            self.values[r] = uniforms(self.keys[r, None, None], c)
            self.base[r] = c0
            off = counters - self.base[rows]
        return self.values[rows, off]

    def select(self, rows: np.ndarray) -> None:
        self.keys, self.base, self.values = self.keys[rows], self.base[rows], self.values[rows]


class RowConstants:
    """`make(rows)`: per-trial constants picked for a set of trial rows, kept per row set. A batch asks for the
    same rows at almost every step, and picking a few small arrays by index costs more than the step's own
    arithmetic on them. The arrays returned are shared: read them, never write into them. `clear()` when the
    rows are renumbered (`select`)."""

    def __init__(self, make):
        self._make = make
        self._kept: dict[tuple, tuple] = {}

    def __call__(self, rows: np.ndarray) -> tuple:
        if not isinstance(rows, np.ndarray):
            rows = np.asarray(rows, np.int64)
        key = (rows.dtype.char, rows.tobytes())
        got = self._kept.get(key)
        if got is None:
            if len(self._kept) >= 64:
                self._kept.clear()
            got = self._kept[key] = self._make(rows)
        return got

    def clear(self) -> None:
        self._kept.clear()


class Mixture:
    """alpha_q, and alpha_h(t) = alpha_h * alpha_h_decay^t per trial (paper: 1, 1, 0.9999).

    Beyond the paper (`alpha_h_adapt` > 0): alpha_h(t) is also multiplied by a running rate of argmax H
    agreeing with argmax Q (an exponential average with step `alpha_h_adapt`, starting at 1, fed by
    `observe`), so a teacher whom the environment keeps contradicting loses the say.

    Beyond the paper (`alpha_h_trust` > 0): the teacher's reliability, a running rate (this step size, from 1)
    of argmax H agreeing with argmax Q counted only from step `alpha_h_trust_after` on (once Q has learned
    from the return; before, Q is noise and every teacher would look unreliable). alpha_h(t) is multiplied
    by min(1, reliability / alpha_h_trust_ref): a teacher whose advice the return keeps contradicting loses
    the say, one it confirms keeps the paper's schedule. One trial has one teacher, so the rate is per
    teacher (one row each)."""

    _ROWS = (
        "alpha_q",
        "alpha_h0",
        "alpha_h_decay",
        "adapt",
        "agree",
        "trust",
        "trust_after",
        "trust_ref",
        "reliability",
    )

    def __init__(self, configs):
        self.alpha_q = np.array([c.alpha_q for c in configs], np.float64)
        self.alpha_h0 = np.array([c.alpha_h for c in configs], np.float64)
        self.alpha_h_decay = np.array([c.alpha_h_decay for c in configs], np.float64)
        self.adapt = np.array([getattr(c, "alpha_h_adapt", 0.0) for c in configs], np.float64)
        self.agree = np.ones(len(configs), np.float64)
        self.trust = np.array([getattr(c, "alpha_h_trust", 0.0) for c in configs], np.float64)
        self.trust_after = np.array([getattr(c, "alpha_h_trust_after", 0) for c in configs], np.float64)
        self.trust_ref = np.array([getattr(c, "alpha_h_trust_ref", 1.0) for c in configs], np.float64)
        self.reliability = np.ones(len(configs), np.float64)
        self._flags()
        self._constants = RowConstants(
            lambda rows: (
                self.alpha_h0[rows],
                self.alpha_h_decay[rows],
                self.alpha_q[rows].astype(np.float32).reshape(-1, 1, 1),
            )
        )

    def alpha_h(self, rows: np.ndarray, steps: np.ndarray, constants: tuple | None = None) -> np.ndarray:
        alpha_h0, decay, _ = self._constants(rows) if constants is None else constants
        sched = alpha_h0 * decay ** steps.astype(np.float64)
        if not self.adapting:
            return sched
        if self.any_adapt:
            sched = np.where(self.adapt[rows] > 0, sched * self.agree[rows], sched)
        if self.any_trust:
            sched = sched * np.minimum(1.0, self.reliability[rows] / self.trust_ref[rows])
        return sched

    def _flags(self) -> None:
        self.any_adapt = bool((self.adapt > 0).any())
        self.any_trust = bool((self.trust > 0).any())
        self.adapting = self.any_adapt or self.any_trust  # none adapts (the paper): skip the per-step work

    def observe(self, rows: np.ndarray, agree: np.ndarray, steps: np.ndarray | None = None) -> None:
        """Trials `rows` chose with argmax H == argmax Q (`agree`, bool) at their step `steps`."""
        if not self.adapting:
            return
        a = self.adapt[rows] > 0
        if a.any():
            r = rows[a]
            self.agree[r] += self.adapt[r] * (agree[a].astype(np.float64) - self.agree[r])
        if self.any_trust and steps is not None:
            t = (self.trust[rows] > 0) & (steps >= self.trust_after[rows])
            if t.any():
                r = rows[t]
                self.reliability[r] += self.trust[r] * (agree[t].astype(np.float64) - self.reliability[r])

    def state_dict(self) -> dict:
        return {"agree": self.agree.copy(), "reliability": self.reliability.copy()}

    def load_state_dict(self, state: dict) -> None:
        self.agree[...] = state["agree"]
        if "reliability" in state:  # (a state saved before the teacher's reliability existed)
            self.reliability[...] = state["reliability"]

    def weights(self, rows: np.ndarray, steps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(alpha_q, alpha_h) as float32 [n, 1, 1], to weigh values [n, N, A]."""
        constants = self._constants(rows)
        ah = self.alpha_h(rows, steps, constants).astype(np.float32).reshape(-1, 1, 1)
        return constants[2], ah

    def select(self, rows: np.ndarray) -> None:
        for name in self._ROWS:
            setattr(self, name, getattr(self, name)[rows])
        self._flags()
        self._constants.clear()


class EpsilonGreedy:
    """epsilon(t) = max(floor, start - decay * t) per trial (paper: 0.3, 0.001, 0.1)."""

    _ROWS = ("start", "decay", "floor")

    def __init__(self, configs, keys: np.ndarray, n_actions: int):
        self.start = np.array([c.epsilon_start for c in configs], np.float64)
        self.decay = np.array([c.epsilon_decay for c in configs], np.float64)
        self.floor = np.array([c.epsilon_floor for c in configs], np.float64)
        self.n_actions = n_actions
        self._u = UniformBlocks(keys, 2)
        self._constants = RowConstants(lambda rows: (self.floor[rows], self.start[rows], self.decay[rows]))

    def epsilons(self, rows: np.ndarray, steps: np.ndarray) -> np.ndarray:
        floor, start, decay = self._constants(rows)
        return np.maximum(floor, start - decay * steps)

    def choose(self, rows: np.ndarray, steps: np.ndarray, greedy: np.ndarray) -> np.ndarray:
        """The actions of trials `rows` at their step `steps`, given their greedy actions."""
        u = self._u.get(rows, steps)
        explore = u[:, 0] < self.epsilons(rows, steps)
        random_action = np.minimum((u[:, 1] * self.n_actions).astype(np.int64), self.n_actions - 1)
        return np.where(explore, random_action, greedy)

    def select(self, rows: np.ndarray) -> None:
        for name in self._ROWS:
            setattr(self, name, getattr(self, name)[rows])
        self._u.select(rows)
        self._constants.clear()


class Acting:
    """The acting methods of `TrialBatchAgent` (it inherits them, as it does `FeedbackDoor`): epsilon-greedy on
    alpha_q Q + alpha_h H, with the parts the agent holds."""

    # What the agent gives them (`TrialBatchAgent.__init__`).
    q: ValueNetworks
    h: ValueNetworks
    explorer: EpsilonGreedy
    mixture: Mixture
    hot: HotCodes | None
    obs_dim: int
    steps: np.ndarray
    greedy_count: np.ndarray
    h_decided_count: np.ndarray
    _learns_both: RowConstants

    @property
    def B(self) -> int:
        return len(self.steps)

    def _all(self, rows: np.ndarray | None) -> np.ndarray:
        return np.arange(self.B) if rows is None else rows

    def _kept(self, obs: np.ndarray) -> np.ndarray:
        """Observations [..., obs_dim] as the agent keeps them and feeds them to Q and H (codes where `hot`)."""
        return obs if self.hot is None else self.hot.encode(obs)

    def epsilons(self, rows: np.ndarray | None = None) -> np.ndarray:
        rows = self._all(rows)
        return self.explorer.epsilons(rows, self.steps[rows])

    def alpha_h(self, rows: np.ndarray | None = None) -> np.ndarray:
        rows = self._all(rows)
        return self.mixture.alpha_h(rows, self.steps[rows])

    def _scores(self, rows: np.ndarray, obs: np.ndarray) -> np.ndarray:
        """alpha_q Q + alpha_h H for trials `rows`, one observation each (obs: [len(rows), obs_dim])."""
        x = self._kept(np.asarray(obs, np.float32).reshape(len(rows), 1, self.obs_dim))
        aq, ah = self.mixture.weights(rows, self.steps[rows])
        return (aq * self.q.values(rows, x) + ah * self.h.values(rows, x))[:, 0, :]

    def greedy_action(self, i: int, obs: np.ndarray) -> int:
        """Trial i's greedy action for one observation, touching no random stream (for evaluation)."""
        return int(self._scores(np.array([i]), np.asarray(obs, np.float32).reshape(1, -1))[0].argmax())

    def preferences(self, i: int, obs: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, float]:
        """Trial i's Q and H per action for one observation, with alpha_q and alpha_h now (what the console
        shows a person)."""
        x = self._kept(np.asarray(obs, np.float32).reshape(1, 1, self.obs_dim))
        r = np.array([i])
        q, h = self.q.values(r, x)[0, 0], self.h.values(r, x)[0, 0]
        return q.copy(), h.copy(), float(self.mixture.alpha_q[i]), float(self.alpha_h(r)[0])

    def act(self, obs: np.ndarray, active: np.ndarray | None = None) -> np.ndarray:
        """Epsilon-greedy actions for the active trials (-1 for the others). obs: [B, obs_dim]."""
        rows = np.arange(self.B) if active is None else active.nonzero()[0]
        n = len(rows)
        if n == 0:
            return np.full(self.B, -1, dtype=np.int64)
        sel = slice(None) if n == self.B else rows  # every row (the usual case): views, not gathers
        obs = np.asarray(obs, np.float32).reshape(self.B, self.obs_dim)
        x = obs[sel].reshape(n, 1, self.obs_dim)
        steps = self.steps[sel]
        aq, ah = self.mixture.weights(rows, steps)
        both, compare = self._learns_both(rows)
        # A network weighed 0 in every row would add exactly +-0 to every score (the same argmax): its forward
        # pass is skipped (DQN, DQN+RS, Deep TAMER alone) unless Q's and H's choices are compared below.
        x1 = with_ones(x) if self.hot is None else None  # (made once for both networks)
        if self.hot is not None:
            x = self.hot.encode(x)
        q = self.q.values(rows, x, x1) if compare or np.count_nonzero(aq) or not np.count_nonzero(ah) else None
        h = self.h.values(rows, x, x1) if compare or np.count_nonzero(ah) else None
        scores = aq * q if h is None else ah * h if q is None else aq * q + ah * h
        greedy = scores[:, 0, :].argmax(axis=1)
        if compare and q is not None and h is not None:  # (both are computed when their choices are compared)
            q_best = q[:, 0, :].argmax(axis=1)
            self.greedy_count[sel] += both
            self.h_decided_count[sel] += both & (greedy != q_best)
            if self.mixture.adapting:  # (H's own argmax is needed only then)
                self.mixture.observe(rows, q_best == h[:, 0, :].argmax(axis=1), steps)
        chosen = self.explorer.choose(rows, steps, greedy)
        if n == self.B:
            return chosen
        actions = np.full(self.B, -1, dtype=np.int64)
        actions[rows] = chosen
        return actions
