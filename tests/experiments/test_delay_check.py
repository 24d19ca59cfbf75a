"""The closed-loop recovery check of the learned delay (experiments/delay_check.py), by its declared rule: four
simulated people of known delay teach DQN-TAMER on the maze, which learns their delay in seconds while it learns
from their feedback; after 200 presses each learned median is within 15% of the true one (the drifting person's
within 20%)."""

import json

from experiments.delay_check import PEOPLE, DelayCheckConfig, delay_check, main


def test_the_learned_delay_recovers_four_people_in_the_closed_loop():
    results = delay_check(DelayCheckConfig())
    assert [r["person"] for r in results] == list(PEOPLE)
    for r in results:
        assert r["presses"] >= 200, r
        tolerance = 0.2 if r["late_delay_s"] else 0.15
        assert abs(r["learned_median_s"] - r["true_median_s"]) <= tolerance * r["true_median_s"], r
        assert r["passed"], r


def test_the_command_writes_its_rule_and_results(tmp_path, capsys):
    out = tmp_path / "check.json"
    assert main(DelayCheckConfig(people=("gamma",), out=str(out))) == 0
    data = json.loads(out.read_text())
    assert data["rule"].startswith("each person") and data["results"][0]["person"] == "gamma"
    assert "gamma" in capsys.readouterr().out
