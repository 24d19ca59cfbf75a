"""Step.info from an env's `info`: every key whole, or an error naming the key a Step cannot carry."""

from __future__ import annotations

import numpy as np
import pytest

from common.envs import make_env
from common.protocol import InfoError, Step, step_info


def test_every_numeric_key_is_kept_as_a_float():
    info = {"a": 1, "b": np.float32(2.5), "c": True, "d": np.int64(-3)}
    assert step_info(info) == {"a": 1.0, "b": 2.5, "c": 1.0, "d": -3.0}


@pytest.mark.parametrize(
    "info,named",
    [
        ({"ok": 1.0, "label": "corridor"}, "'label'"),
        ({"gap": float("nan")}, "'gap'"),
        ({"far": float("inf")}, "'far'"),
        ({"none": None}, "'none'"),
        ({"vec": [1.0, 2.0]}, "'vec'"),
        ({"x" * 65: 1.0}, "'xxxx"),
        ({"": 1.0}, "''"),
        ({f"k{i}": float(i) for i in range(18)}, "'k16', 'k17' cannot be sent"),
    ],
)
def test_a_key_that_cannot_be_sent_is_named(info, named):
    with pytest.raises(InfoError) as err:
        step_info(info)
    assert named in str(err.value)


def test_the_maze_info_travels_whole_in_a_step():
    env, rule = make_env("maze", 0, "shortest-path")
    env.reset(seed=0)
    info = env.step(0)[4]
    sent = step_info(info)
    step = Step(
        run="r",
        incarnation="a-1",
        seq=0,
        t_action=1.0,
        episode=0,
        t_in_episode=0,
        obs=[0.0, 0.0],
        action=0,
        reward=-0.01,
        next_obs=[0.0, 0.0],
        terminated=False,
        truncated=False,
        weights_version=0,
        info=sent,
    )
    received = Step.decode(step.encode())
    assert isinstance(received, Step)
    assert received.info == info and {"path_distance_after", "reward"} <= set(received.info)
    assert rule(received.info) == rule(info)
