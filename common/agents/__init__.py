"""The four agents of the paper, assembled from parts (see `agent.TrialBatchAgent`, `build.build_parts`)."""
from common.agents.agent import FeedbackOutcome, TrialBatchAgent
from common.agents.build import AgentParts, build_parts
from common.agents.config import (AGENT_CONFIGS, ALGOS, AgentConfig, DeepTamerConfig, DQNConfig, DQNRSConfig,
                                  DQNTamerConfig, agent_config)

__all__ = ["FeedbackOutcome", "TrialBatchAgent", "AgentParts", "build_parts", "AGENT_CONFIGS", "ALGOS", "AgentConfig", "DeepTamerConfig",
           "DQNConfig", "DQNRSConfig", "DQNTamerConfig", "agent_config"]
