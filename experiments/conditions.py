"""The paper's experimental conditions, each run with all four agents (see docs/hyperparameters.md).

Observer settings (DESIGN.md): high / low feedback frequency p_feedback 0.5 / 0.1; "without delay" is a
lag of 0 steps for every reaction (delay_probs 1,0,0), "with delay" the paper's true
lag distribution (0.3, 0.6, 0.1) over 0, 1, 2 steps. The learner always assumes lags uniform over 0..2.
The feedback-stop and natural-reaction conditions use the realistic observer: high frequency, delayed.

Trials: trial k of a maze condition runs on layout k % 10 with seed k // 10, so 30 trials are the
paper's 10 initial conditions x 3 seeds, and any prefix of the trials covers the layouts evenly. Taxi has
one layout: trial k is seed k. Trial k uses the same layout and seed under every agent and condition
(common random numbers), so comparisons between agents or conditions are paired by trial.
"""
from __future__ import annotations

from dataclasses import dataclass

from common.agents import ALGOS, AgentConfig, agent_config
from common.observer import ObserverConfig
from experiments.runner import TrialSpec

NO_DELAY = (1.0, 0.0, 0.0)
PAPER_DELAY = (0.3, 0.6, 0.1)
HIGH, LOW = 0.5, 0.1
STOP_EPISODE = 30
FLIP = 0.15

# Episode counts (ours; why: docs/hyperparameters.md "Episode counts").
MAZE_EPISODES = 60
TAXI_EPISODES = 50


@dataclass(frozen=True)
class Condition:
    name: str
    title: str
    env: str
    observer: ObserverConfig
    episodes: int
    figure: str
    """Which of the paper's figures the panel belongs to."""

    @property
    def stop_episode(self) -> int | None:
        return self.observer.stop_episode


CONDITIONS: tuple[Condition, ...] = (
    Condition("maze-high-nodelay", "Maze MDP, high frequency (p=0.5), no delay", "maze",
              ObserverConfig(HIGH, NO_DELAY), MAZE_EPISODES, "Fig. maze results, upper left"),
    Condition("maze-high-delay", "Maze MDP, high frequency (p=0.5), with delay", "maze",
              ObserverConfig(HIGH, PAPER_DELAY), MAZE_EPISODES, "Fig. maze results, upper right"),
    Condition("maze-low-nodelay", "Maze MDP, low frequency (p=0.1), no delay", "maze",
              ObserverConfig(LOW, NO_DELAY), MAZE_EPISODES, "Fig. maze results, lower left"),
    Condition("maze-low-delay", "Maze MDP, low frequency (p=0.1), with delay", "maze",
              ObserverConfig(LOW, PAPER_DELAY), MAZE_EPISODES, "Fig. maze results, lower right"),
    Condition("maze-stop", "Maze MDP, feedback stops after 30 episodes", "maze",
              ObserverConfig(HIGH, PAPER_DELAY, stop_episode=STOP_EPISODE), MAZE_EPISODES,
              "Fig. feedback stop, left"),
    Condition("pomdp-stop", "Maze POMDP, feedback stops after 30 episodes", "maze-pomdp",
              ObserverConfig(HIGH, PAPER_DELAY, stop_episode=STOP_EPISODE), MAZE_EPISODES,
              "Fig. feedback stop, right"),
    Condition("taxi-stop", "Taxi, feedback stops after 30 episodes", "taxi",
              ObserverConfig(HIGH, PAPER_DELAY, stop_episode=STOP_EPISODE), TAXI_EPISODES, "Fig. taxi"),
    Condition("maze-flip", "Maze MDP, delayed feedback with 15% polarity flips", "maze",
              ObserverConfig(HIGH, PAPER_DELAY, p_flip=FLIP), MAZE_EPISODES, "natural reaction (Sec. V-C)"),
)
BY_NAME = {c.name: c for c in CONDITIONS}


# Per-environment agent settings that differ from the `AgentConfig` defaults (ours; why:
# docs/hyperparameters.md "update interval"). Taxi updates every 4 steps, as DQN did on Atari: no agent
# solves Taxi within the run either way, and Taxi's 1000-step episodes make it the costliest condition.
AGENT_OVERRIDES: dict[str, dict] = {"taxi": {"update_interval": 4}}


def agent_for(algo: str, env: str = "maze") -> AgentConfig:
    """The agent configuration of a condition: the `AgentConfig` defaults (see their docs) and the
    environment's overrides."""
    return agent_config(algo, **AGENT_OVERRIDES.get(env, {}))


def trial_spec(cond: Condition, algo: str, k: int, episodes: int | None = None) -> TrialSpec:
    maze = cond.env.startswith("maze")
    layout, seed = (k % 10, k // 10) if maze else (0, k)
    return TrialSpec(cond.env, agent_for(algo, cond.env), cond.observer, seed=seed, layout=layout,
                     episodes=cond.episodes if episodes is None else episodes)


def select(names: list[str] | None) -> list[Condition]:
    if not names:
        return list(CONDITIONS)
    unknown = [n for n in names if n not in BY_NAME]
    if unknown:
        raise ValueError(f"unknown condition {', '.join(unknown)}; choose from {', '.join(BY_NAME)}")
    return [BY_NAME[n] for n in names]


__all__ = ["ALGOS", "CONDITIONS", "BY_NAME", "Condition", "agent_for", "trial_spec", "select"]
