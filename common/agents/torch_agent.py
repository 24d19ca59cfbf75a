"""Choosing the agent's value networks: the paper's numpy MLP (`networks.StackedMLP`, the fast path) or
torch modules (`torch_net.TorchValueNetworks`) behind the same `ValueNetworks` interface, so everything else
(replay, D_global, credit, exploration streams, schedules, minibatch draws) is the same on either path. On the
paper's MLP (`--agent.network torch-mlp`) the two paths give the same updates (tests/core/test_torch_path.py).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from common.agents.agent import TrialBatchAgent
from common.agents.build import build_parts, hot_codes
from common.agents.config import AgentConfig, resolve_network
from common.core.seeding import derive_seed

if TYPE_CHECKING:  # torch is imported only for a torch network (its import costs a service ~1.3 s of CPU)
    from common.agents.torch_net import TorchValueNetworks


def torch_networks(
    configs: list[AgentConfig],
    obs_shape: tuple[int, ...],
    n_actions: int,
    seeds: list[int],
    purpose: str,
    trained: bool = True,
) -> TorchValueNetworks:
    """One module per trial of `configs[0].network` (seeded by `purpose`), with RMSprop if trained."""
    from common.agents.torch_net import TorchValueNetworks, build_modules

    c = configs[0]
    check_device(c.device)
    modules = build_modules(
        resolve_network(c.network, obs_shape), obs_shape, n_actions, c.hidden, [derive_seed(s, purpose) for s in seeds]
    )
    return TorchValueNetworks(modules, n_actions, c.lr if trained else None, c.rmsprop_alpha, c.rmsprop_eps, c.device)


def check_device(device: str) -> None:
    """A one-line ValueError for a device torch does not know or this machine does not have."""
    import torch

    try:
        dev = torch.device(device)
    except RuntimeError as exc:
        raise ValueError(f"device {device!r}: {exc}") from None
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise ValueError(f"device {device!r}: CUDA is not available on this machine")


def make_agent(
    configs: list[AgentConfig],
    obs_shape: tuple[int, ...] | int,
    n_actions: int,
    seeds: list[int],
    step_unit: float = 1.0,
    hot_inputs: int | None = None,
) -> TrialBatchAgent:
    """The agent for `configs` (one per trial; they share their network): numpy MLP for `mlp` (and `auto`
    on flat observations), torch modules for anything else (`cnn`, `torch-mlp`, `module:factory`).
    hot_inputs: every observation is that many ones among zeros (Taxi's one-hot groups): the numpy MLP with a
    wide first layer then keeps observations as codes (`build.hot_codes`; the same numbers, less memory)."""
    shape = (int(obs_shape),) if isinstance(obs_shape, (int, np.integer)) else tuple(int(s) for s in obs_shape)
    obs_dim = int(np.prod(shape))
    numpy_mlp = resolve_network(configs[0].network, shape) == "mlp"
    hot = hot_codes(obs_dim, hot_inputs, configs[0].hidden) if numpy_mlp else None
    parts = build_parts(configs, obs_dim, n_actions, seeds, step_unit, hot=hot)
    if not numpy_mlp:
        parts.q = torch_networks(configs, shape, n_actions, seeds, "q-init")
        parts.q_target = torch_networks(configs, shape, n_actions, seeds, "q-init", trained=False)
        parts.h = torch_networks(configs, shape, n_actions, seeds, "h-init")
    return TrialBatchAgent(configs, obs_dim, n_actions, seeds, step_unit, parts=parts)


def check_agent(config: AgentConfig, env) -> None:
    """Raise the one-line ValueError that building `config`'s networks for `env` would (a CNN on flat
    observations, a factory that fails or returns the wrong shape), before a run starts."""
    from common.envs import obs_shape

    shape = obs_shape(env)
    name = resolve_network(config.network, shape)
    if name != "mlp":
        from common.agents.torch_net import build_modules

        check_device(config.device)
        build_modules(name, shape, int(env.action_space.n), config.hidden, [0])
