"""The observer's delay distribution learned online, per trial, from how well each lag explains feedback.

The credit component asks "which recent step did this feedback refer to?" and answers with an assumed
lag distribution pi over 0..L-1 steps. Here pi is estimated while learning, per trial, by expectation-
maximisation over a window of the most recent feedbacks (a mixture over lags):

  likelihood  for a feedback f (+1/-1) whose candidate steps are k_0..k_{L-1} (the step at lag l),
              P(f | lag l) = (1 + f H(s_k, a_k)) / 2 with H clipped to [-1, 1] and the result floored at
              `floor` (H is the learner's current model of the teacher, not the truth); lags without a
              held step are impossible. Each feedback's likelihood row is stored when it arrives.
  EM          after each feedback, `iterations` EM steps over the stored rows, from the current pi:
              E: r_il ~ pi_l P(f_i | lag l);  M: pi = (sum_i r_i + prior) / (n + L prior).

The window (`window` feedbacks) lets the estimate follow an observer whose lag drifts during a session;
the Dirichlet `prior` (shaped like the start distribution) keeps every lag possible. While H knows nothing
(H ~ 0) every lag explains a feedback equally and pi stays at its start; it moves once H separates what
the teacher approves from what it does not. Vectorised over trials (rows), like the agent's other state.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class DelayLearningConfig:
    lags: int = 7
    """Candidate lags 0..lags-1 steps."""
    prior: float = 1.0
    """Dirichlet pseudo-count per lag."""
    window: int = 400
    """Most recent feedbacks the estimate is fitted to."""
    iterations: int = 3
    """EM steps after each feedback (warm-started from the current estimate)."""
    floor: float = 0.05
    """Smallest P(f | lag) a prediction may give."""

    def __post_init__(self):
        if self.lags < 1 or self.window < 1 or self.iterations < 1:
            raise ValueError("lags, window and iterations must be >= 1")
        if self.prior <= 0 or not 0 < self.floor <= 0.5:
            raise ValueError("need prior > 0 and 0 < floor <= 0.5")


class OnlineDelayEM:
    """Per-trial EM estimate of the lag distribution over 0..lags-1 steps from recent feedback."""

    def __init__(self, trials: int, config: DelayLearningConfig = DelayLearningConfig(),
                 initial: np.ndarray | None = None):
        self.config = config
        L, W = config.lags, config.window
        start = np.full(L, 1.0 / L) if initial is None else np.asarray(initial, np.float64)
        start = np.broadcast_to(start, (trials, L))
        # The start distribution (per trial or shared) shapes the prior; a lag it rules out keeps a small
        # share so that the data can still revive it.
        start = np.maximum(start, 0.1 / L)
        self.prior = start / start.sum(axis=1, keepdims=True) * config.prior * L
        self.pi = self.prior / self.prior.sum(axis=1, keepdims=True)
        self.like = np.zeros((trials, W, L), np.float64)  # stored likelihood rows (0 = impossible lag)
        self.held = np.zeros(trials, np.int64)
        self.head = np.zeros(trials, np.int64)
        self.updates = np.zeros(trials, np.int64)

    def probs(self, rows: np.ndarray | None = None) -> np.ndarray:
        """[n, lags] current estimates."""
        return self.pi if rows is None else self.pi[rows]

    def likelihood(self, feedback: np.ndarray, predictions: np.ndarray, valid: np.ndarray) -> np.ndarray:
        h = np.clip(np.asarray(predictions, np.float64), -1.0, 1.0)
        like = np.maximum((1.0 + np.asarray(feedback, np.float64)[:, None] * h) / 2.0, self.config.floor)
        return like * valid

    def responsibilities(self, rows: np.ndarray, feedback: np.ndarray, predictions: np.ndarray,
                         valid: np.ndarray) -> np.ndarray:
        """E-step for one feedback per row under the current estimate: [n, lags]."""
        r = self.probs(rows) * self.likelihood(feedback, predictions, valid)
        total = r.sum(axis=1, keepdims=True)
        return np.divide(r, total, out=np.zeros_like(r), where=total > 0)

    def update(self, rows: np.ndarray, feedback: np.ndarray, predictions: np.ndarray,
               valid: np.ndarray) -> np.ndarray:
        """Store one feedback per row (rows distinct), then refit. Returns its responsibilities."""
        rows = np.asarray(rows, np.int64)
        r = self.responsibilities(rows, feedback, predictions, valid)
        seen = r.sum(axis=1) > 0
        rows = rows[seen]
        if not len(rows):
            return r
        W = self.config.window
        self.like[rows, self.head[rows]] = self.likelihood(feedback, predictions, valid)[seen]
        self.head[rows] = (self.head[rows] + 1) % W
        self.held[rows] = np.minimum(self.held[rows] + 1, W)
        self.updates[rows] += 1
        like = self.like[rows]  # unfilled rows are all zero and drop out below
        pi = self.pi[rows]
        for _ in range(self.config.iterations):
            post = pi[:, None, :] * like
            total = post.sum(axis=2, keepdims=True)
            post = np.divide(post, total, out=np.zeros_like(post), where=total > 0)
            pi = post.sum(axis=1) + self.prior[rows]
            pi /= pi.sum(axis=1, keepdims=True)
        self.pi[rows] = pi
        return r

    def select(self, rows: np.ndarray) -> None:
        for name in ("prior", "pi", "like", "held", "head", "updates"):
            setattr(self, name, getattr(self, name)[rows])

    def state_dict(self) -> dict:
        return {name: getattr(self, name).copy() for name in ("pi", "like", "held", "head", "updates")}

    def load_state_dict(self, state: dict) -> None:
        for name, value in state.items():
            getattr(self, name)[...] = value


def expected_lag(probs: np.ndarray) -> np.ndarray:
    """Mean lag in steps of each row of probs [n, lags]."""
    probs = np.asarray(probs, np.float64)
    return probs @ np.arange(probs.shape[-1], dtype=np.float64)


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


class TrialLags:
    """The credit component's delay part when trials differ in their lag distribution or learn it: an
    assumed point-mass distribution per trial (zero-padded to the longest), replaced by the online EM
    estimate (`OnlineDelayEM`, starting from the assumption) for trials whose config says `learn_delay`.
    `rows(r)` is what `common.core.credit` integrates for trials r."""

    def __init__(self, configs, step_unit: float = 1.0, window: int = 400):
        B, L = len(configs), max(len(c.assumed_delay_probs) for c in configs)
        self.width, self.unit = L, step_unit
        self.lags = np.arange(L, dtype=np.float64) * step_unit
        self.assumed = np.zeros((B, L), np.float64)
        for k, c in enumerate(configs):
            self.assumed[k, :len(c.assumed_delay_probs)] = c.assumed_delay_probs
        self.learn = np.array([bool(getattr(c, "learn_delay", False)) for c in configs])
        self.em = OnlineDelayEM(B, DelayLearningConfig(lags=L, window=window if self.learn.any() else 1),
                                initial=self.assumed)

    def probs(self, rows: np.ndarray) -> np.ndarray:
        """[n, L] the distribution credit uses now for trials `rows`."""
        out = self.assumed[rows]
        learn = self.learn[rows]
        if learn.any():
            out = out.copy()
            out[learn] = self.em.probs(rows[learn])
        return out

    def rows(self, rows: np.ndarray) -> RowDelays:
        return RowDelays(self.probs(rows), self.unit)

    def mean_lag(self, rows: np.ndarray) -> np.ndarray:
        return self.probs(rows) @ np.arange(self.width, dtype=np.float64)

    def select(self, rows: np.ndarray) -> None:
        self.assumed, self.learn = self.assumed[rows], self.learn[rows]
        self.em.select(rows)

    def state_dict(self) -> dict:
        return self.em.state_dict()

    def load_state_dict(self, state: dict) -> None:
        self.em.load_state_dict(state)
