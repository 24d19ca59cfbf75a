"""The simulated human observer with the paper's five characteristics.

binary (a rule per environment: +1/-1), delay (true lag drawn from `delay_probs`), stochasticity (a step
gets feedback with probability `p_feedback`), unsustainability (silent from episode `stop_episode` or
global step `stop_step` on), natural reaction (polarity flipped with probability `p_flip`).

It is deterministic for a seed and draws the same three numbers for every step, so two observers with the
same seed but different settings make the same underlying choices (common random numbers).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Mapping

import numpy as np

from common.config import option
from common.delay import DelayModel, parse_probs

# A reaction lands half a step after its lag: between two actions, never on one.
REACTION_OFFSET = 0.5


@dataclass(frozen=True)
class ObserverConfig:
    """The simulated observer: how often, how late and how reliably it gives feedback."""

    p_feedback: float = option(0.5, "probability that a step gets any feedback (stochasticity)")
    delay_probs: tuple[float, ...] = option((0.3, 0.6, 0.1), "true lag distribution over 0, 1, 2, ... steps (delay)")
    p_flip: float = option(0.0, "probability that the polarity is flipped (natural reaction, a misread face)")
    stop_episode: int | None = option(None, "no feedback for steps of this episode (0-based) and later "
                                            "(unsustainability); none = never")
    stop_step: int | None = option(None, "no feedback for this global step (0-based) and later; none = never")

    def __post_init__(self):
        object.__setattr__(self, "delay_probs", parse_probs(self.delay_probs, "delay-probs"))
        for name in ("p_feedback", "p_flip"):
            value = getattr(self, name)
            if not (math.isfinite(value) and 0.0 <= value <= 1.0):
                raise ValueError(f"{name.replace('_', '-')} must be in [0, 1], got {value}")
        for name in ("stop_episode", "stop_step"):
            value = getattr(self, name)
            if value is not None and value < 0:
                raise ValueError(f"{name.replace('_', '-')} must be >= 0, got {value}")


@dataclass(frozen=True)
class FeedbackEvent:
    """One reaction: stamped with the time it happens (t_reaction), not the time of the step."""

    t_reaction: float
    value: int
    intended: int
    step_ref: int
    lag_steps: int


class SimulatedObserver:
    def __init__(self, config: ObserverConfig, rule: Callable[[Mapping[str, float]], int], seed: int,
                 step_unit: float = 1.0):
        self.config = config
        self.rule = rule
        self.delay = DelayModel(config.delay_probs, step_unit)
        self.step_unit = step_unit
        self.rng = np.random.default_rng(seed)
        self.emitted = 0
        self.flipped = 0

    def silent(self, episode: int, global_step: int) -> bool:
        c = self.config
        return ((c.stop_episode is not None and episode >= c.stop_episode)
                or (c.stop_step is not None and global_step >= c.stop_step))

    def react(self, t_action: float, info: Mapping[str, float], episode: int, global_step: int,
              step_ref: int | None = None) -> FeedbackEvent | None:
        """The observer watches the step whose action was taken at t_action; maybe reacts later."""
        give, u_delay, u_flip = self.rng.random(3)
        if self.silent(episode, global_step) or give >= self.config.p_feedback:
            return None
        intended = self.rule(info)
        lag = self.delay.sample_steps(u_delay)
        value = -intended if u_flip < self.config.p_flip else intended
        self.emitted += 1
        self.flipped += value != intended
        t_reaction = t_action + (lag + REACTION_OFFSET) * self.step_unit
        return FeedbackEvent(t_reaction, int(value), int(intended),
                             global_step if step_ref is None else step_ref, lag)
