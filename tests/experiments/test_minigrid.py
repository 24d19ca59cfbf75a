"""A task with pictures: MiniGrid's 7x7x3 view, the default CNN, the grid-world progress rule; DQN-TAMER
(feedback) learns it in fewer steps than DQN (none) on the in-process runner."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import mannwhitneyu

from common.agents import agent_config, make_agent
from common.agents.torch_net import GridCNN
from common.envs import make_env, obs_shape
from experiments.minigrid import compare


def test_minigrid_task_has_image_observations_a_rule_and_a_cnn():
    env, rule = make_env("minigrid-empty")
    assert obs_shape(env) == (7, 7, 3) and env.action_space.n == 3
    obs, _ = env.reset(seed=0)
    _, _, _, _, info = env.step(2)  # forward, towards the goal from the start
    assert rule(info) == 1 and info["target_distance_after"] < info["target_distance_before"]
    agent = make_agent([agent_config("dqn-tamer")], obs_shape(env), 3, [0])
    assert isinstance(agent.q.modules[0], GridCNN)


@pytest.mark.slow
def test_cnn_learns_minigrid_faster_with_feedback_than_without():
    data = compare("minigrid-empty", seeds=6, episodes=15)
    fb = np.asarray(data["dqn-tamer"]["steps"], float)
    no = np.asarray(data["dqn"]["steps"], float)
    msg = f"steps per episode, with feedback {fb.mean(0).round(1)}, without {no.mean(0).round(1)}"
    p = mannwhitneyu(fb.mean(1), no.mean(1), alternative="less").pvalue
    assert p < 0.05, f"{msg}, p = {p:.3f}"
    assert fb[:, -5:].mean() < 20 < fb[:, :2].mean(), msg  # it learns: from ~80 steps to the goal to < 20
