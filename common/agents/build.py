"""Assembling an agent: the parts of `TrialBatchAgent` built from its configs (or passed in instead).

`build_parts` is the one place that decides what each part is; a caller may build its own `AgentParts`
(another network, replay or explorer) and hand it to the agent. Every part keeps one row per trial and
can drop rows (`select`), so the agent can shrink its batch.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from common.agents.config import AgentConfig
from common.agents.explorer import EpsilonGreedy, Mixture, UniformBlocks
from common.agents.feedback import TeacherDelays
from common.agents.memory import BatchStepHistory, FeedbackMemory, TransitionReplay
from common.agents.mlp import HotCodes, takes_rows
from common.agents.networks import FlatRMSProp, StackedMLP, ValueNetworks
from common.core.seeding import derive_seed

# Structural settings must agree across a batch; the rest may differ per trial.
SHARED_FIELDS = (
    "network",
    "device",
    "hidden",
    "lr",
    "rmsprop_alpha",
    "rmsprop_eps",
    "gamma",
    "batch_size",
    "replay_size",
    "replay_start",
    "target_update_interval",
    "update_interval",
    "h_batch_size",
    "feedback_memory_size",
    "history_steps",
)


@dataclass
class AgentParts:
    q: ValueNetworks
    q_target: ValueNetworks
    h: ValueNetworks
    replay: TransitionReplay
    feedback_memory: FeedbackMemory
    history: BatchStepHistory
    explorer: EpsilonGreedy
    mixture: Mixture
    delays: TeacherDelays  # the teachers' delays: assumed step lags per trial, a delay in seconds per teacher
    q_draws: UniformBlocks  # Q's replay minibatch draws (counter-based, per trial)
    h_draws: UniformBlocks  # H's D_global minibatch draws
    hot: HotCodes | None = None  # observations are kept (replay, D_global, history) and fed to Q and H as codes

    _ROWS = ("q", "q_target", "h", "replay", "feedback_memory", "history", "explorer", "mixture", "q_draws", "h_draws")
    _STATE = ("q", "q_target", "h", "replay", "feedback_memory", "history", "mixture", "delays")

    def select(self, rows: np.ndarray) -> None:
        for name in self._ROWS + ("delays",):
            getattr(self, name).select(rows)

    def state_dict(self) -> dict:
        return {name: getattr(self, name).state_dict() for name in self._STATE}

    def load_state_dict(self, state: dict) -> None:
        if "assumed_delay" in state:  # (written before the registry: a trial's learned delay, by its old name)
            state = {**state, "delays": state["assumed_delay"]}
        for name in self._STATE:
            if name in state:  # (logs written before a part kept state lack it)
                getattr(self, name).load_state_dict(state[name])


def _keys(seeds: list[int], purpose: str) -> np.ndarray:
    return np.array([derive_seed(s, purpose) for s in seeds], dtype=np.uint64)


def mlp(
    configs: list[AgentConfig],
    obs_dim: int,
    n_actions: int,
    seeds: list[int],
    purpose: str,
    trained: bool = True,
    hot: HotCodes | None = None,
) -> StackedMLP:
    """The paper's network (one hidden layer of `hidden` tanh units) per trial, with RMSProp if trained (fed codes
    where `hot`)."""
    c = configs[0]
    opt = FlatRMSProp(c.lr, c.rmsprop_alpha, c.rmsprop_eps) if trained else None
    return StackedMLP(obs_dim, c.hidden, n_actions, [derive_seed(s, purpose) for s in seeds], opt, hot)


def hot_codes(obs_dim: int, hot_inputs: int | None, hidden: int) -> HotCodes | None:
    """Codes for observations of `obs_dim` inputs with exactly `hot_inputs` ones (None: not known), where the
    numpy MLP takes its first layer as rows (`mlp.takes_rows`): else None (dense)."""
    if not hot_inputs or not takes_rows(np.empty((0, obs_dim + 1, hidden))):
        return None
    return HotCodes(obs_dim, hot_inputs)


def build_parts(
    configs: list[AgentConfig],
    obs_dim: int,
    n_actions: int,
    seeds: list[int],
    step_unit: float = 1.0,
    make_network=mlp,
    hot: HotCodes | None = None,
) -> AgentParts:
    """The parts of an agent for these configs. `make_network(configs, obs_dim, n_actions, seeds, purpose,
    trained)` builds each value network (Q, its target, H; the purpose names its initialisation stream). hot
    (`hot_codes`; only with the numpy MLP, `mlp`): observations are kept as their codes, with the same numbers."""
    c, B = configs[0], len(configs)
    if hot is not None:
        make_network = functools.partial(mlp, hot=hot)
    width = obs_dim if hot is None else hot.width  # (an observation as kept)
    q = make_network(configs, obs_dim, n_actions, seeds, "q-init")
    q_target = make_network(configs, obs_dim, n_actions, seeds, "q-init", trained=False)  # starts as q
    return AgentParts(
        q=q,
        q_target=q_target,
        h=make_network(configs, obs_dim, n_actions, seeds, "h-init"),
        replay=TransitionReplay(B, c.replay_size, width, coded=hot is not None),
        feedback_memory=FeedbackMemory(B, c.feedback_memory_size, width, coded=hot is not None),
        history=BatchStepHistory(B, c.history_steps, width),
        explorer=EpsilonGreedy(configs, _keys(seeds, "explore"), n_actions),
        mixture=Mixture(configs),
        delays=TeacherDelays(configs, step_unit),
        q_draws=UniformBlocks(_keys(seeds, "q-replay"), c.batch_size),
        h_draws=UniformBlocks(_keys(seeds, "h-replay"), c.h_batch_size),
        hot=hot,
    )
