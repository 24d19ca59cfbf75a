"""The task's `info` reaches the teacher rule whole: live (`python -m services up`) as in process.

Every registered rule, and a user's rule (`module:function`) that reads a key the project never names, gives the
same feedback live and in the in-process runner on the same seed. The comparison: DQN (feedback changes no
action, so both sides take the same actions, tests/services/test_live.py) with an observer that reacts to every
step and never flips (p_feedback 1, p_flip 0: each reaction's value is the rule's value), so the feedback sequence
is the rule's value on every step, each at the time its lag puts it. Both sides draw the lags from the same seeded
observer, so the sequences of (stamp on the step clock, value) must be equal: the live stamps are placed back on
the step clock from the Steps' action times (a reaction to step k with lag d lands between actions k+d and
k+d+1: k+d+0.5), exactly as the runner stamps the reactions it delivers.

A rule that raises, and an env `info` key a Step cannot carry, stop the run at once with an error naming them (no
restart: it would fail the same way).
"""

from __future__ import annotations

import bisect
import json
from typing import Any

import pytest

from common.envs import RULES
from common.logs.mcap_log import load_log
from common.protocol import Feedback, Step

from .live import assert_nothing_left, start_up

pytestmark = pytest.mark.live

USER = "tests.services.info_rule"
SEED = 3
MAX_STEPS = 120
FLAGS = (
    "--algo",
    "dqn",
    "--max-ahead",
    "0",
    "--observer.p-feedback",
    "1",
    "--observer.p-flip",
    "0",
    "--max-steps",
    str(MAX_STEPS),
    "--episodes",
    "20",
    "--seed",
    str(SEED),
)
CASES = [("maze", rule) for rule in RULES] + [(f"{USER}:checker_maze", f"{USER}:dark_square_rule")]


def live_feedback(rundir) -> tuple[list[tuple[float, int]], int, int, dict]:
    """The live run's feedback as (stamp on the step clock, value), in the order sent; its step and episode
    counts; its teacher's observer settings."""
    records, status = load_log(rundir / "session.mcap")
    assert status.complete
    steps = [r.message for r in records if isinstance(r.message, Step)]
    assert [s.seq for s in steps] == list(range(len(steps)))
    t_actions = [s.t_action for s in steps]
    feedback = sorted((r.message for r in records if isinstance(r.message, Feedback)), key=lambda f: f.seq)
    stamped = [(bisect.bisect_left(t_actions, f.t_reaction) - 1 + 0.5, f.value) for f in feedback]
    observer = json.loads((rundir / "config" / "run.json").read_text())["services"]["teacher.oracle"]["observer"]
    return stamped, len(steps), steps[-1].episode + 1, observer


def in_process_feedback(env: str, rule: str, observer: dict, n_steps: int, episodes: int) -> list[tuple[float, int]]:
    """The in-process runner's feedback (stamp, value) in the order delivered, up to what a live run of
    `n_steps` steps can send (stamps before its last action)."""
    from common.agents import agent_config
    from common.core.observer import ObserverConfig
    from experiments.runner import TrialSpec, run_trials

    fields: dict[str, Any] = {k: tuple(v) if isinstance(v, list) else v for k, v in observer.items()}
    obs_cfg = ObserverConfig(**fields)
    seen: list[tuple[float, int]] = []

    def on_input(_trial: int, kind: str, record: dict) -> None:
        if kind == "feedback" and record["t"] < n_steps - 1:
            seen.append((record["t"], record["value"]))

    run_trials([TrialSpec(env, agent_config("dqn"), obs_cfg, SEED, 0, episodes, teacher_rule=rule)], on_input=on_input)
    return seen


@pytest.mark.parametrize("env,rule", CASES, ids=[rule.rpartition(":")[2] for _, rule in CASES])
def test_every_rule_gives_the_same_feedback_live_and_in_process(tmp_path, env, rule):
    launch = start_up(tmp_path, "info", "--env", env, "--teacher-rule", rule, *FLAGS)
    try:
        assert launch.wait(timeout=240) == 0, launch.out
        live, n_steps, episodes, observer = live_feedback(launch.rundir)
    finally:
        assert_nothing_left(launch.rundir)
    assert n_steps == MAX_STEPS
    assert observer["p_feedback"] == 1.0 and observer["p_flip"] == 0.0
    ref = in_process_feedback(env, rule, observer, n_steps, episodes)
    # every step but the last few (whose reactions fall after the last action) got its reaction
    assert len(ref) >= n_steps - len(observer["delay_probs"]) - 1
    assert live == ref
    if rule.endswith("dark_square_rule"):
        assert {v for _, v in live} == {1, -1}  # the user's key was read: both answers occur


def test_a_rule_that_raises_stops_the_run_with_its_name_and_error(tmp_path):
    launch = start_up(tmp_path, "broken", "--teacher-rule", f"{USER}:broken_rule", *FLAGS)
    try:
        assert launch.wait(timeout=240) != 0
    finally:
        assert_nothing_left(launch.rundir)
    summary = launch.summary()
    assert summary["outcome"] == "failed"
    assert summary["restarts"] == []  # stopped at once, not restarted three times
    assert f"teacher rule '{USER}:broken_rule' failed" in summary["error"]
    assert "ZeroDivisionError" in summary["error"] and "ZeroDivisionError" in launch.out


def test_an_info_key_a_step_cannot_carry_stops_the_run_naming_it(tmp_path):
    launch = start_up(tmp_path, "label", "--env", f"{USER}:labelled_maze", *FLAGS)
    try:
        assert launch.wait(timeout=240) != 0
    finally:
        assert_nothing_left(launch.rundir)
    summary = launch.summary()
    assert summary["outcome"] == "failed" and summary["restarts"] == []
    assert "env info key 'label'" in summary["error"] and "not a number" in summary["error"]
