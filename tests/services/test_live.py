"""The live system: every service as its own process on a loopback Zenoh router (free port, no multicast).

Each test checks that nothing is left running afterwards (every service's argv names the run directory).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
import warnings

import numpy as np
import pytest

from common.logs.mcap_log import LogRecoveryWarning, load_log
from common.protocol import Step

from .live import ROOT, assert_nothing_left, env, processes_mentioning, start_up, wait_for

pytestmark = pytest.mark.live

REJECT_REASONS = {"stale", "too_old", "ignored", "after_end", "actor_restarted"}


@pytest.fixture(scope="module")
def live_run(tmp_path_factory):
    """One 25-episode run of the main job (maze, DQN-TAMER, oracle teacher, as fast as possible in lockstep)."""
    out = tmp_path_factory.mktemp("live")
    launch = start_up(out, "it", "--episodes", "25", "--seed", "0", "--curve", "true")
    rc = launch.wait(timeout=240)
    assert rc == 0, launch.out
    yield launch
    assert_nothing_left(launch.rundir)


def steps_in_log(path):
    records, status = load_log(path)
    return [r.message for r in records if isinstance(r.message, Step)], records, status


def test_no_step_lost_and_every_feedback_accounted_for(live_run):
    s = live_run.summary()
    assert s["outcome"] == "ok" and set(s["exit_codes"].values()) == {0}
    assert s["services_not_stopped"] == []  # every service said its last word: its counts are final
    n = s["steps_sent"]
    assert n > 0 and s["steps_logged"] == n and s["steps_learned"] == n
    assert s["steps_seq_contiguous_in_log"] and s["actor_incarnations"] == 1
    assert s["learner_step_entries"] == {"learned": n}  # seq contiguous at the learner: no gap, no old step
    steps, _, _ = steps_in_log(live_run.rundir / "session.mcap")
    assert [m.seq for m in steps] == list(range(n))
    assert s["feedback_sent"] > 0 and s["feedback_logged"] == s["feedback_sent"]
    assert s["feedback_seq_contiguous_in_log"]
    rejected = s["feedback_rejected"]
    assert set(rejected) <= REJECT_REASONS, rejected  # no "unresolved": each one credited or rejected with a reason
    assert s["feedback_credited"] + sum(rejected.values()) == s["feedback_logged"]
    # The rest went stale (arrived after its steps left the held window), more of it on a loaded machine: above 0.9
    # of the logged were credited on a quiet one, 0.875 and 0.877 under the suite's two workers, 0.754 under three on
    # a slow hour; so more than half, which a pipeline that delays feedback by a window's worth of steps would miss.
    assert s["feedback_credited"] > 0.5 * s["feedback_logged"]
    for name in ("session.mcap", "summary.json", "learning_curve.png"):
        assert (live_run.rundir / name).stat().st_size > 0
    # the oracle of an unpaced run is credited on the step clock (--oracle-delay auto): the block says so
    (oracle,) = s["delay"].values()
    assert oracle["assumed"].startswith("steps:") and set(oracle) >= {"median_s", "p10_s", "p90_s", "feedbacks"}


def test_returns_improve(live_run):
    s = live_run.summary()
    returns = s["returns"]
    assert len(returns) == 25
    assert all(e["finished"] for e in s["episodes"])
    # The goal gives +1, each step -0.01: short paths by the end (median: exploratory detours are allowed), better
    # than the first episode. Not "the last 5 beat the first 5 on the mean": the agent learns the maze within a few
    # episodes, and one 289-step detour in a loaded run put the last 5 at 0.29 against 0.47 (medians 0.89, 0.83).
    assert np.median(returns[-10:]) > max(0.8, returns[0]), returns
    assert [e["episode"] for e in s["episodes"]] == list(range(25))


def test_launcher_exits_within_10_s_of_the_end(live_run):
    steps, records, _ = steps_in_log(live_run.rundir / "session.mcap")
    t_end = steps[-1].t_action
    assert live_run.t_exit - t_end < 10.0, f"launcher exited {live_run.t_exit - t_end:.1f} s after the last step"
    assert "zenoh endpoint: tcp/127.0.0.1:" in live_run.out


def test_retrain_reproduces_the_live_weights_bit_for_bit(live_run):
    out = subprocess.run(
        [sys.executable, "-m", "services.replay", str(live_run.rundir / "session.mcap"), "retrain"],
        cwd=ROOT,
        env=env(),
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode == 0, out.stdout + out.stderr
    assert "IDENTICAL bit for bit" in out.stdout and "match" in out.stdout


def test_replay_summary_agrees_with_the_launcher(live_run, tmp_path):
    out = subprocess.run(
        [
            sys.executable,
            "-m",
            "services.replay",
            str(live_run.rundir),
            "summary",
            "--json",
            "--plot",
            str(tmp_path / "c.png"),
        ],
        cwd=ROOT,
        env=env(),
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode == 0, out.stderr
    s, launcher = json.loads(out.stdout), live_run.summary()
    for k in ("steps_sent", "steps_learned", "feedback_sent", "feedback_credited", "feedback_rejected", "returns"):
        assert s[k] == launcher[k]
    assert (tmp_path / "c.png").stat().st_size > 0


def test_replay_summary_of_the_recorded_log_with_one_flipped_byte_names_what_was_lost(live_run, tmp_path):
    """Issue 25, finding 5: a flipped byte in a real recorded log used to read "(complete)" with exit 0."""
    from tests.plumbing.test_mcap_damage import chunks_of

    data = bytearray((live_run.rundir / "session.mcap").read_bytes())
    chunks = chunks_of(live_run.rundir / "session.mcap")
    offset, length, lost = chunks[len(chunks) // 2]
    data[offset + length // 2] ^= 0x01
    (tmp_path / "session.mcap").write_bytes(bytes(data))
    out = subprocess.run(
        [sys.executable, "-m", "services.replay", str(tmp_path), "summary", "--no-plot"],
        cwd=ROOT,
        env=env(),
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode == 1, out.stdout + out.stderr
    assert (
        "DATA LOST" in out.stdout and f"skipped 1 damaged chunk(s), {length} bytes, {len(lost)} messages" in out.stdout
    ), out.stdout


def test_play_republishes_the_session_to_a_recorder(live_run, tmp_path):
    from common.wire.transport import free_port, open_session, router_config, tcp_endpoint
    from services.common.runtime import wait_alive

    endpoint = tcp_endpoint(free_port())
    copy = tmp_path / "copy.mcap"
    creds = tmp_path / "creds"
    subprocess.run(
        [sys.executable, "-m", "services", "credentials", "--run", "it", "--out", str(creds)],
        cwd=ROOT,
        env=env(),
        check=True,
        timeout=60,
    )
    with open_session(router_config(endpoint)) as session:
        rec = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "services.recorder",
                "--connect",
                endpoint,
                "--run",
                "it",
                "--out",
                str(copy),
                "--parent-pid",
                str(os.getpid()),
                "--credentials",
                str(creds / "recorder.json"),
            ],
            cwd=ROOT,
            env=env(),
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            start_new_session=True,
        )
        try:
            assert not wait_alive(session, "it", ["recorder"], 60)
            play = subprocess.run(
                [
                    sys.executable,
                    "-m",
                    "services.replay",
                    str(live_run.rundir / "session.mcap"),
                    "play",
                    "--connect",
                    endpoint,
                    "--speed",
                    "0",
                    "--kinds",
                    "step,feedback,episode",
                    "--start-delay",
                    "0",
                    "--credentials",
                    str(creds / "launcher.json"),
                ],
                cwd=ROOT,
                env=env(),
                capture_output=True,
                text=True,
                timeout=120,
            )
            assert play.returncode == 0, play.stderr
            time.sleep(3.0)  # the recorder checks and writes what is still in flight
        finally:
            rec.send_signal(signal.SIGTERM)
            rec.wait(20)
    original, _, _ = steps_in_log(live_run.rundir / "session.mcap")
    replayed, records, status = steps_in_log(copy)
    assert status.complete
    assert [m.encode() for m in replayed] == [m.encode() for m in original]
    kinds = {r.key.split("/")[2] for r in records}
    assert {"step", "feedback", "episode"} <= kinds


def test_dqn_live_in_lockstep_equals_the_in_process_runner(tmp_path):
    """Same seed and timing: DQN (feedback ignored) acts identically live and in-process, action for action."""
    from common.agents import agent_config
    from common.core.observer import ObserverConfig
    from experiments.runner import TrialSpec, run_trials

    episodes, seed = 6, 2
    launch = start_up(
        tmp_path, "dqn", "--algo", "dqn", "--episodes", str(episodes), "--seed", str(seed), "--max-ahead", "0"
    )
    assert launch.wait(timeout=240) == 0, launch.out
    steps, _, _ = steps_in_log(launch.rundir / "session.mcap")
    ref = run_trials(
        [TrialSpec("maze", agent_config("dqn"), ObserverConfig(), seed, 0, episodes)], record_actions=True
    )[0]
    assert [m.action for m in steps] == ref.actions
    assert launch.summary()["returns"] == pytest.approx(list(ref.returns), abs=1e-9)
    assert_nothing_left(launch.rundir)


def test_dqn_tamer_live_learns_like_in_process(tmp_path):
    """DQN-TAMER live (lockstep) learns as the in-process runner does: over the same 4 seeds, the mean of the
    learning measure (mean log episode length over episodes 10-19) is within what 99.99% of in-process 4-seed
    draws reach, for the live runs and for the in-process runs. The rule and its measured rates (false failures,
    and passes of an untrained agent and of one whose feedback never arrives) are in `learning_rule.py`.

    Exact equality is not expected: live feedback reaches the policy at least one step later than on the virtual
    clock (docs/live.md), and a teacher that falls behind (its start-up, a loaded machine) sends reactions later
    still, which slows live learning a little (measured in learning_rule.py). With the default 32-step history
    the latest would be dropped as stale, so both sides keep 1000 steps (no reaction is dropped for lateness;
    the in-process runner never delivers one late). Live and in-process runs of one seed are not paired: their
    measures correlate at 0.17 (60 seeds), since their actions part at the first feedback."""
    from .learning_rule import EPISODES, HISTORY_STEPS, MAX_MEAN_LOG_STEPS, in_process_steps, learning_measure, passes

    seeds = range(4)
    ref = [learning_measure(steps) for steps in in_process_steps(seeds)]
    live = []
    for s in seeds:  # one at a time: a second run's load makes the lockstep actor outrun the teacher
        launch = start_up(
            tmp_path,
            f"s{s}",
            "--episodes",
            str(EPISODES),
            "--seed",
            str(s),
            "--max-ahead",
            "0",
            "--agent.history-steps",
            str(HISTORY_STEPS),
        )
        assert launch.wait(timeout=240) == 0, launch.out
        summary = launch.summary()
        # None stale, none ignored: every feedback reached H (the measure alone would pass an agent that ignores
        # feedback by design, dqn: 99.9% of draws, as DQN too learns the maze by episode 10).
        assert set(summary["feedback_rejected"]) <= {"after_end"}, summary["feedback_rejected"]
        assert summary["feedback_credited"] >= 0.9 * summary["feedback_logged"] > 0, summary["feedback_credited"]
        assert all(e["finished"] for e in summary["episodes"])
        live.append(learning_measure([e["steps"] for e in summary["episodes"]]))
        assert_nothing_left(launch.rundir)
    msg = (
        f"mean log steps of episodes 10-19 per seed: live {np.round(live, 2)} (mean {np.mean(live):.2f}), "
        f"in-process {np.round(ref, 2)} (mean {np.mean(ref):.2f}); limit {MAX_MEAN_LOG_STEPS}"
    )
    assert passes(ref), "in process: " + msg  # deterministic: the algorithm itself changed (re-measure the rule)
    assert passes(live), "live: " + msg


def test_ctrl_c_stops_everything_cleanly(tmp_path):
    launch = start_up(tmp_path, "int", "--episodes", "100000", "--rate", "200")
    log = launch.rundir / "session.mcap"
    assert wait_for(lambda: log.exists() and log.stat().st_size > 20_000, 90)  # steps are flowing
    time.sleep(1.0)
    t = time.time()
    os.killpg(launch.popen.pid, signal.SIGINT)  # what a terminal's Ctrl-C does to the foreground group
    rc = launch.wait(timeout=30)
    assert rc == 130, launch.out
    assert launch.t_exit - t < 10.0
    assert_nothing_left(launch.rundir)
    s = launch.summary()
    assert s["outcome"] == "interrupted" and log.exists()
    # The actor stopped first, so the others finished what it sent: nothing lost on the way out.
    # (how many steps flowed before the signal depends on the machine's load: 35 seen under three test workers)
    assert s["steps_sent"] > 0 and s["steps_logged"] == s["steps_sent"] == s["steps_learned"]
    assert s["feedback_logged"] == s["feedback_sent"]
    assert set(s["feedback_rejected"]) <= REJECT_REASONS


def test_killed_recorder_log_is_recovered_up_to_its_last_chunk(tmp_path):
    launch = start_up(tmp_path, "crash", "--episodes", "100000", "--rate", "200", "--restart-limit", "0")

    def recorder():
        return [p for p in processes_mentioning(str(launch.rundir)) if "services.recorder" in p.info["cmdline"]]

    assert wait_for(lambda: bool(recorder()), 60)
    log = launch.rundir / "session.mcap"

    def steps_flushed() -> list:
        """The steps a reader finds in the log as it is being written (up to its last complete chunk)."""
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", LogRecoveryWarning)
            return steps_in_log(log)[0] if log.exists() and log.stat().st_size > 4096 else []

    # Kill once the log holds more than 20 steps and a later flush has added to it: on progress, not on a clock
    # (a loaded CI machine made 5 steps in the 2 s a fixed wait gave it).
    assert wait_for(lambda: len(steps_flushed()) > 20, 120, period=0.5)
    before = steps_flushed()
    assert wait_for(lambda: len(steps_flushed()) > len(before), 60, period=0.5)
    flushed = steps_flushed()
    recorder()[0].send_signal(signal.SIGKILL)
    rc = launch.wait(timeout=40)
    assert rc == 1, launch.out  # a service died: the launcher says so and stops the others
    assert "recorder exited with code -9" in launch.out
    assert_nothing_left(launch.rundir)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", LogRecoveryWarning)
        steps, records, status = steps_in_log(log)
    assert any("recovered" in str(w.message) for w in caught)
    assert status.truncated and not status.complete
    # Every step flushed before the kill was recovered, in order, and nothing else was lost on the way.
    assert [m.seq for m in steps] == list(range(len(steps))) and len(steps) >= len(flushed) > 20
    out = subprocess.run(
        [sys.executable, "-m", "services.replay", str(log), "summary", "--no-plot"],
        cwd=ROOT,
        env=env(),
        capture_output=True,
        text=True,
        timeout=120,
    )
    # read up to the cut, and the cut is named: exit 1 (data lost), not 0
    assert out.returncode == 1 and "recovered" in out.stderr and "lost:" in out.stdout, out.stdout + out.stderr
    assert "truncated" in out.stdout and "(complete)" not in out.stdout


def test_services_exit_when_the_launcher_is_killed(tmp_path):
    launch = start_up(tmp_path, "orphan", "--episodes", "100000", "--rate", "100")
    assert wait_for(lambda: len(processes_mentioning(str(launch.rundir))) >= 4, 60)
    time.sleep(1.0)
    launch.popen.kill()  # SIGKILL: no chance to clean up; the services notice their parent is gone
    launch.popen.wait(10)
    assert_nothing_left(launch.rundir, timeout=15.0)


def test_a_paced_oracle_has_its_delay_learned_and_reported(tmp_path):
    """`services up --teacher oracle --rate 8`, no delay option: the learner learns the oracle's delay in seconds
    (its true reactions come 0.06-0.31 s after a step) and summary.json reports it, moved off the prior's 2.1 s."""
    # at most 160 steps (20 s): six episodes took 46-112 s in the suite, as early episodes run long
    launch = start_up(tmp_path, "paced", "--episodes", "6", "--max-steps", "160", "--rate", "8", "--seed", "0")
    assert launch.wait(timeout=240) == 0, launch.out
    assert_nothing_left(launch.rundir)
    (oracle,) = launch.summary()["delay"].values()
    assert "assumed" not in oracle and oracle["feedbacks"] >= 10, oracle
    assert 0 <= oracle["p10_s"] <= oracle["median_s"] < 1.0 and oracle["p90_s"] <= 6, oracle
