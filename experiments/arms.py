"""The arms of the reproduction's conditions: the observers' feedback rates and lags (the paper's and ours), and
the agent configuration of each arm (`agent_for`: an algorithm, and how it assumes, learns or is told the lag, or
how it weighs its teacher)."""

from __future__ import annotations

from dataclasses import replace
from typing import Any

from common.agents import AgentConfig, agent_config

NO_DELAY = (1.0, 0.0, 0.0)
PAPER_DELAY = (0.3, 0.6, 0.1)
HIGH, LOW = 0.5, 0.1
STOP_EPISODE = 30
FLIP = 0.15

# Beyond the paper: observers whose lag is skewed late, long, or drifting, over 0..6 steps.
WINDOW = 7
LATE_DELAY = (0.0, 0.05, 0.15, 0.5, 0.3)
LONG_DELAY = (0.05, 0.1, 0.15, 0.2, 0.2, 0.15, 0.15)
PAPER_PRIOR = (1 / 3, 1 / 3, 1 / 3)
"""The paper's learner's assumption: lags uniform over 0, 1, 2 steps (the `<algo>/uniform2` arms, declared 28
November 2026: the prior D1-D3 are tested against; `<algo>/uniform` is uniform over the whole window 0..6)."""
ADAPT_RATE = 0.01
MATCH_K = 0.3386
"""A1's control `dqn-tamer/matched`: the paper's alpha_h schedule times MATCH_K, the adaptive arm's mean
alpha_h over the paper arm's (alpha_h at each episode's end, averaged over episodes and trials) on a pilot
of maze-high-delay, 100 episodes, pilot layouts 44-59 (8 honest, 8 misleading), seeds 9000+:
`python -m experiments pilot alpha --episodes 100 --reps 2` (PILOT)."""
TRUST: dict[str, Any] = {"alpha_h_trust": 0.01, "alpha_h_trust_after": 1000, "alpha_h_trust_ref": 0.35}
"""M1's arm `dqn-tamer/trusted`: the teacher's reliability (common/agents/explorer.py), chosen on the same
pilot among the candidates it ran (PILOT)."""


# Per-environment agent settings that differ from the `AgentConfig` defaults, the same for all four agents
# (ours; why: docs/notes/2026-11-23-reproduction-pilots-and-speed.md, "Taxi"). The reproduction's Taxi observes
# the state one-hot beside the 19 factored values (`taxi-s`, `taxi-fixed-s`) and updates every step (b = 1), as
# on the Maze.
AGENT_OVERRIDES: dict[str, dict] = {
    "taxi": {"update_interval": 4},
    "taxi-fixed": {"update_interval": 4},
    "taxi-s": {"update_interval": 1},
    "taxi-fixed-s": {"update_interval": 1},
}


def _padded(probs: tuple[float, ...]) -> tuple[float, ...]:
    return tuple(probs) + (0.0,) * (WINDOW - len(probs))


def agent_for(arm: str, env: str = "maze", true_delay: tuple[float, ...] = PAPER_DELAY) -> AgentConfig:
    """The agent configuration of an arm in an environment (the `AgentConfig` defaults otherwise)."""
    algo, _, how = arm.partition("/")
    cfg = agent_config(algo, **AGENT_OVERRIDES.get(env, {}))
    if how == "uniform":
        return replace(cfg, assumed_delay_probs=(1.0 / WINDOW,) * WINDOW)
    if how == "uniform2":
        return replace(cfg, assumed_delay_probs=_padded(PAPER_PRIOR))
    if how == "true":
        return replace(cfg, assumed_delay_probs=_padded(true_delay))
    if how == "learned":
        return replace(cfg, assumed_delay_probs=(1.0 / WINDOW,) * WINDOW, learn_delay=True)
    if how == "adaptive":
        return replace(cfg, alpha_h_adapt=ADAPT_RATE)
    if how == "matched":
        return replace(cfg, alpha_h=cfg.alpha_h * MATCH_K)
    if how == "trusted":
        return replace(cfg, **TRUST)
    if how:
        raise ValueError(f"unknown arm {arm!r}")
    return cfg
