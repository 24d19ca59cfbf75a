"""Supervision and the run directory (issue 10): a hung learner is killed and restarted, a dead actor is restarted,
a full or read-only disk ends the run with one line and a summary.json, two launchers never share a run.

`pytest -k hang`, `-k disk` select them."""

from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time

import psutil
import pytest

from .live import ROOT, assert_nothing_left, env, kill_tree, processes_mentioning, start_up, wait_for

pytestmark = [pytest.mark.live, pytest.mark.timeout(600)]


def service_process(rundir, module: str) -> psutil.Process | None:
    for p in processes_mentioning(str(rundir)):
        if module in (p.info["cmdline"] or []):
            return p
    return None


def log_size(rundir) -> int:
    return sum(p.stat().st_size for p in rundir.glob("session*.mcap"))


def assert_complete(s: dict, episodes: int | None = None) -> None:
    assert s["outcome"] == "ok", s
    n = s["steps_sent"]
    assert n > 0 and s["steps_logged"] == n and s["steps_learned"] == n, s
    assert s["steps_not_ingested"] == 0 and s["feedback_not_ingested"] == 0, s
    if episodes is not None:
        assert len(s["returns"]) == episodes


def test_hang_learner_stopped_longer_than_its_lease_is_restarted_and_nothing_is_lost(tmp_path):
    """In lockstep the actor waits for the stopped learner, so the run cannot end before the hang is caught:
    400 steps leave about 250 (6 s at 40 steps/s) after the restart to show that nothing is lost."""
    launch = start_up(tmp_path, "hang", "--episodes", "100000", "--max-steps", "400", "--rate", "40", "--seed", "2")
    try:
        assert wait_for(lambda: log_size(launch.rundir) > 50_000, 120), "the run never got going"
        learner = service_process(launch.rundir, "services.learner")
        assert learner is not None
        learner.send_signal(signal.SIGSTOP)  # hung: alive, but its Zenoh session lapses
        t_stop = time.time()
        assert wait_for(lambda: not learner.is_running() or learner.status() == psutil.STATUS_ZOMBIE, 90)
        took = time.time() - t_stop
        rc = launch.wait(timeout=400)
    finally:
        if launch.popen.poll() is None:
            launch.popen.kill()
    assert rc == 0, launch.out
    assert_nothing_left(launch.rundir)
    s = launch.summary()
    assert_complete(s)
    assert s["steps_sent"] == 400
    kills = [r for r in s["restarts"] if r["service"] == "learner"]
    assert kills and kills[0]["how"] == "signal SIGKILL" and kills[0]["recovered_s"] is not None, s["restarts"]
    assert "is hung" in launch.out and took < 60, (took, launch.out[-2000:])


def test_hang_dead_actor_is_restarted_and_the_run_completes(tmp_path):
    """A SIGTERM the launcher did not send is a death: the actor ends 'failed', is restarted, and the run (its
    teacher, learner, recorder) goes on to the last episode."""
    launch = start_up(tmp_path, "dead", "--episodes", "6", "--rate", "80", "--seed", "1")
    try:
        assert wait_for(lambda: log_size(launch.rundir) > 50_000, 120), "the run never got going"
        actor = service_process(launch.rundir, "services.actor")
        actor.send_signal(signal.SIGTERM)
        rc = launch.wait(timeout=400)
    finally:
        if launch.popen.poll() is None:
            launch.popen.kill()
    assert rc == 0, launch.out
    assert_nothing_left(launch.rundir)
    s = launch.summary()
    assert_complete(s, episodes=6)
    assert [r["service"] for r in s["restarts"]] == ["actor"] and s["restarts"][0]["exit"] == 1, s["restarts"]
    assert s["actor_incarnations"] == 2


def in_namespace(tmp_path, mount: str, *up_args: str) -> subprocess.CompletedProcess:
    """`services up --out <tmpfs>` in a private mount namespace (unshare: no privileges needed), then the run
    directory copied out for the test to read."""
    out, keep = tmp_path / "mnt", tmp_path / "keep"
    out.mkdir()
    keep.mkdir()
    script = (
        f"mount -t tmpfs -o {mount} tmpfs {out} && {sys.executable} -m services up --out {out} --run full "
        f"--progress false {' '.join(up_args)}; rc=$?; cp -r {out}/. {keep}/ 2>/dev/null; exit $rc"
    )
    assert shutil.which("unshare"), "util-linux unshare is needed (apt-get install util-linux)"
    return subprocess.run(
        ["unshare", "-rm", "sh", "-c", script], cwd=ROOT, env=env(), capture_output=True, text=True, timeout=400
    )


