"""The four agents of the paper, assembled from parts (see `agent.TrialBatchAgent`, `build.build_parts`);
Q and H as the paper's numpy MLP or any torch module (`torch_agent.make_agent`)."""
from common.agents.agent import FeedbackOutcome, TrialBatchAgent
from common.agents.build import AgentParts, build_parts
from common.agents.config import (AGENT_CONFIGS, ALGOS, AgentConfig, DeepTamerConfig, DQNConfig, DQNRSConfig,
                                  DQNTamerConfig, agent_config)
from common.agents.torch_agent import make_agent

__all__ = ["FeedbackOutcome", "TrialBatchAgent", "AgentParts", "build_parts", "AGENT_CONFIGS", "ALGOS", "AgentConfig",
           "DeepTamerConfig", "DQNConfig", "DQNRSConfig", "DQNTamerConfig", "agent_config", "make_agent"]
