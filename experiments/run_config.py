"""The config of `python -m experiments run`: one documented dataclass, also the command line."""
from __future__ import annotations

import math
from dataclasses import dataclass

from common.agents import ALGOS, agent_config
from common.config import option
from common.delay import parse_probs
from common.envs import ENV_NAMES, LAYOUT_COUNT
from common.observer import ObserverConfig


@dataclass(frozen=True)
class RunConfig:
    """Run one agent on one environment against the simulated observer, on a virtual clock."""

    env: str = option("maze", "environment", choices=ENV_NAMES)
    algo: str = option("dqn-tamer", "agent", choices=ALGOS)
    layout: int = option(0, f"maze layout 0..{LAYOUT_COUNT - 1} (the initial condition; ignored by taxi)")
    seed: int = option(0, "trial seed (network init, exploration, observer, replay sampling)")
    episodes: int = option(100, "episodes to run")
    p_feedback: float = option(0.5, "probability that the observer gives feedback on a step")
    delay_probs: tuple[float, ...] = option((0.3, 0.6, 0.1), "observer's true lag distribution over 0,1,2.. steps")
    assumed_delay_probs: tuple[float, ...] = option((0.3333, 0.3333, 0.3334),
                                                    "lag distribution the learner assumes for credit")
    stop_episode: int | None = option(None, "observer silent from this episode on (0-based); none = never")
    stop_step: int | None = option(None, "observer silent from this global step on; none = never")
    flip: float = option(0.0, "probability the observer's polarity is flipped (misread reaction)")
    out: str = option("runs/experiment", "output directory for config.json, episodes.csv and curve.png")

    def __post_init__(self):
        if self.env not in ENV_NAMES:
            raise ValueError(f"unknown env {self.env!r}; choose one of {', '.join(ENV_NAMES)}")
        if self.algo not in ALGOS:
            raise ValueError(f"unknown algo {self.algo!r}; choose one of {', '.join(ALGOS)}")
        if self.episodes < 0:
            raise ValueError(f"episodes must be >= 0, got {self.episodes}")
        if not 0 <= self.layout < LAYOUT_COUNT:
            raise ValueError(f"layout must be in 0..{LAYOUT_COUNT - 1}, got {self.layout}")
        for name in ("p_feedback", "flip"):
            v = getattr(self, name)
            if not (math.isfinite(v) and 0 <= v <= 1):
                raise ValueError(f"{name.replace('_', '-')} must be in [0, 1], got {v}")
        object.__setattr__(self, "delay_probs", parse_probs(self.delay_probs, "delay-probs"))
        object.__setattr__(self, "assumed_delay_probs", parse_probs(self.assumed_delay_probs, "assumed-delay-probs"))
        for name in ("stop_episode", "stop_step"):
            v = getattr(self, name)
            if v is not None and v < 0:
                raise ValueError(f"{name.replace('_', '-')} must be >= 0, got {v}")

    def observer(self) -> ObserverConfig:
        return ObserverConfig(self.p_feedback, self.delay_probs, self.flip, self.stop_episode, self.stop_step)

    def agent(self):
        return agent_config(self.algo, assumed_delay_probs=self.assumed_delay_probs)
