"""A tiny client process for the live transport test: ``sub`` prints what it receives, ``pub`` sends a Step
and a Weights message. Run as ``python tests/plumbing/zenoh_peer.py sub|pub ENDPOINT RUN``."""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

import numpy as np  # noqa: E402

from common.protocol import Step, Weights, run_prefix, step_key, weights_key  # noqa: E402
from common.wire.transport import Inbox, MessagePublisher, client_config, open_session, subscribe  # noqa: E402


def sub(endpoint: str, run: str, count: int = 2, timeout: float = 20.0) -> int:
    with open_session(client_config(endpoint)) as session:
        subscriber, inbox = subscribe(session, run_prefix(run), Inbox(16, "block"))
        try:
            print("subscribed", flush=True)
            deadline = time.monotonic() + timeout
            got = 0
            while got < count and time.monotonic() < deadline:
                item = inbox.get_message(timeout=0.5)
                if item is None:
                    continue
                received, msg = item
                out = {"key": received.key, "type": type(msg).__name__, "t_zenoh": received.t_zenoh}
                if isinstance(msg, Step):
                    out.update(seq=msg.seq, obs=msg.obs, action=msg.action)
                else:
                    out.update(
                        version=msg.version,
                        spec={k: list(v) for k, v in msg.spec().items()},
                        sum=float(sum(a.sum() for a in msg.tensors.values())),
                    )
                print(json.dumps(out), flush=True)
                got += 1
            print(json.dumps({"counters": inbox.snapshot()}), flush=True)
            return 0 if got == count else 1
        finally:
            inbox.close()
            subscriber.undeclare()


def pub(endpoint: str, run: str) -> int:
    with open_session(client_config(endpoint)) as session:
        with MessagePublisher(session, step_key(run)) as steps, MessagePublisher(session, weights_key(run)) as weights:
            if not (steps.wait_for_subscribers(10) and weights.wait_for_subscribers(10)):
                print("no subscriber", flush=True)
                return 1
            steps.put(
                Step(
                    run=run,
                    incarnation="pub-1",
                    seq=0,
                    t_action=time.time(),
                    episode=0,
                    t_in_episode=0,
                    obs=[0.5, -1.0],
                    action=3,
                    reward=-0.01,
                    next_obs=[1.5, -1.0],
                    terminated=False,
                    truncated=False,
                    weights_version=0,
                    info={},
                )
            )
            tensors = {"q.0.weight": np.arange(6, dtype=np.float32).reshape(3, 2), "q.0.bias": np.ones(3, np.float32)}
            weights.put(Weights(run=run, incarnation="learner-1", version=7, t_published=time.time(), tensors=tensors))
            print("sent", flush=True)
            time.sleep(0.2)  # let the transmission queue empty before the session closes
    return 0


if __name__ == "__main__":
    role, endpoint, run = sys.argv[1:4]
    sys.exit(sub(endpoint, run) if role == "sub" else pub(endpoint, run))