def test_disk_full_ends_the_run_with_one_line_and_a_summary(tmp_path):
    done = in_namespace(tmp_path, "size=1500k", "--episodes", "200", "--rate", "0", "--min-free-mb", "0.01")
    err = done.stderr
    assert done.returncode == 1, err[-3000:]
    assert "Traceback" not in err, err[-3000:]
    errors = [line for line in err.splitlines() if line.startswith("error: ")]
    assert len(errors) == 1 and "disk full" in errors[0], err[-3000:]
    s = json.loads((tmp_path / "keep" / "full" / "summary.json").read_text())
    assert s["outcome"] == "disk_full" and "disk full" in s["error"], s
    # Issue 25, finding 6: every count is in the space reserved for summary.json, and no 0-byte file is left
    # (learning_curve.png, stats/*.json.tmp used to be).
    for key in (
        "steps_sent",
        "steps_logged",
        "steps_learned",
        "feedback_sent",
        "feedback_logged",
        "feedback_credited",
        "feedback_rejected",
        "rejected_inputs",
        "duplicates_dropped",
        "log",
    ):
        assert key in s, (key, sorted(s))
    assert s["steps_sent"] > 0 and s["steps_logged"] > 0, s
    empty = [
        str(p.relative_to(tmp_path / "keep"))
        for p in (tmp_path / "keep").rglob("*")
        if p.is_file() and p.stat().st_size == 0 and p.name != ".lock" and p.parent.name != "logs"
    ]  # a process's own output log may honestly be empty
    assert not empty, empty


def test_disk_read_only_out_is_one_line(tmp_path):
    done = in_namespace(tmp_path, "ro,size=64k", "--episodes", "2")
    assert done.returncode == 2
    assert "Traceback" not in done.stderr
    assert done.stderr.strip().count("\n") == 0 and done.stderr.startswith("error: cannot write"), done.stderr


def test_two_launchers_with_the_same_out_make_two_runs_that_both_complete(tmp_path):
    cmd = [sys.executable, "-m", "services", "up", "--out", str(tmp_path), "--episodes", "3", "--progress", "false"]
    procs = [
        subprocess.Popen(
            cmd,
            cwd=ROOT,
            env=env(),
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            start_new_session=True,
        )
        for _ in range(2)
    ]
    try:
        outs = [p.communicate(timeout=400)[0] for p in procs]
    finally:  # (a run that hangs leaves nothing behind either)
        for p in procs:
            if p.poll() is None:
                kill_tree(p.pid)
    assert [p.returncode for p in procs] == [0, 0], outs
    runs = sorted(d for d in tmp_path.iterdir() if d.is_dir())
    assert len(runs) == 2, runs
    for rundir in runs:
        s = json.loads((rundir / "summary.json").read_text())
        assert_complete(s, episodes=3)
        assert_nothing_left(rundir)


