"""A press changes the very next action: a person's press credited between steps m and m+1 reaches the actor's
choice at step m+1, not m+2 (issue 24).

A scripted person presses in Chromium on the console page of a live `services up --teacher web` run (actor,
learner, recorder and console as processes over Zenoh on loopback, idle-time updates on as for every person).
From the recorded log: every press credited at least `SLACK` s before an action was acted on by that action,
i.e. the action's `Step.weights_revision` covers the press's H update (`Credit.revision`). `SLACK` is the time
the new weights need to reach the actor (publish, carry, check, decode); a press credited closer to the action
than that may wait one more step. The log's weights revisions are checked to say something: the action before
the credit did not have it, and the learner's revisions move between steps (the idle updates and presses).
"""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from common.logs.mcap_read import read_log
from common.protocol import Credit, Step

from tests.services.live import ROOT, env

from .harness import WebRun, scripted_person

pytestmark = [pytest.mark.live, pytest.mark.browser]

RATE = 4.0  # steps per second: 250 ms between two actions, most presses credited well before the next one
SLACK = 0.1  # s from the learner's credit to the new weights held by the actor


def log_of(rundir):
    steps, credits = [], []
    for rec in read_log(rundir / "session.mcap"):
        m = rec.message
        if isinstance(m, Step):
            steps.append(m)
        elif isinstance(m, Credit) and m.teacher_id == "web-1" and m.status == "credited":
            credits.append(m)
    return sorted(steps, key=lambda s: s.seq), credits


def test_a_press_credited_before_the_next_action_is_acted_on_by_it(tmp_path):
    run = WebRun(
        tmp_path,
        "next",
        "--env",
        "maze",
        "--layout",
        "0",
        "--algo",
        "dqn-tamer",
        "--episodes",
        "50",
        "--episode-steps",
        "30",
        "--max-steps",
        "120",
        "--rate",
        str(RATE),
        "--seed",
        "3",
    )
    scripted_person(run, tmp_path / "profile", "{p: 0.7, lagMin: 0.3, lagMax: 1.0, seed: 5}")

    steps, credits = log_of(run.rundir)
    assert len(steps) == 120 and len({s.incarnation for s in steps}) == 1
    revisions = [s.weights_revision for s in steps]
    assert None not in revisions[5:] and all(a <= b for a, b in zip(revisions[5:], revisions[6:]))
    assert len(credits) >= 40 and all(c.revision is not None for c in credits)
    checked, late = 0, []
    for c in credits:
        nxt = next((s for s in steps if s.t_action > c.t_credited), None)
        if nxt is None or nxt.t_action - c.t_credited < SLACK:
            continue  # the run ended first, or the credit came too close to the action to reach it
        before = [s for s in steps if s.t_action < c.t_credited]
        assert before and before[-1].weights_revision < c.revision  # the action before could not have it
        if nxt.weights_revision < c.revision:
            late.append(f"press {c.seq} credited {nxt.t_action - c.t_credited:.3f} s before step {nxt.seq}")
            after = next(s for s in steps if s.seq > nxt.seq)
            assert after.weights_revision >= c.revision, late[-1] + " and not acted on by the one after either"
        checked += 1
    assert checked >= 20, checked
    # SLACK is a latency, not a guarantee: on a loaded 2-core machine (the suite's two workers and a browser) one
    # press of 46 once needed 0.185 s. The old version-only rule gave the next action 0 of them.
    assert len(late) <= checked // 20, late

    # The measure prints press -> first action that used it (and says the next action did, as a rule).
    out = subprocess.run(
        [sys.executable, "-m", "services.console", "measure", str(run.rundir)],
        cwd=ROOT,
        env=env(),
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode == 0, out.stderr[-2000:]
    figures = json.loads(out.stdout)
    used = figures["press_to_first_action_using_it_ms"]
    assert used["n"] + figures["credited_never_used"] == len(credits)
    # Milliseconds are a figure for `measure` to print, not a test's threshold (a loaded machine once gave p99 3 s):
    # the test asks the order of events, that most presses are used by the very next action.
    assert 0 < used["p50"] <= used["p99"]
    assert figures["actions_between_credit_and_first_use"]["p50"] == 0

    # What the actor did with the weights is not an input of learning: retraining from the log gives the live
    # learner's weights bit for bit.
    retrain = subprocess.run(
        [sys.executable, "-m", "services.replay", str(run.rundir / "session.mcap"), "retrain"],
        cwd=ROOT,
        env=env(),
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert retrain.returncode == 0 and "IDENTICAL" in retrain.stdout, retrain.stdout[-2000:] + retrain.stderr[-2000:]
