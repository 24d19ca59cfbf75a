"""The task every entry point shares: which environment, which initial condition, which seed, which
teacher rule. One documented dataclass, nested (flags unprefixed: `--env`, `--layout`, `--seed`,
`--teacher-rule`) in the configs of `experiments run`, `services up` and every live service, so a live
run and an in-process run with the same task are the same experiment."""

from __future__ import annotations

from dataclasses import dataclass

from common.config import option
from common.envs import LAYOUT_COUNT, check_task


@dataclass(frozen=True)
class Task:
    """The environment and teacher rule of a run (see common/envs/registry.py, docs/envs.md)."""

    env: str = option(
        "maze",
        "environment: a project name (maze, maze-pomdp, taxi, minigrid-empty), any "
        "Gymnasium id (FrozenLake-v1, MiniGrid-DoorKey-5x5-v0, ...), or module:factory",
    )
    layout: int = option(
        0,
        f"maze layout 0..{LAYOUT_COUNT - 1}, the initial condition (passed to a factory "
        "that takes layout=; ignored by other envs)",
    )
    seed: int = option(0, "trial seed: network init, exploration, observer, replay sampling, env")
    teacher_rule: str | None = option(
        None,
        "the simulated teacher's rule: progress, reward, auto or module:function (none = the env's own; docs/envs.md)",
    )

    def __post_init__(self):
        check_task(self.env, self.teacher_rule)
        if not 0 <= self.layout < LAYOUT_COUNT:
            raise ValueError(f"layout must be in 0..{LAYOUT_COUNT - 1}, got {self.layout}")
