"""One documented config dataclass per agent. Paper values where the paper gives them; the rest (ours)
are chosen for the paper's small tasks and explained in docs/hyperparameters.md."""
from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace

from common.delay import parse_probs


@dataclass(frozen=True)
class AgentConfig:
    """Everything an agent of this project is made of. The four algorithms are presets of it."""

    algo: str = "dqn-tamer"
    # Networks and optimiser (paper): one hidden layer of 100 tanh units, RMSProp, lr 1e-3.
    hidden: int = 100
    lr: float = 1e-3
    rmsprop_alpha: float = 0.99
    rmsprop_eps: float = 1e-8
    # Exploration (paper): epsilon-greedy 0.3, minus 0.001 per step, floor 0.1.
    epsilon_start: float = 0.3
    epsilon_decay: float = 0.001
    epsilon_floor: float = 0.1
    # Mixture (paper): argmax(alpha_q Q + alpha_h H), alpha_h *= alpha_h_decay every step.
    alpha_q: float = 1.0
    alpha_h: float = 1.0
    alpha_h_decay: float = 0.9999
    # Which parts learn.
    train_q: bool = True
    """Learn Q from the environment's reward (DQN part)."""
    train_h: bool = True
    """Learn H from feedback (Deep TAMER part)."""
    reward_shaping: bool = False
    """Naive shaping: add a feedback to the reward of the newest step at its arrival (DQN+RS)."""
    # DQN (ours).
    gamma: float = 0.9
    batch_size: int = 32
    replay_size: int = 10_000
    replay_start: int = 32
    target_update_interval: int = 100
    update_interval: int = 1
    """b: Q update and D_global minibatch every b steps (Algorithm 2)."""
    # Deep TAMER (ours).
    h_batch_size: int = 32
    feedback_memory_size: int = 20_000
    assumed_delay_probs: tuple[float, ...] = (1 / 3, 1 / 3, 1 / 3)
    """The learner's assumption about the observer's lag over 0, 1, 2, ... steps (uniform by default)."""
    history_steps: int = 32
    """Recent steps a feedback may still be credited to; older targets are stale."""

    def __post_init__(self):
        object.__setattr__(self, "assumed_delay_probs",
                           parse_probs(self.assumed_delay_probs, "assumed-delay-probs"))
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, float) and not math.isfinite(v):
                raise ValueError(f"{f.name} must be finite, got {v}")
        positive = ("hidden", "batch_size", "replay_size", "target_update_interval", "update_interval",
                    "h_batch_size", "feedback_memory_size", "history_steps")
        for name in positive:
            if getattr(self, name) <= 0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)}")
        if not 0 <= self.gamma <= 1:
            raise ValueError(f"gamma must be in [0, 1], got {self.gamma}")
        if self.lr <= 0:
            raise ValueError(f"lr must be positive, got {self.lr}")

    def with_(self, **changes) -> "AgentConfig":
        return replace(self, **changes)


@dataclass(frozen=True)
class DQNConfig(AgentConfig):
    """DQN: Q only; feedback is ignored."""

    algo: str = "dqn"
    alpha_h: float = 0.0
    train_h: bool = False


@dataclass(frozen=True)
class DQNRSConfig(AgentConfig):
    """DQN with naive reward shaping: feedback added to the reward of the step it arrives after."""

    algo: str = "dqn-rs"
    alpha_h: float = 0.0
    train_h: bool = False
    reward_shaping: bool = True


@dataclass(frozen=True)
class DeepTamerConfig(AgentConfig):
    """Deep TAMER: H only, argmax H (alpha_q = 0, alpha_h constant)."""

    algo: str = "deep-tamer"
    alpha_q: float = 0.0
    alpha_h_decay: float = 1.0
    train_q: bool = False


@dataclass(frozen=True)
class DQNTamerConfig(AgentConfig):
    """DQN-TAMER: Q and H trained separately, argmax(alpha_q Q + alpha_h H), alpha_h decaying."""

    algo: str = "dqn-tamer"


AGENT_CONFIGS: dict[str, type[AgentConfig]] = {
    "dqn": DQNConfig, "dqn-rs": DQNRSConfig, "deep-tamer": DeepTamerConfig, "dqn-tamer": DQNTamerConfig}
ALGOS = tuple(AGENT_CONFIGS)


def agent_config(algo: str, **overrides) -> AgentConfig:
    if algo not in AGENT_CONFIGS:
        raise ValueError(f"unknown algo {algo!r}; choose one of {', '.join(ALGOS)}")
    return AGENT_CONFIGS[algo](**overrides)
