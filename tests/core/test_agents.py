import numpy as np
import pytest
import torch

from common.agents import (AgentConfig, DeepTamerConfig, DQNConfig, DQNTamerConfig, TrialBatchAgent,
                           agent_config)
from common.agents.optim import MaskedRMSProp
from common.observer import ObserverConfig
from experiments.runner import TrialSpec, run_trials

DELAYED = ObserverConfig(p_feedback=0.5, delay_probs=(0.3, 0.6, 0.1))


def actions_of(agent_cfg, seed=3, layout=2, episodes=6, env="maze"):
    spec = TrialSpec(env, agent_cfg, DELAYED, seed=seed, layout=layout, episodes=episodes)
    result = run_trials([spec], record_actions=True)[0]
    return result.actions, result.returns


def test_dqn_tamer_with_alpha_h_zero_acts_exactly_like_dqn():
    a, ra = actions_of(DQNTamerConfig(alpha_h=0.0))
    b, rb = actions_of(DQNConfig())
    assert len(a) > 100 and a == b
    np.testing.assert_array_equal(ra, rb)


def test_dqn_tamer_with_alpha_q_zero_acts_exactly_like_deep_tamer():
    a, ra = actions_of(DQNTamerConfig(alpha_q=0.0))
    b, rb = actions_of(DeepTamerConfig())
    assert len(a) > 30 and a == b
    np.testing.assert_array_equal(ra, rb)


def test_the_presets_really_differ():
    dqn, _ = actions_of(DQNConfig())
    tamer, _ = actions_of(DQNTamerConfig())
    assert dqn != tamer


def test_one_trial_batched_acts_as_it_does_alone():
    specs = [TrialSpec("maze", agent_config(algo), DELAYED, seed=s, layout=s, episodes=3)
             for algo in ("dqn", "dqn-rs", "deep-tamer", "dqn-tamer") for s in (0, 5)]
    batched = run_trials(specs, record_actions=True)
    for spec, res in zip(specs, batched):
        alone = run_trials([spec], record_actions=True)[0]
        assert res.actions == alone.actions, spec
        np.testing.assert_array_equal(res.returns, alone.returns)


def test_masked_rmsprop_matches_torch_and_leaves_masked_trials_alone():
    torch.manual_seed(0)
    w = torch.randn(2, 3, 4, requires_grad=True)
    ref = w.detach()[0].clone().requires_grad_(True)
    opt = MaskedRMSProp({"w": w}, lr=1e-2)
    ref_opt = torch.optim.RMSprop([ref], lr=1e-2, alpha=0.99, eps=1e-8)
    frozen = w.detach()[1].clone()
    for _ in range(5):
        x = torch.randn(3)
        opt.zero_grad(); ref_opt.zero_grad()
        (w[0].T @ x).pow(2).sum().backward()
        (w[1].T @ x).pow(2).sum().backward()  # a gradient the mask must ignore
        (ref.T @ x).pow(2).sum().backward()
        opt.step(torch.tensor([True, False]))
        ref_opt.step()
    torch.testing.assert_close(w.detach()[0], ref.detach(), rtol=1e-5, atol=1e-6)
    assert torch.equal(w.detach()[1], frozen)


def test_feedback_credit_and_shaping_paths():
    cfgs = [agent_config("dqn-tamer"), agent_config("dqn-rs"), agent_config("dqn")]
    agent = TrialBatchAgent(cfgs, obs_dim=2, n_actions=4, seeds=[0, 1, 2])
    for k in range(5):
        for i in range(3):
            agent.record_step(i, np.array([k, 0], np.float32), k % 4, -0.01, np.array([k + 1, 0], np.float32),
                              False, float(k))
    out = agent.give_feedback([(0, 4.5, 1), (1, 4.5, -1), (2, 4.5, 1)])
    assert [o.status for o in out] == ["credited", "credited", "ignored"]
    assert out[0].steps == 3 and agent.feedback_memory.size[0] == 3 and agent.h_updates[0] == 1
    assert agent.replay.data["reward"][1, 4] == pytest.approx(-1.01)  # shaping hits the newest step
    stale = agent.give_feedback([(0, -5.0, 1)])
    assert stale[0].status == "stale"
    with pytest.raises(ValueError, match="-1 or \\+1"):
        agent.give_feedback([(0, 4.5, 2)])


def test_policy_weights_round_trip_and_shape_check():
    a = TrialBatchAgent([agent_config("dqn-tamer")], 2, 4, [0])
    b = TrialBatchAgent([agent_config("dqn-tamer")], 2, 4, [99])
    b.load_policy_weights(a.policy_weights())
    obs = np.array([[0.1, 0.7]], np.float32)
    assert torch.equal(a.scores(obs), b.scores(obs))
    bad = a.policy_weights()
    bad["q.w1"] = torch.zeros(3, 100)
    with pytest.raises(ValueError, match="shape"):
        b.load_policy_weights(bad)


@pytest.mark.parametrize("kwargs, match", [
    ({"gamma": 1.5}, "gamma"), ({"batch_size": 0}, "batch_size"), ({"lr": -1.0}, "lr"),
    ({"assumed_delay_probs": (0.2, 0.2)}, "sum to 1"), ({"alpha_h": float("nan")}, "alpha_h")])
def test_agent_config_validation(kwargs, match):
    with pytest.raises(ValueError, match=match):
        AgentConfig(**kwargs)


def test_unknown_algo_and_mismatched_batch():
    with pytest.raises(ValueError, match="unknown algo"):
        agent_config("ppo")
    with pytest.raises(ValueError, match="share gamma"):
        TrialBatchAgent([AgentConfig(), AgentConfig(gamma=0.5)], 2, 4, [0, 1])
