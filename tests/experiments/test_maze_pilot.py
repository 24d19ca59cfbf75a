"""The maze horizon pilot: the report's flatness rule by checkpoint, and trials that are never the reproduction's."""

import numpy as np
import pytest

from experiments import maze_pilot
from experiments.conditions import BY_NAME, CONDITIONS, FULL, n_trials, trial_spec


def test_pilot_trials_are_never_the_reproductions():
    repro = {
        (s.layout, s.seed)
        for c in CONDITIONS
        if not c.is_taxi
        for k in range(n_trials(c, FULL))
        for s in [trial_spec(c, "dqn" if "dqn" in c.arms else c.arms[0], k, FULL)]
    }
    repro_seeds = {seed for _, seed in repro}
    for name in maze_pilot.DEFAULT_CONDITIONS:
        got = maze_pilot.specs(BY_NAME[name], 5)
        assert not {s.seed for _, s in got} & repro_seeds
        assert {arm for arm, _ in got} == set(BY_NAME[name].arms)  # every arm: the cost covers the grid
    # the learned-delay conditions' pilot layouts are honest and outside their reproduction set
    delay = {s.layout for _, s in maze_pilot.specs(BY_NAME["delay-late"], 5)}
    repro_delay = {
        trial_spec(BY_NAME["delay-late"], "dqn-tamer/true", k, FULL).layout
        for k in range(n_trials(BY_NAME["delay-late"], FULL))
    }
    assert delay and all(L % 2 == 0 for L in delay) and not delay & repro_delay
    # a drifting observer drifts over the pilot's own length
    assert {s.observer.drift_episodes for _, s in maze_pilot.specs(BY_NAME["delay-drift"], 150)} == {150}
    with pytest.raises(SystemExit):
        maze_pilot.cli(["--seed0", "5"])
    with pytest.raises(SystemExit):
        maze_pilot.cli(["--conditions", "taxi-stop"])


def test_flatness_by_checkpoint_on_known_curves():
    E = 100
    slow = np.full((3, E), 200.0)
    slow[:, :] = np.exp(np.linspace(np.log(200), np.log(20), E))[None, :]  # still falling everywhere
    fast = np.full((3, E), 400.0)
    fast[:, 65:] = 10.0  # best from checkpoint 80; flat over its last 20 from checkpoint 90
    rows = maze_pilot.flat_by_episodes({"dqn": slow, "dqn-tamer": fast}, None)
    assert [r["episodes"] for r in rows] == [60, 70, 80, 90, 100]
    assert [r["best_arm"] for r in rows] == ["dqn", "dqn", "dqn-tamer", "dqn-tamer", "dqn-tamer"]
    assert [r["flat"] for r in rows] == [False, False, False, True, True]
    assert maze_pilot.flat_from(rows) == 90
    assert maze_pilot.flat_from([{"episodes": 60, "flat": True}, {"episodes": 70, "flat": False}]) is None
    assert maze_pilot.flat_from([{"episodes": 60, "flat": True}, {"episodes": 70, "flat": True}]) == 60
