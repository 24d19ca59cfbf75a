"""The console follows the learner's weights with the actor's follower and checks: the same Weights messages,
offered to the actor's follower and to the console's hub, are adopted or dropped alike, for the same reasons."""

from __future__ import annotations

import asyncio
import time

import numpy as np

from common.agents import make_agent
from common.envs import make_env, n_actions, obs_shape
from common.protocol import ServiceStatus, Weights, status_key, teacher_service_name, weights_key
from common.wire.auth import make_run_credentials
from common.wire.delivery import Inbox, Received
from common.wire.transport import open_session, peer_config
from services.common.config import ActorConfig
from services.common.runtime import ServiceRuntime
from services.common.gate import WeightsFollower
from services.console.bridge import Hub
from services.console.config import ConsoleConfig

RUN = "follow"


def offers(spec: dict) -> list[tuple[str, bytes]]:
    """(what it is, the Weights bytes) in the order they arrive; `spec`: the agent's tensor names and shapes."""
    now = time.time()

    def w(version, fill, learner="learner-1", revision=None, run=RUN, t=now, shapes=spec):
        tensors = {k: np.full(s, fill, np.float32) for k, s in shapes.items()}
        return Weights(
            run=run, incarnation=learner, version=version, t_published=t, tensors=tensors, revision=revision
        ).encode()

    wrong = {k: (s[0] + 1, *s[1:]) for k, s in spec.items()}
    return [
        ("first", w(5, 0.5)),
        ("older", w(3, 0.3)),
        ("newer", w(7, 0.7)),
        ("unannounced", w(99, 0.9, learner="mallory")),
        ("other run", w(8, 0.8, run="other")),
        ("from the future", w(9, 0.9, t=now + 3600)),
        ("stale", w(9, 0.9, t=now - 3600)),
        ("wrong shapes", w(9, 0.9, shapes=wrong)),
        ("a press's H update", w(7, 0.75, revision=4)),
        ("an older revision", w(7, 0.72, revision=3)),
        ("restarted learner", w(1, 0.1, learner="learner-2")),
    ]


def test_the_console_adopts_and_drops_weights_as_the_actor_does(tmp_path):
    creds = make_run_credentials(tmp_path, RUN, teachers=["web"])
    console_cfg = ConsoleConfig(run=RUN, credentials=str(creds["teacher.web"]))
    env, _ = make_env(console_cfg.env, console_cfg.layout)
    agent = make_agent([console_cfg.agent], obs_shape(env), n_actions(env), [0])
    spec = {k: tuple(v.shape) for k, v in agent.policy_weights(0).items()}
    actor_rt = ServiceRuntime(
        "actor", ActorConfig(run=RUN, credentials=str(creds["actor"])), install_signals=False, process_default=False
    )
    actor = WeightsFollower(agent, spec, actor_rt)
    console_rt = ServiceRuntime(
        teacher_service_name(console_cfg.teacher_prefix), console_cfg, install_signals=False, process_default=False
    )
    loop = asyncio.new_event_loop()
    with open_session(peer_config()) as session:
        hub = Hub(console_cfg, console_rt, session, loop)
        hub.obs = np.asarray(env.reset(seed=0)[0], np.float32)
        try:
            for learner in ("learner-1", "learner-2"):  # both announced by their statuses
                st = ServiceStatus(
                    run=RUN, service="learner", pid=1, state="ready", t=time.time(), counters={}, incarnation=learner
                )
                hub.on_message(status_key(RUN, "learner"), st.encode(), time.time())
                actor.announce(st)
            seen = []
            for what, data in offers(spec):
                t = time.time()
                inbox = Inbox(4, "drop_oldest")
                inbox.put(Received(weights_key(RUN), data, t, None))
                by_actor = actor.adopt(inbox)
                before = hub.weights.progress
                hub.on_message(weights_key(RUN), data, t)
                by_console = hub.weights.progress != before
                assert by_console == by_actor, what
                assert hub.weights.progress == actor.progress, what
                seen.append((what, by_actor))
                prefs = hub.preferences()  # what the pages show: the actor's Q and H
                assert prefs["weights_version"] == actor.version
                q, h, _, _ = agent.preferences(0, hub.obs)
                assert prefs["q"] == [round(float(x), 4) for x in q] and prefs["h"] == [round(float(x), 4) for x in h]
        finally:
            hub.close()
    loop.close()
    adopted = [what for what, ok in seen if ok]
    assert adopted == ["first", "newer", "a press's H update", "restarted learner"]
    dropped = {k: v for k, v in console_rt.counters.items() if k.startswith("weights_")}
    assert dropped == {k: v for k, v in actor_rt.counters.items() if k.startswith("weights_")}
    for reason in ("unknown_incarnation", "wrong_run", "future_timestamp", "stale_timestamp"):
        assert dropped[f"weights_dropped_{reason}"] == 1, dropped
    assert sum(v for k, v in dropped.items() if k.startswith("weights_dropped_")) == 5  # and the wrong shapes
    assert dropped["weights_not_newer"] == 2 and dropped["weights_adopted"] == 4
