"""Names of the environments the runners know, and the teacher rule that goes with each.

Any discrete-action Gymnasium environment can be plugged in: give it a name, a factory and a rule that
turns one step's `info` into +1/-1 (see `EnvSpec`).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Mapping

import gymnasium as gym

from common.envs.maze import MazeEnv
from common.envs.taxi import TaxiEnv

TeacherRule = Callable[[Mapping[str, float]], int]


def progress_rule(info: Mapping[str, float]) -> int:
    """The paper's binary rule: +1 if the action brought the agent closer (Manhattan) to its current
    target or completed a sub-goal (goal, pick-up, drop-off), else -1."""
    if info.get("subgoal_reached", 0.0) > 0:
        return 1
    return 1 if info["target_distance_after"] < info["target_distance_before"] else -1


@dataclass(frozen=True)
class EnvSpec:
    name: str
    factory: Callable[..., gym.Env]
    rule: TeacherRule
    uses_layout: bool


ENVS: dict[str, EnvSpec] = {
    "maze": EnvSpec("maze", lambda layout=0: MazeEnv(layout, "mdp"), progress_rule, True),
    "maze-pomdp": EnvSpec("maze-pomdp", lambda layout=0: MazeEnv(layout, "pomdp"), progress_rule, True),
    "taxi": EnvSpec("taxi", lambda layout=0: TaxiEnv(), progress_rule, False),
}
ENV_NAMES = tuple(ENVS)


def make_env(name: str, layout: int = 0) -> tuple[gym.Env, TeacherRule]:
    """The environment `name` (maze, maze-pomdp, taxi) and its teacher rule."""
    if name not in ENVS:
        raise ValueError(f"unknown env {name!r}; choose one of {', '.join(ENV_NAMES)}")
    spec = ENVS[name]
    return spec.factory(layout), spec.rule
