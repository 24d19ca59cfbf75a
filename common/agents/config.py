"""One documented config dataclass per agent. Paper values where the paper gives them; the rest (ours)
are chosen for the paper's small tasks and explained in docs/hyperparameters.md."""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace

from common.config import option
from common.core.delay import check_delay_spec, parse_probs

NETWORKS = ("auto", "mlp", "torch-mlp", "cnn")  # the built-in networks (common/agents/torch_net.py builds them)


def resolve_network(name: str, obs_shape: tuple[int, ...]) -> str:
    """`auto` made concrete: cnn for image observations (3-d), else mlp (the numpy MLP: no torch)."""
    if name == "auto":
        return "cnn" if len(obs_shape) == 3 else "mlp"
    return name


@dataclass(frozen=True)
class AgentConfig:
    """Everything an agent of this project is made of. The four algorithms are presets of it."""

    algo: str = option(
        "dqn-tamer",
        "which of the four agents (dqn, dqn-rs, deep-tamer, dqn-tamer); a preset of the fields below",
        cli=False,
    )
    # Networks and optimiser (paper): one hidden layer of 100 tanh units, RMSProp, lr 1e-3.
    network: str = option(
        "auto",
        "Q and H networks: mlp (the paper's, fast numpy path), cnn (images), "
        "module:factory (any torch nn.Module), or auto (cnn for image observations, "
        "else mlp)",
    )
    device: str = option("cpu", "torch device of a non-mlp network (cpu, cuda, cuda:1, ...)")
    hidden: int = option(100, "hidden units of the mlp (and of the cnn's dense layer)")
    lr: float = option(1e-3, "RMSProp learning rate of Q and H")
    rmsprop_alpha: float = option(0.99, "RMSProp smoothing constant")
    rmsprop_eps: float = option(1e-8, "RMSProp epsilon")
    # Exploration (paper): epsilon-greedy 0.3, minus 0.001 per step, floor 0.1.
    epsilon_start: float = option(0.3, "epsilon-greedy: epsilon at step 0")
    epsilon_decay: float = option(0.001, "epsilon-greedy: epsilon lost per step")
    epsilon_floor: float = option(0.1, "epsilon-greedy: lowest epsilon")
    # Mixture (paper): argmax(alpha_q Q + alpha_h H), alpha_h *= alpha_h_decay every step.
    alpha_q: float = option(1.0, "weight of Q in argmax(alpha_q Q + alpha_h H)")
    alpha_h: float = option(1.0, "weight of H at step 0 (dqn, dqn-rs: 0)")
    alpha_h_decay: float = option(0.9999, "alpha_h is multiplied by this every step (deep-tamer: 1)")
    train_q: bool = option(True, "learn Q from the environment's reward (DQN part; deep-tamer: false)")
    train_h: bool = option(True, "learn H from feedback (Deep TAMER part; dqn, dqn-rs: false)")
    reward_shaping: bool = option(
        False, "naive shaping: add a feedback to the reward of the newest step at its arrival (dqn-rs: true)"
    )
    # DQN (ours).
    gamma: float = option(0.9, "discount of the Q target")
    batch_size: int = option(32, "Q minibatch size")
    replay_size: int = option(10_000, "transitions kept for Q's replay")
    replay_start: int = option(32, "transitions stored before Q learns")
    target_update_interval: int = option(100, "steps between copies of Q into its target network")
    update_interval: int = option(1, "b: a Q and a D_global minibatch update every b steps (Algorithm 2)")
    # Deep TAMER (ours).
    h_batch_size: int = option(32, "H minibatch size (from D_global)")
    feedback_memory_size: int = option(20_000, "credited (step, feedback, weight) rows kept in D_global")
    assumed_delay_probs: tuple[float, ...] = option(
        (1 / 3, 1 / 3, 1 / 3), "the learner's assumption about the observer's lag over 0, 1, 2, ... steps (for credit)"
    )
    history_steps: int = option(32, "recent steps a feedback may still be credited to; older targets are stale")
    # Beyond the paper (ours; docs/results/REPORT.md: learned delay, adaptive alpha_h).
    learn_delay: bool = option(
        False,
        "learn the teacher's delay in seconds online (common.core.delay_model: a "
        "density over 0-6 s, from delay_prior), instead of assumed_delay_probs",
    )
    delay_prior: str = option("uniform:0.2,4", "the learned delay's prior in seconds (Deep TAMER's uniform 0.2-4 s)")
    alpha_h_adapt: float = option(
        0.0,
        "if > 0, alpha_h is also multiplied by a running rate (this step size, "
        "from 1) of argmax H agreeing with argmax Q; 0 = the paper's schedule",
    )
    alpha_h_trust: float = option(
        0.0,
        "if > 0, the teacher's reliability: a running rate (this step size, from 1) "
        "of argmax H agreeing with argmax Q from step alpha-h-trust-after on; "
        "alpha_h is multiplied by min(1, reliability / alpha-h-trust-ref)",
    )
    alpha_h_trust_after: int = option(0, "steps before the reliability counts (Q learns from the return first)")
    alpha_h_trust_ref: float = option(1.0, "reliability at or above which the teacher keeps the whole alpha_h")

    def __post_init__(self):
        object.__setattr__(self, "assumed_delay_probs", parse_probs(self.assumed_delay_probs, "assumed-delay-probs"))
        check_delay_spec(self.delay_prior)
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, float) and not math.isfinite(v):
                raise ValueError(f"{f.name} must be finite, got {v}")
        positive = (
            "hidden",
            "batch_size",
            "replay_size",
            "target_update_interval",
            "update_interval",
            "h_batch_size",
            "feedback_memory_size",
            "history_steps",
        )
        for name in ("alpha_h_adapt", "alpha_h_trust"):
            if not 0 <= getattr(self, name) <= 1:
                raise ValueError(f"{name} must be in [0, 1], got {getattr(self, name)}")
        if self.alpha_h_trust_after < 0 or not 0 < self.alpha_h_trust_ref <= 1:
            raise ValueError("alpha_h_trust_after must be >= 0 and alpha_h_trust_ref in (0, 1]")
        for name in positive:
            if getattr(self, name) <= 0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)}")
        if not 0 <= self.gamma <= 1:
            raise ValueError(f"gamma must be in [0, 1], got {self.gamma}")
        if self.lr <= 0:
            raise ValueError(f"lr must be positive, got {self.lr}")
        if self.algo not in AGENT_CONFIGS:
            raise ValueError(f"unknown algo {self.algo!r}; choose one of {', '.join(AGENT_CONFIGS)}")
        if self.network not in NETWORKS:  # torch only for a module:factory (configs stay torch-free)
            from common.agents.torch_net import network_factory

            network_factory(self.network)  # a one-line error naming a bad name or module:factory

    def with_(self, **changes) -> AgentConfig:
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
    "dqn": DQNConfig,
    "dqn-rs": DQNRSConfig,
    "deep-tamer": DeepTamerConfig,
    "dqn-tamer": DQNTamerConfig,
}
ALGOS = tuple(AGENT_CONFIGS)


def agent_config(algo: str, /, **overrides) -> AgentConfig:
    """The preset of `algo` with `overrides` (a settings dict's `algo`, if any, must agree)."""
    if algo not in AGENT_CONFIGS:
        raise ValueError(f"unknown algo {algo!r}; choose one of {', '.join(ALGOS)}")
    if overrides.get("algo", algo) != algo:
        raise ValueError(f"agent.algo {overrides['algo']!r} differs from algo {algo!r}")
    overrides.pop("algo", None)
    return AGENT_CONFIGS[algo](**overrides)


def agent_for(algo: str, agent) -> AgentConfig:
    """`agent` (a settings dict, None or an AgentConfig) on top of `algo`'s preset, for a parent config's
    `__post_init__`; an AgentConfig of another algorithm is an error naming both."""
    from common.config import nested

    built = nested(agent, AgentConfig, build=lambda **kw: agent_config(algo, **kw), name="agent")
    if built.algo != algo:
        raise ValueError(f"agent.algo {built.algo!r} differs from algo {algo!r}")
    return built
