"""The four agents of the paper, assembled from parts (see `agent.TrialBatchAgent`, `build.build_parts`);
Q and H as the paper's numpy MLP or any torch module (`torch_agent.make_agent`).

The configs are imported at once; the agent and its parts (which import torch) only when first used, so a
process that needs only the configs (the recorder, a teacher, the launcher) starts without torch."""

from __future__ import annotations

import importlib

from common.agents.config import (
    AGENT_CONFIGS,
    ALGOS,
    AgentConfig,
    DeepTamerConfig,
    DQNConfig,
    DQNRSConfig,
    DQNTamerConfig,
    agent_config,
)

_LAZY = {
    "FeedbackOutcome": "agent",
    "TrialBatchAgent": "agent",
    "AgentParts": "build",
    "build_parts": "build",
    "make_agent": "torch_agent",
}

__all__ = [
    "FeedbackOutcome",
    "TrialBatchAgent",
    "AgentParts",
    "build_parts",
    "AGENT_CONFIGS",
    "ALGOS",
    "AgentConfig",
    "DeepTamerConfig",
    "DQNConfig",
    "DQNRSConfig",
    "DQNTamerConfig",
    "agent_config",
    "make_agent",
]


def __getattr__(name: str):
    if name in _LAZY:
        value = getattr(importlib.import_module(f"common.agents.{_LAZY[name]}"), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'common.agents' has no attribute {name!r}")