def test_a_step_dropped_before_the_learner_knew_its_actor_is_sent_again(tmp_path):
    """On a loaded machine the actor's first step can reach the learner before its announcement: the learner
    drops it (unknown incarnation) and, in lockstep, the actor waits for weights that cannot come. The actor
    re-sends what the learner has not learned after `stall-resend` s (2 s), so the run completes, nothing lost. (A
    learner that starts late may instead catch the step up from the recorder's log before the re-send is due.)
    (Seen once in a run of the suite: two launchers at once, the second one stalled until its test timed out.)"""
    launch = start_up(tmp_path, "late", "--episodes", "2", "--debug-drop-steps", "1")
    assert launch.wait(timeout=240) == 0, launch.out
    s = launch.summary()
    assert_complete(s, episodes=2)
    assert s["wall_s"] < 60, s["wall_s"]  # (not after the actor gave up and was restarted: 120 s at the least)
    learner = json.loads((launch.rundir / "stats" / "learner.json").read_text())["counters"]
    actor = json.loads((launch.rundir / "stats" / "actor.json").read_text())["counters"]
    # Recovered by the actor's re-send, or (a loaded run, once with four workers) by the learner itself: started
    # late, it caught the step up from the recorder's log before the actor's re-send was due.
    assert learner["rejected_unknown_incarnation"] == 1, (learner, actor)
    assert actor["resent"] >= 1 or learner["catchup_steps"] >= 1, (learner, actor)
    for name in ("learner", "actor", "recorder"):  # start-up's objects frozen once ready: full collections skip them
        frozen = json.loads((launch.rundir / "stats" / f"{name}.json").read_text())["gc"]["frozen"]
        assert frozen > 10_000, (name, frozen)
    # Caught up by the learner; or re-sent by the stall timer, or (a loaded run, once) earlier: by the whole window
    # the actor re-sends when it first sees the learner's liveliness, if that came after the step.
    log = (launch.rundir / "logs" / "actor.log").read_text()
    if not actor["resent"]:
        assert "started without a checkpoint; caught up" in (launch.rundir / "logs" / "learner.log").read_text()
    elif actor.get("stall_resends", 0):
        assert "re-sent the last 1 steps" in log, log
    else:
        assert "learner or recorder (re)started: re-sending the last" in log, log
    assert_nothing_left(launch.rundir)


def test_a_taken_port_is_one_line_and_no_run_directory(tmp_path):
    """`services up --port N` where something already listens: one line naming the port, exit 2, no run directory
    (it was zenoh's traceback, after a run directory with credentials and a run record had been written)."""
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        done = subprocess.run(
            [sys.executable, "-m", "services", "up", "--out", str(tmp_path), "--port", str(port), "--progress", "no"],
            cwd=ROOT,
            env=env(),
            capture_output=True,
            text=True,
            timeout=120,
        )
    assert done.returncode == 2, done.stderr
    assert done.stderr.splitlines() == [
        f"error: port {port} on 127.0.0.1 is in use: choose another --port, or 0 for a free one"
    ], done.stderr
    assert not [p for p in tmp_path.iterdir() if p.is_dir()], sorted(tmp_path.iterdir())


def test_a_run_directory_in_use_is_refused(tmp_path):
    launch = start_up(tmp_path, "busy", "--episodes", "200", "--rate", "20")
    try:
        assert wait_for((launch.rundir / "config" / "run.json").exists, 60)
        second = subprocess.run(
            [sys.executable, "-m", "services", "up", "--out", str(tmp_path), "--run", "busy", "--progress", "false"],
            cwd=ROOT,
            env=env(),
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert second.returncode == 2 and "in use by another launcher" in second.stderr, second.stderr
    finally:
        launch.popen.send_signal(signal.SIGINT)
        launch.wait(timeout=120)
    assert_nothing_left(launch.rundir)
    assert os.path.exists(launch.rundir / "summary.json")


def test_hang_watch_spares_a_loaded_live_service_whose_token_lapsed(monkeypatch):
    """On a loaded machine a token can lapse while the process still runs (uses CPU): not hung until the
    status timeout; a stopped process (no CPU) is hung after the token grace."""
    from services.launcher import supervise

    clock = [1000.0]
    monkeypatch.setattr(supervise.time, "monotonic", lambda: clock[0])
    watch = supervise.HangWatch(timeout=60.0)
    for name in ("busy", "stopped"):
        watch.token(name, True)
        watch.progress(name, 1.0)
        watch.token(name, False)  # both sessions lapse at t = 1000
    for second in range(1, 31):
        clock[0] = 1000.0 + second
        watch.progress("busy", 1.0 + 0.01 * second)  # slow but running
        watch.progress("stopped", 1.0)
    assert watch.why("busy") is None
    assert "no CPU" in watch.why("stopped")
    clock[0] = 1061.0
    watch.progress("busy", 2.0)
    assert "never got it back" in watch.why("busy")  # its session never came back: hung after all


def test_services_start_on_one_blas_thread_unless_the_user_chose(monkeypatch):
    """The services compute on one BLAS thread; told so before numpy loads, OpenBLAS starts no pool."""
    from services.launcher.children import child_env

    monkeypatch.delenv("OPENBLAS_NUM_THREADS", raising=False)
    assert child_env()["OPENBLAS_NUM_THREADS"] == "1"
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "2")
    assert child_env()["OPENBLAS_NUM_THREADS"] == "2"
