"""The in-process pilot of the console comparison: its measures, its seeds, and a small run."""

import pytest

from common.envs.maze import LAYOUT_COUNT
from experiments import console_pilot as cp
from experiments.taxi_pilot import PILOT_SEED0


def test_measures_score_the_tenth_goal_the_first_near_shortest_episode_and_the_steps():
    steps = [200, 12] + [5] * 13
    reached = [False] + [True] * 14
    m = cp.measures(steps, reached, shortest=5)
    assert m == {"goals": 11, "first_good": 3, "steps": 277}  # 12 > 2 x 5: not near the shortest path
    short = cp.measures([200] * 15, [False] * 15, shortest=5)
    assert short == {"goals": 15 + 10, "first_good": 16, "steps": 3000}


def test_a_small_pilot_runs_every_arm_on_pilot_seeds_with_episodes_cut_at_200(capsys):
    out = cp.run(["dqn", "dqn-tamer/matched"], trials=2, layouts=(0,))
    assert set(out) == {"dqn", "dqn-tamer/matched"} and all(len(rows) == 2 for rows in out.values())
    assert all(r["steps"] <= cp.EPISODES * cp.EPISODE_STEPS for rows in out.values() for r in rows)
    cp.summary(out)
    assert "dqn-tamer/matched" in capsys.readouterr().out
    assert PILOT_SEED0 >= 9000  # never a browser design's seed (tests/console/test_compare.py checks them)


def test_bad_settings_are_one_line_errors():
    with pytest.raises(ValueError, match="unknown arm"):
        cp.ConsolePilotConfig(arms=("dqn-tamer/nope",))
    with pytest.raises(ValueError, match="layouts"):
        cp.ConsolePilotConfig(layouts=(LAYOUT_COUNT,))
