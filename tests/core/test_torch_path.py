"""The torch path: Q and H as torch modules trained with autograd and torch.optim (common/agents/torch_*.py)."""

from __future__ import annotations

import sys
import textwrap

import numpy as np
import pytest
import torch

from common.agents import agent_config, make_agent
from common.agents.networks import StackedMLP
from common.agents.torch_net import TorchValueNetworks
from common.agents.torch_agent import check_agent
from common.envs import make_env
from common.core.observer import ObserverConfig
from common.agents.agent import StepLoop
from experiments.runner import TrialSpec, run_trials

torch.set_num_threads(1)  # as the runner and the services run it (threads only contend at these sizes)


def _drive(agent, rng_seed: int, steps: int, obs_dim: int, n_actions: int, t0: int = 0) -> None:
    """The same inputs for any agent: random transitions of 3 trials, feedback now and then."""
    rng = np.random.default_rng(rng_seed)
    loop = StepLoop(agent)
    rows = np.arange(agent.B)
    for t in range(t0, t0 + steps):
        obs = rng.random((agent.B, obs_dim), dtype=np.float32)
        nxt = rng.random((agent.B, obs_dim), dtype=np.float32)
        give = rng.random(agent.B) < 0.5
        if give.any():
            k = rows[give]
            loop.credit(k, np.full(len(k), t - 0.5), rng.choice([-1, 1], len(k)))
        loop.step(
            rows,
            obs,
            rng.integers(0, n_actions, agent.B),
            rng.normal(size=agent.B).astype(np.float32),
            nxt,
            rng.random(agent.B) < 0.05,
            np.full(agent.B, float(t)),
            np.zeros(agent.B, np.int64),
        )


@pytest.mark.parametrize("algo", ["dqn-tamer", "dqn-rs", "deep-tamer"])
def test_mlp_numpy_and_torch_paths_give_the_same_updates(algo):
    obs_dim, n_actions, seeds = 5, 4, [3, 4, 5]
    fast = make_agent([agent_config(algo, network="mlp", target_update_interval=25)] * 3, obs_dim, n_actions, seeds)
    slow = make_agent(
        [agent_config(algo, network="torch-mlp", target_update_interval=25)] * 3, obs_dim, n_actions, seeds
    )
    assert isinstance(fast.q, StackedMLP) and isinstance(slow.q, TorchValueNetworks)
    for i in range(3):  # same initial weights
        for k, v in slow.policy_weights(i).items():
            assert np.array_equal(v, fast.policy_weights(i)[k]), k
    _drive(fast, 9, 120, obs_dim, n_actions)
    _drive(slow, 9, 120, obs_dim, n_actions)
    assert (fast.q_updates == slow.q_updates).all() and (fast.h_updates == slow.h_updates).all()
    assert fast.q_updates.sum() + fast.h_updates.sum() > 100
    for i in range(3):
        a, b = fast.policy_weights(i), slow.policy_weights(i)
        for k in a:
            np.testing.assert_allclose(b[k], a[k], rtol=0, atol=2e-5, err_msg=k)
        start = make_agent([agent_config(algo)], obs_dim, n_actions, [seeds[i]]).policy_weights(0)
        moved = max(float(np.abs(a[k] - start[k]).max()) for k in a)
        assert moved > 1e-3  # they learned something, and learned it alike


def test_mlp_paths_act_alike_in_the_runner():
    specs = [
        TrialSpec("maze", agent_config("dqn-tamer", network=net), ObserverConfig(), 1, 2, 2)
        for net in ("mlp", "torch-mlp")
    ]
    fast, slow = (run_trials([s], record_actions=True)[0] for s in specs)
    assert fast.actions == slow.actions and fast.returns.tolist() == pytest.approx(slow.returns.tolist())


def test_lr_reaches_both_optimisers():
    fast = make_agent([agent_config("dqn-tamer", lr=5e-4)], 2, 4, [0])
    assert fast.q.opt.lr == np.float32(5e-4) and fast.h.opt.lr == np.float32(5e-4)
    slow = make_agent([agent_config("dqn-tamer", lr=5e-4, network="torch-mlp")], 2, 4, [0])
    assert {g["lr"] for o in slow.q.opts + slow.h.opts for g in o.param_groups} == {5e-4}


def test_a_users_module_factory_is_trained(tmp_path, monkeypatch):
    (tmp_path / "usernet.py").write_text(
        textwrap.dedent("""
        import torch
        from torch import nn

        def two_layers(obs_shape, n_actions, hidden):
            size = 1
            for s in obs_shape:
                size *= s
            return nn.Sequential(nn.Linear(size, 16), nn.ELU(), nn.Linear(16, n_actions))
    """)
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    sys.modules.pop("usernet", None)
    agent = make_agent([agent_config("dqn-tamer", network="usernet:two_layers")], 6, 3, [1])
    before = {k: v.copy() for k, v in agent.policy_weights(0).items()}
    assert set(before) == {
        "q.0.weight",
        "q.0.bias",
        "q.2.weight",
        "q.2.bias",
        "h.0.weight",
        "h.0.bias",
        "h.2.weight",
        "h.2.bias",
    }
    _drive(agent, 2, 60, 6, 3)
    after = agent.policy_weights(0)
    assert all(not np.array_equal(before[k], after[k]) for k in before)


def test_bad_networks_are_one_line_errors():
    env, _ = make_env("maze")
    with pytest.raises(ValueError, match="cnn needs image observations"):
        check_agent(agent_config("dqn", network="cnn"), env)
    with pytest.raises(ValueError, match="network factory 'json:nope'"):
        agent_config("dqn", network="json:nope")
    with pytest.raises(ValueError, match="unknown network 'resnet'"):
        agent_config("dqn", network="resnet")


def test_image_observations_get_a_cnn_by_default():
    env, _ = make_env("minigrid-empty")
    agent = make_agent([agent_config("dqn-tamer")], (7, 7, 3), env.action_space.n, [0])
    assert isinstance(agent.q, TorchValueNetworks) and type(agent.q.modules[0]).__name__ == "GridCNN"
    weights = agent.policy_weights(0)
    other = make_agent([agent_config("dqn-tamer")], (7, 7, 3), env.action_space.n, [0])
    other.load_policy_weights(weights)  # what the actor does with the learner's weights
    obs = env.reset(seed=0)[0]
    assert agent.greedy_action(0, obs) == other.greedy_action(0, obs)


def test_torch_state_survives_the_learners_checkpoint(tmp_path):
    from services.learner import checkpoint

    def agent():
        return make_agent([agent_config("dqn-tamer", network="torch-mlp")], 5, 4, [7])

    a = agent()
    _drive(a, 3, 60, 5, 4)
    checkpoint.save(tmp_path / "c.ckpt", a.state_dict(), {})
    b = agent()
    b.load_state_dict(checkpoint.load(tmp_path / "c.ckpt")[0])
    _drive(a, 4, 30, 5, 4, t0=60)
    _drive(b, 4, 30, 5, 4, t0=60)  # same inputs after the restore: same weights (optimiser state included)
    for k, v in a.policy_weights(0).items():
        np.testing.assert_array_equal(v, b.policy_weights(0)[k], err_msg=k)


def test_bench_prints_both_paths_side_by_side(capsys):
    from experiments.__main__ import main

    assert main(["bench", "--paths-only", "--trials", "1", "--episodes", "1"]) == 0
    out = capsys.readouterr().out
    assert "numpy MLP (fast path)" in out and "torch MLP (autograd + optim)" in out and "numpy / torch: x" in out
