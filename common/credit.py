"""Credit assignment by timestamp (Deep TAMER's rule), one function for virtual and real time.

A feedback stamped t_f may refer to any recent step. Step k, whose action was taken at tau_k, occupied
the interval until the next action tau_{k+1}; it receives the assumed-delay probability mass that falls
in that interval:  w_k = P(t_f - tau_{k+1} < delay <= t_f - tau_k).  The newest step's interval is open
(tau_{k+1} = +inf). Mass that falls before the oldest step still held is lost: the feedback refers to
steps we no longer have, and the caller counts it.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from common.delay import DelayModel


def credit_weights(t_feedback: float, step_times, assumed: DelayModel) -> tuple[np.ndarray, float]:
    """Weights of each held step (oldest first) for a feedback at `t_feedback`, and the lost mass.

    `step_times` are the action times of the held steps, ascending; durations may be unequal. Weights
    and lost mass sum to 1. Steps taken after t_feedback get 0: a reaction cannot precede its cause.
    """
    times = np.asarray(step_times, dtype=np.float64)
    n = len(times)
    weights = np.zeros(n, dtype=np.float64)
    if n == 0:
        return weights, 1.0
    if np.any(np.diff(times) < 0):
        raise ValueError("step_times must be ascending")
    lags = assumed.lags
    probs = np.asarray(assumed.probs, dtype=np.float64)
    # Each lag belongs to the newest step taken at or before t_f - lag.
    for lag, p in zip(lags, probs):
        if p == 0.0:
            continue
        cause_time = t_feedback - lag
        k = int(np.searchsorted(times, cause_time, side="right")) - 1
        if k >= 0:
            weights[k] += p
    lost = max(0.0, 1.0 - float(weights.sum()))
    return weights, lost


@dataclass
class CreditResult:
    """What one feedback was assigned to: (payload, weight) pairs with weight > 0, and the lost mass."""

    entries: list[tuple[Any, float]]
    lost_mass: float

    @property
    def credited(self) -> bool:
        return bool(self.entries)


@dataclass
class StepHistory:
    """The recent steps a feedback may still refer to: (action time, payload), oldest first.

    Holds `capacity` steps; older ones are forgotten, and feedback pointing only at them is stale.
    """

    capacity: int = 32
    _times: deque = field(default_factory=deque)
    _payloads: deque = field(default_factory=deque)

    def push(self, t_action: float, payload: Any) -> None:
        if self._times and t_action < self._times[-1]:
            raise ValueError(f"step time {t_action} is older than the previous step {self._times[-1]}")
        self._times.append(t_action)
        self._payloads.append(payload)
        if len(self._times) > self.capacity:
            self._times.popleft()
            self._payloads.popleft()

    def clear(self) -> None:
        self._times.clear()
        self._payloads.clear()

    def __len__(self) -> int:
        return len(self._times)

    @property
    def newest_time(self) -> float | None:
        return self._times[-1] if self._times else None

    def latest_at(self, t: float) -> Any | None:
        """The payload of the newest step taken at or before t (naive reward shaping's target)."""
        for time, payload in zip(reversed(self._times), reversed(self._payloads)):
            if time <= t:
                return payload
        return None

    def credit(self, t_feedback: float, assumed: DelayModel) -> CreditResult:
        weights, lost = credit_weights(t_feedback, self._times, assumed)
        entries = [(payload, float(w)) for payload, w in zip(self._payloads, weights) if w > 0]
        return CreditResult(entries, lost)
