"""The SB3 anchor's project rows measure this checkout's DQN on the maze; a bad row name is a clear error.
(Stable-Baselines3 itself is not a dependency: its row runs only where a user installed it.)"""

from __future__ import annotations

import pytest

from experiments import sb3_anchor


def test_project_rows_count_the_trials_steps():
    plain = sb3_anchor.project_rate(1, 2, 120)
    batched = sb3_anchor.project_rate(3, 2, 120)
    assert (plain["who"], batched["who"]) == ("plain", "batched")
    assert 0 < plain["steps"] < batched["steps"]
    assert batched["steps_per_cpu_s"] > 0


def test_a_bad_row_is_named():
    with pytest.raises(SystemExit, match="--here must be sb3, plain or batched"):
        sb3_anchor.main(["--here", "sb4"])
