import numpy as np
import pytest
import torch

from common.agents import AgentConfig, DeepTamerConfig, DQNConfig, DQNTamerConfig, TrialBatchAgent, agent_config
from common.agents.networks import FlatRMSProp
from common.core.observer import ObserverConfig
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
    specs = [
        TrialSpec("maze", agent_config(algo), DELAYED, seed=s, layout=s, episodes=3)
        for algo in ("dqn", "dqn-rs", "deep-tamer", "dqn-tamer")
        for s in (0, 5)
    ]
    batched = run_trials(specs, record_actions=True)
    for spec, res in zip(specs, batched):
        alone = run_trials([spec], record_actions=True)[0]
        assert res.actions == alone.actions, spec
        np.testing.assert_array_equal(res.returns, alone.returns)


def test_rmsprop_matches_torch_and_leaves_unselected_trials_alone():
    rng = np.random.default_rng(0)
    flat = rng.standard_normal((3, 7)).astype(np.float32)
    ref = torch.tensor(flat[1].copy(), requires_grad=True)
    ref_opt = torch.optim.RMSprop([ref], lr=1e-2, alpha=0.99, eps=1e-8)
    opt = FlatRMSProp(1e-2, 0.99, 1e-8)
    opt.attach(flat.shape)
    frozen = flat[[0, 2]].copy()
    for _ in range(20):
        grad = rng.standard_normal((1, 7)).astype(np.float32)
        opt.step_rows(flat, np.array([1]), grad)  # an index array: gathered, stepped, scattered back
        ref.grad = torch.from_numpy(grad[0].copy())
        ref_opt.step()
    np.testing.assert_allclose(flat[1], ref.detach().numpy(), rtol=1e-6, atol=1e-7)
    assert np.array_equal(flat[[0, 2]], frozen) and not opt.square_avg[[0, 2]].any()
    opt.step_rows(flat, slice(0, 2), np.ones((2, 7), np.float32))  # a slice: stepped in place
    assert np.array_equal(flat[2], frozen[1]) and not np.array_equal(flat[0], frozen[0])


def test_feedback_credit_and_shaping_paths():
    cfgs = [agent_config("dqn-tamer"), agent_config("dqn-rs"), agent_config("dqn")]
    agent = TrialBatchAgent(cfgs, obs_dim=2, n_actions=4, seeds=[0, 1, 2])
    for k in range(5):
        for i in range(3):
            agent.record_step(
                i, np.array([k, 0], np.float32), k % 4, -0.01, np.array([k + 1, 0], np.float32), False, float(k)
            )
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
    obs = np.array([[[0.1, 0.7]]], np.float32)
    assert np.array_equal(a.q.values(None, obs), b.q.values(None, obs))
    assert np.array_equal(a.h.values(None, obs), b.h.values(None, obs))
    bad = a.policy_weights()
    bad["q.w1"] = np.zeros((3, 100), np.float32)
    with pytest.raises(ValueError, match="shape"):
        b.load_policy_weights(bad)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"gamma": 1.5}, "gamma"),
        ({"batch_size": 0}, "batch_size"),
        ({"lr": -1.0}, "lr"),
        ({"assumed_delay_probs": (0.2, 0.2)}, "sum to 1"),
        ({"alpha_h": float("nan")}, "alpha_h"),
    ],
)
def test_agent_config_validation(kwargs, match):
    with pytest.raises(ValueError, match=match):
        AgentConfig(**kwargs)


def test_unknown_algo_and_mismatched_batch():
    with pytest.raises(ValueError, match="unknown algo"):
        agent_config("ppo")
    with pytest.raises(ValueError, match="share gamma"):
        TrialBatchAgent([AgentConfig(), AgentConfig(gamma=0.5)], 2, 4, [0, 1])
