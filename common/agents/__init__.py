"""The four agents of the paper, built from shared pieces (see `agent.TrialBatchAgent`)."""
from common.agents.agent import FeedbackOutcome, TrialBatchAgent
from common.agents.config import (AGENT_CONFIGS, ALGOS, AgentConfig, DeepTamerConfig, DQNConfig, DQNRSConfig,
                                  DQNTamerConfig, agent_config)

__all__ = ["FeedbackOutcome", "TrialBatchAgent", "AGENT_CONFIGS", "ALGOS", "AgentConfig", "DeepTamerConfig",
           "DQNConfig", "DQNRSConfig", "DQNTamerConfig", "agent_config"]
