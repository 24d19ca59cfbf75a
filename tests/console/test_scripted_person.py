"""A scripted person in the browser (the paper's rule, a lag of 0.3-1.5 s after each paint) teaches DQN-TAMER on a
maze through the console at a test-friendly pace: every press is credited, and always to (among others) the step
the person was reacting to, since its on-screen interval lies inside the assumed 0.2-4 s window."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from common.logs.mcap_read import read_log
from common.protocol import Credit, Feedback, Step

from tests.services.live import ROOT, env

from .harness import WebRun, scripted_person

pytestmark = [pytest.mark.live, pytest.mark.browser]


def test_scripted_person_teaches_dqn_tamer(tmp_path):
    run = WebRun(
        tmp_path,
        "scripted",
        "--env",
        "maze",
        "--layout",
        "0",
        "--algo",
        "dqn-tamer",
        "--episodes",
        "50",
        "--max-steps",
        "160",
        "--rate",
        "8",
        "--seed",
        "2",
    )
    plan, presses = scripted_person(run, tmp_path / "profile", "{p: 0.6, lagMin: 0.3, lagMax: 1.5, seed: 7}")

    summary = run.rundir / "summary.json"
    assert summary.exists()
    feedback, credits, episode_of, logged = {}, {}, {}, {}
    last_step = 0
    for rec in read_log(run.rundir / "session.mcap"):
        m = rec.message
        if isinstance(m, Step):
            episode_of[m.seq] = m.episode
            last_step = max(last_step, rec.log_time)
        elif isinstance(m, Feedback) and m.teacher_id == "web-1":
            feedback[m.seq] = m
            logged[m.seq] = rec.log_time
        elif isinstance(m, Credit) and m.teacher_id == "web-1":
            credits[m.seq] = m
    assert len(presses) >= 40 and len(feedback) == len(presses)
    # A press that reaches the log after the actor's last step may come after the learner has ended (no Credit, or
    # `after_end`: how many depends on the machine's load); every press before it is credited.
    credited = [c for c in credits.values() if c.status == "credited"]
    uncredited = [q for q in feedback if q not in credits or credits[q].status != "credited"]
    early = [(q, credits[q].status if q in credits else None) for q in uncredited if logged[q] <= last_step]
    assert not early and len(credited) >= len(feedback) - 10, (early, len(credited), len(feedback))
    checked = 0
    for c in credited:
        fb = feedback[c.seq]
        # the reaction it was: due at or before the press (a timer never fires early; a loaded machine fires late)
        due = [p for p in plan if p["value"] == fb.value and -0.005 <= fb.t_page - p["due"] < 1.0]
        assert due, f"press {fb.seq} matches no planned reaction"
        reacted = [min(due, key=lambda p: fb.t_page - p["due"])]
        if all(episode_of[p["seq"]] != episode_of[fb.shown[-1].seq] for p in reacted):
            continue  # reacting to an episode's last step after the next began: credit never crosses episodes
        seqs = {s.seq for s in c.steps}
        assert any(p["seq"] in seqs for p in reacted), (fb.seq, [p["seq"] for p in reacted], sorted(seqs))
        checked += 1
    assert checked >= 35
    # The learner's idle-time updates and its credit of the person's feedback are in its Ingest order:
    # retraining from the log gives its weights bit for bit.
    retrain = subprocess.run(
        [sys.executable, "-m", "services.replay", str(run.rundir / "session.mcap"), "retrain"],
        cwd=ROOT,
        env=env(),
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert retrain.returncode == 0, retrain.stdout[-2000:] + retrain.stderr[-2000:]
    stats = json.loads((run.rundir / "stats" / "learner.json").read_text())["counters"]
    assert stats.get("idle_updates", 0) > 0
