"""A trial's specification (`TrialSpec`: its environment, agent, observer, seed, episodes) and its result
(`TrialResult`: per-episode figures, `EPISODE_FIELDS`)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from common.agents import AgentConfig
from common.core.observer import ObserverConfig

EPISODE_FIELDS = (
    "episode",
    "return",
    "steps",
    "feedback_given",
    "feedback_credited",
    "feedback_stale",
    "epsilon",
    "alpha_h",
    "h_decided",
    "greedy",
    "mean_lag",
    "delay_median_s",
)


@dataclass(frozen=True)
class TrialSpec:
    """One trial: an environment (and layout), an agent, an observer, a seed and a length."""

    env: str
    agent: AgentConfig
    observer: ObserverConfig
    seed: int = 0
    layout: int = 0
    episodes: int = 100
    teacher_rule: str | None = None  # None: the env's own rule (common/envs/rules.py)
    step_seconds: float = 0.5  # seconds per step of the virtual clock (a learned delay's clock)


@dataclass
class TrialResult:
    spec: TrialSpec
    episodes: list[dict] = field(default_factory=list)
    actions: list[int] = field(default_factory=list)
    total_steps: int = 0
    weights: dict[str, np.ndarray] = field(default_factory=dict)  # final policy weights (Q and H)
    delay: dict | None = None  # the teacher's delay the agent credits with at the end (`delay_summary`)

    @property
    def returns(self) -> np.ndarray:
        return np.array([e["return"] for e in self.episodes])
