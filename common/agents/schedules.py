"""Exploration and mixing schedules as pure functions of the global step count.

Functions of the step count (not running products) so the actor and the learner, and a restarted
process, agree on the value at any step without sharing state.
"""
from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class EpsilonSchedule:
    """Epsilon-greedy: start, minus `decay` per step, never below `floor` (paper: 0.3, 0.001, 0.1)."""

    start: float = 0.3
    decay: float = 0.001
    floor: float = 0.1

    def __call__(self, step: int) -> float:
        return max(self.floor, self.start - self.decay * step)


@dataclass(frozen=True)
class AlphaSchedule:
    """Policy mixture argmax(alpha_q Q + alpha_h H); alpha_h *= decay every step (paper: 1, 1, 0.9999)."""

    alpha_q: float = 1.0
    alpha_h: float = 1.0
    decay: float = 0.9999

    def alpha_h_at(self, step: int) -> float:
        return self.alpha_h * self.decay ** step
