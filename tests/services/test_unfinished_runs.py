"""A run whose launcher was SIGKILLed (issue 25, finding 6): its summary.json stays `{"outcome": "running"}`
until `python -m services.replay RUN_DIR summary --write` or the next `services up` in that `--out` writes it
from the log, outcome `interrupted`, with the counts the log holds."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from .live import ROOT, assert_nothing_left, env, start_up, wait_for

pytestmark = [pytest.mark.live, pytest.mark.timeout(600)]


def killed_run(out, run: str):
    """A run going at 100 steps/s whose launcher gets SIGKILL; its services notice and exit."""
    launch = start_up(out, run, "--episodes", "100000", "--rate", "100", "--seed", "1")
    log = launch.rundir / "session.mcap"
    try:
        assert wait_for(lambda: log.exists() and log.stat().st_size > 30_000, 120), "the run never got going"
        refused = replay_summary(launch.rundir, "--write")  # its launcher still runs it: not now
        assert refused.returncode == 2 and "in use" in refused.stderr, refused.stderr
        # the kill lands well into the run (more than 100 steps), whatever the refused command took
        assert wait_for(lambda: log.stat().st_size > 90_000, 120), "the run stopped growing"
    finally:
        launch.popen.kill()
        launch.wait(timeout=30)
    assert_nothing_left(launch.rundir, timeout=15.0)
    assert json.loads((launch.rundir / "summary.json").read_text()) == {"outcome": "running"}
    return launch


def replay_summary(rundir, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "services.replay", str(rundir), "summary", "--no-plot", *args],
        cwd=ROOT,
        env=env(),
        capture_output=True,
        text=True,
        timeout=300,
    )


def assert_finished_from_log(rundir) -> dict:
    s = json.loads((rundir / "summary.json").read_text())
    assert s["outcome"] == "interrupted" and s["finished_from_log"] and "launcher" in s["error"], s
    assert s["run"] == rundir.name and s["endpoint"].startswith("tcp/")
    # Without its router no service could publish a final status: the counts come from what the log shows.
    assert {"actor", "learner", "teacher.oracle"} <= set(s["services_not_stopped"]), s["services_not_stopped"]
    assert "launcher" not in s["services_not_stopped"]  # (it never says 'stopped': not a service of the run)
    n = s["steps_sent"]
    assert n > 0 and s["steps_logged"] == n and s["steps_seq_contiguous_in_log"], s
    assert s["steps_learned"] == s["learner_step_entries"]["learned"] > 0, s
    assert s["steps_not_ingested"] == n - s["steps_learned"], s  # the learner's last steps, said as such
    assert s["feedback_sent"] == s["feedback_logged"] > 0 and s["feedback_seq_contiguous_in_log"], s
    assert s["log"]["lost"] == [] and s["episodes"], s
    assert (rundir / "learning_curve.png").stat().st_size > 0
    return s


def test_replay_summary_write_finishes_a_run_whose_launcher_was_killed(tmp_path):
    launch = killed_run(tmp_path, "killed")
    done = replay_summary(launch.rundir, "--write")
    assert done.returncode == 0, done.stdout + done.stderr
    assert "wrote" in done.stderr and "interrupted" in done.stderr
    s = assert_finished_from_log(launch.rundir)
    again = replay_summary(launch.rundir, "--write")  # a final summary is left as it is
    assert again.returncode == 0 and "final already" in again.stderr, again.stderr
    assert json.loads((launch.rundir / "summary.json").read_text()) == s


def test_the_next_up_in_that_out_finishes_a_run_whose_launcher_was_killed(tmp_path):
    killed = killed_run(tmp_path, "killed")
    nxt = start_up(tmp_path, "next", "--episodes", "2")
    assert nxt.wait(timeout=300) == 0, nxt.out
    assert f"wrote {killed.rundir}/summary.json from the log" in nxt.out, nxt.out
    assert_finished_from_log(killed.rundir)
    assert json.loads((nxt.rundir / "summary.json").read_text())["outcome"] == "ok"
    assert_nothing_left(nxt.rundir)
