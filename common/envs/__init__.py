"""Environments of the paper, with the teacher rule each one needs (see `registry`)."""
from common.envs.maze import MazeEnv, MazeLayout, make_layout, LAYOUT_COUNT
from common.envs.taxi import TaxiEnv
from common.envs.registry import ENV_NAMES, EnvSpec, make_env, progress_rule

__all__ = ["MazeEnv", "MazeLayout", "make_layout", "LAYOUT_COUNT", "TaxiEnv", "ENV_NAMES", "EnvSpec",
           "make_env", "progress_rule"]
