"""The Taxi pilot: the report's convergence rule, and seeds that are never the reproduction's."""

import numpy as np
import pytest

from experiments import taxi_pilot
from experiments.conditions import BY_NAME, FULL, n_trials, trial_spec


def test_convergence_rule_on_known_curves():
    steps = np.full((2, 100), 1000.0)
    steps[0, 40:] = 15.0
    steps[1, 60:] = 15.0
    got = taxi_pilot.convergence(steps)
    assert got["converged"] and got["flat"] and abs(got["final_steps_geomean"] - 15.0) < 1e-9
    # the first 5-episode window entirely at the final level is episodes 61-65 (1-based): counted to its end
    assert got["within_margin_episode"] == 65
    assert got["steps_to_level_mean"] == pytest.approx((40 * 1000 + 25 * 15 + 60 * 1000 + 5 * 15) / 2)
    assert got["trial_median_below_100_from_episode"] == [46, 66]  # the 10-episode median drops at 40+6, 60+6
    never = taxi_pilot.convergence(np.full((2, 50), 1000.0))
    assert never["flat"] and not never["converged"] and never["trial_median_below_100_from_episode"] == [None, None]


def test_pilot_seeds_and_tasks_are_not_the_reproductions():
    pilot = taxi_pilot.specs("taxi-s", 5, 6, {})
    fixed = taxi_pilot.specs("taxi-fixed-s", 5, 6, {})
    repro = {
        trial_spec(BY_NAME[c], "dqn", k, FULL).seed
        for c in ("taxi-stop", "taxi-fixed-stop")
        for k in range(n_trials(BY_NAME[c], FULL))
    }
    assert not {s.seed for s in pilot + fixed} & repro
    assert [s.layout for s in fixed] == [3, 8, 1, 6, 11, 4]  # another order of the 12 tasks
    with pytest.raises(SystemExit):
        taxi_pilot.cli(["--seed0", "5"])
    with pytest.raises(SystemExit):
        taxi_pilot.cli(["--set", "no_such_field=1", "--episodes", "1", "--trials", "1"])


def test_set_takes_several_fields_and_values_that_hold_commas():
    from common.config import parse_config

    cfg = parse_config(taxi_pilot.TaxiPilotConfig, ["--set", "replay_size=50000,assumed_delay_probs=0.3,0.6,0.1"])
    assert cfg.changes == {"replay_size": 50000, "assumed_delay_probs": "0.3,0.6,0.1"}
    (spec,) = taxi_pilot.specs("taxi-s", 1, 1, cfg.changes)
    assert spec.agent.assumed_delay_probs == (0.3, 0.6, 0.1) and spec.agent.replay_size == 50000
