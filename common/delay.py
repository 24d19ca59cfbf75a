"""Delay distributions: the observer's true lag and the learner's assumption about it.

A `DelayModel` is a discrete distribution over lags of i * unit (i = 0, 1, ...). In virtual time the
unit is one step; in the live system it is the actor's nominal step period in seconds.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

PROBABILITY_TOLERANCE = 1e-3


def parse_probs(text: str | tuple | list, name: str = "probabilities") -> tuple[float, ...]:
    """'0.3,0.6,0.1' -> (0.3, 0.6, 0.1), checked to be finite, non-negative and to sum to 1."""
    if isinstance(text, str):
        try:
            values = tuple(float(x) for x in text.split(",") if x.strip())
        except ValueError:
            raise ValueError(f"{name} must be comma-separated numbers, got {text!r}") from None
    else:
        values = tuple(float(x) for x in text)
    if not values:
        raise ValueError(f"{name} is empty")
    if any(not math.isfinite(v) or v < 0 for v in values):
        raise ValueError(f"{name} must be finite and non-negative, got {values}")
    total = sum(values)
    if abs(total - 1.0) > PROBABILITY_TOLERANCE:
        raise ValueError(f"{name} must sum to 1, got {values} (sum {total:.4f})")
    return values


@dataclass(frozen=True)
class DelayModel:
    """P(lag = i * unit) = probs[i]."""

    probs: tuple[float, ...]
    unit: float = 1.0

    def __post_init__(self):
        object.__setattr__(self, "probs", parse_probs(self.probs, "delay probabilities"))
        if not (self.unit > 0 and math.isfinite(self.unit)):
            raise ValueError(f"delay unit must be positive, got {self.unit}")

    @property
    def lags(self) -> np.ndarray:
        return np.arange(len(self.probs), dtype=np.float64) * self.unit

    @property
    def max_lag(self) -> float:
        return (len(self.probs) - 1) * self.unit

    def sample_steps(self, u: float) -> int:
        """The lag in units for a uniform draw u in [0, 1) (inverse CDF, so one draw per decision)."""
        acc = 0.0
        for i, p in enumerate(self.probs):
            acc += p
            if u < acc:
                return i
        return len(self.probs) - 1

    def mass_between(self, low: float, high: float) -> float:
        """P(low < lag <= high)."""
        lags = self.lags
        return float(sum(p for lag, p in zip(lags, self.probs) if low < lag <= high))

    @classmethod
    def uniform(cls, n: int, unit: float = 1.0) -> "DelayModel":
        return cls(tuple([1.0 / n] * n), unit)
