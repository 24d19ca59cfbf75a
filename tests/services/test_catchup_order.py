"""A learner catching up from a log whose file order has live steps before the actor's re-sent ones learns every
step: the ahead ones wait for the re-sent ones as they do live (`StepReorder`), instead of being consumed at once as a
gap. A real `python -m services.learner` process, a real MCAP log, a real Zenoh router.

The order is a chaos run's (29 November): the recorder, restarted, wrote live steps 225-226 before the actor's re-sent
0-226, and the learner, restarted from a checkpoint at 200 steps, lost 25 steps reading it in file order."""

from __future__ import annotations

import json
import os
import subprocess
import sys

from common.logs.mcap_log import LogWriter
from common.protocol import RunConfig, ServiceStatus, status_key, step_key

from .live import ROOT, env
from .test_cores import RUN, make_steps

STEPS = 60


def status(state: str, published: int, t: float) -> ServiceStatus:
    counters = {"steps_published": published}
    return ServiceStatus(run=RUN, service="actor", pid=1, state=state, t=t, counters=counters, incarnation="actor-1")


def write_log(path) -> None:
    """The actor announced, its steps 0-29, then 45-46 (live, ahead), then 0-46 (re-sent), then the rest, stopped."""
    steps = make_steps(STEPS, [100.0 + 0.1 * k for k in range(STEPS)])
    order = steps[:30] + steps[45:47] + steps[:47] + steps[47:]
    writer = LogWriter(path, RunConfig.create(RUN, {"env": "maze", "algo": "dqn-tamer"}, t_created=98.0))
    writer.write(status_key(RUN, "actor"), status("ready", 0, 99.0), log_time=int(99.0e9))
    for k, s in enumerate(order):
        writer.write(step_key(RUN), s, log_time=int((100.0 + 0.01 * k) * 1e9))
    writer.write(status_key(RUN, "actor"), status("stopped", STEPS, 107.0), log_time=int(107.0e9))
    writer.finish()


def test_a_learner_catching_up_waits_for_the_steps_a_live_one_overtook_in_the_log(tmp_path):
    from common.wire.transport import free_port, open_session, router_config, tcp_endpoint

    log, stats = tmp_path / "session.mcap", tmp_path / "learner.json"
    write_log(log)
    creds = tmp_path / "creds"
    subprocess.run([sys.executable, "-m", "services", "credentials", "--run", RUN, "--out", str(creds)], cwd=ROOT,
                   env=env(), check=True, timeout=60)  # fmt: skip
    endpoint = tcp_endpoint(free_port())
    args = ["--credentials", str(creds / "learner.json"), "--connect", endpoint, "--run", RUN]
    args += ["--catchup-log", str(log), "--stats-out", str(stats)]
    args += ["--wait-teachers", "", "--end-grace", "0.5", "--parent-pid", str(os.getpid())]
    with open_session(router_config(endpoint)):
        done = subprocess.run(
            [sys.executable, "-m", "services.learner", *args],
            cwd=ROOT,
            env=env(),
            capture_output=True,
            text=True,
            timeout=120,
        )
    assert done.returncode == 0, done.stderr[-3000:]
    counters = json.loads(stats.read_text())["counters"]
    assert counters["steps_learned"] == STEPS and counters.get("steps_lost", 0) == 0, counters
    assert counters["steps_waited"] == 2 and counters["catchup_steps"] == STEPS, counters
