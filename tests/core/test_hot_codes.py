"""Taxi's one-hot observations kept as codes (common/agents/mlp.py `HotCodes`): the numpy MLP computes from the
codes exactly what it computes from the dense input, so an agent that keeps codes runs the same trials bit for bit."""

from dataclasses import replace
from typing import Any

import numpy as np
import pytest

from common.agents.mlp import HotCodes, with_ones
from common.agents.networks import HUBER_MEAN, FitJob, FlatRMSProp, StackedMLP, fit_together
from experiments import runner
from experiments.conditions import BY_NAME, FULL, trial_spec

WAYS = ("dense", "codes")


def one_hot(rng, m: int, groups=((0, 5), (5, 10), (10, 15), (15, 19), (19, 519))) -> np.ndarray:
    x = np.zeros((m, 519), np.float32)
    for lo, hi in groups:
        x[np.arange(m), rng.integers(lo, hi, m)] = 1.0
    return x


def test_codes_are_the_columns_set_then_the_bias_column():
    x = one_hot(np.random.default_rng(0), 6).reshape(2, 3, 519)
    codes = HotCodes(519, 5).encode(x)
    assert codes.shape == (2, 3, 6) and codes.dtype == np.float32
    for obs, c in zip(x.reshape(-1, 519), codes.reshape(-1, 6)):
        assert list(c) == [*np.flatnonzero(obs), 519]


@pytest.mark.parametrize("bad", ["two", "value", "missing"])
def test_an_observation_that_is_not_k_ones_is_refused(bad):
    x = one_hot(np.random.default_rng(1), 4)
    if bad == "two":
        x[1, 2] = x[1, 3] = 1.0
    elif bad == "value":
        x[2] *= 0.5
    else:
        x[3, :19] = 0.0
    with pytest.raises(ValueError, match="5 ones"):
        HotCodes(519, 5).encode(x)


def test_the_mlp_on_codes_is_the_mlp_on_the_dense_input_bit_for_bit():
    rng = np.random.default_rng(2)
    hot = HotCodes(519, 5)
    nets: dict[str, Any] = {
        how: StackedMLP(519, 100, 6, [3, 4, 5], FlatRMSProp(), hot if how == "codes" else None) for how in WAYS
    }
    rows = np.array([0, 2])
    for _ in range(3):
        x = one_hot(rng, 2 * 32).reshape(2, 32, 519)
        act, target = rng.integers(0, 6, (2, 32)), rng.standard_normal((2, 32)).astype(np.float32)
        for how, net in nets.items():
            x_in, x1 = (hot.encode(x), None) if how == "codes" else (x, with_ones(x))
            fit_together([FitJob(net, rows, x_in, act, target, None, HUBER_MEAN, x1)])
    assert np.array_equal(nets["codes"].flat, nets["dense"].flat)
    assert np.array_equal(nets["codes"].opt.square_avg, nets["dense"].opt.square_avg)
    x = one_hot(rng, 3 * 7).reshape(3, 7, 519)
    assert np.array_equal(nets["codes"].values(None, hot.encode(x)), nets["dense"].values(None, x))


def test_taxi_trials_kept_as_codes_are_the_dense_trials_bit_for_bit(monkeypatch):
    arms = ("dqn-rs", "dqn-tamer", "dqn-tamer/learned")  # (shaping, credit on the step clock, in seconds)
    specs = [replace(trial_spec(BY_NAME["taxi-stop"], arm, 0, FULL), episodes=1) for arm in arms]
    real, kept = runner.make_agent, []

    def spy(*args, **kw):
        agent = real(*args, **kw)
        kept.append(agent.hot is not None)
        return agent

    monkeypatch.setattr(runner, "make_agent", spy)
    coded = runner.run_trials(specs, record_actions=True)
    monkeypatch.setattr(runner, "make_agent", lambda *a, **kw: spy(*a, **{**kw, "hot_inputs": None}))
    dense = runner.run_trials(specs, record_actions=True)
    assert kept == [True, False]
    assert sum(r.total_steps for r in coded) > 500
    for a, b in zip(coded, dense):
        assert a.episodes == b.episodes and a.actions == b.actions and a.delay == b.delay
        assert a.weights.keys() == b.weights.keys()
        assert all(np.array_equal(a.weights[k], b.weights[k]) for k in a.weights)
