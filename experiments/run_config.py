"""The config of `python -m experiments run`: one documented dataclass tree, also the command line
(`--env FrozenLake-v1 --algo dqn-tamer --agent.lr 5e-4 --observer.p-feedback 0.2 --config FILE`)."""

from __future__ import annotations

from dataclasses import dataclass

from common.agents import ALGOS, AgentConfig
from common.agents.config import agent_for
from common.config import nested, option
from common.core.observer import ObserverConfig
from common.core.task import Task


@dataclass(frozen=True)
class RunConfig:
    """Run one agent on one environment against the simulated observer, on a virtual clock."""

    task: Task = option(Task(), "environment, layout, seed, teacher rule", flatten=True)
    algo: str = option("dqn-tamer", "agent", choices=ALGOS)
    episodes: int = option(100, "episodes to run")
    agent: AgentConfig | None = option(
        None, "the agent's hyper-parameters (default: the algo's preset)", exclude=("algo",)
    )
    observer: ObserverConfig = option(ObserverConfig(), "the simulated observer")
    step_seconds: float = option(
        0.5,
        "seconds per step of the virtual clock (2 steps/s): the clock of a delay "
        "learned in seconds (--agent.learn-delay) and of --observer.delay-s",
    )
    out: str = option(
        "runs/experiment",
        "output directory for config.json, episodes.csv, summary.json (with the teacher's delay) and curve.png",
    )

    def __post_init__(self):
        if self.algo not in ALGOS:
            raise ValueError(f"unknown algo {self.algo!r}; choose one of {', '.join(ALGOS)}")
        object.__setattr__(self, "task", nested(self.task, Task))
        object.__setattr__(self, "agent", agent_for(self.algo, self.agent))
        object.__setattr__(self, "observer", nested(self.observer, ObserverConfig, name="observer"))
        if not (self.step_seconds > 0 and self.step_seconds < 3600):
            raise ValueError(f"step-seconds must be positive, got {self.step_seconds}")
        if self.episodes < 0:
            raise ValueError(f"episodes must be >= 0, got {self.episodes}")
