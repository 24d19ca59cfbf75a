"""The agent's policy parts: the mixture argmax(alpha_q Q + alpha_h H) and epsilon-greedy exploration.

Both are functions of each trial's step count (not running products), so the actor and the learner, and a
restarted process, agree on their value at any step without sharing state. Exploration draws are
counter-based (`streams`): step t of trial i explores when u(i, 2t) < epsilon(t), with action
floor(u(i, 2t + 1) * n_actions), whatever else runs in the batch.
"""

from __future__ import annotations

import numpy as np

from common.agents.streams import UniformBlocks
from common.core.util import RowConstants


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
