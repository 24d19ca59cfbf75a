"""Environments by name (project names, Gymnasium ids, module:factory) and teacher rules (see `registry`,
`rules`, `gym_tasks`)."""

from common.envs.maze import MazeEnv, MazeLayout, make_layout, LAYOUT_COUNT
from common.envs.taxi import TaxiEnv
from common.envs.registry import ENV_NAMES, EnvSpec, check_task, make_env, n_actions, obs_shape, resolve_env
from common.envs.rules import RULES, progress_rule, resolve_rule

__all__ = [
    "MazeEnv",
    "MazeLayout",
    "make_layout",
    "LAYOUT_COUNT",
    "TaxiEnv",
    "ENV_NAMES",
    "EnvSpec",
    "check_task",
    "make_env",
    "n_actions",
    "obs_shape",
    "resolve_env",
    "RULES",
    "progress_rule",
    "resolve_rule",
]
