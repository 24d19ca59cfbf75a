"""`python -m services flood --connect ENDPOINT --run RUN`: publish garbage on a run's step, feedback and weights
keys (a test tool: what every subscriber must drop, count and survive; docs/faults.md). With `--run-dir DIR` in
place of `--connect` it waits for the run's record and connects to the router that record names, so it can be
started before the run and flood from its first moment, with no port chosen in advance.

Each message is one of `KINDS`, in turn: bytes that are not JSON, oversized payloads, wrong types, missing and
extra fields, NaN, a wrong run, feedback values other than -1/+1, timestamps far in the future or the past,
unknown actor incarnations and teachers, seq jumps, observations of the wrong length, actions out of range,
weights of the wrong shape, with NaN, or from a learner nobody announced. Nothing here is a well-formed input
from a known sender: those only access control can keep out (docs/security.md).
"""

from __future__ import annotations

import json
import signal
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from common.config import option

KINDS = (
    "malformed",
    "oversized",
    "wrong_type",
    "missing_field",
    "extra_field",
    "nan",
    "wrong_run",
    "future_step",
    "stale_step",
    "unknown_incarnation",
    "obs_shape",
    "action_range",
    "feedback_value",
    "feedback_seq_jump",
    "feedback_future",
    "unknown_teacher",
    "teacher_mismatch",
    "feedback_nan",
    "weights_garbage",
    "weights_shape",
    "weights_nan",
    "weights_unknown_learner",
)


def _step_obj(
    run: str, now: float, *, inc: str | None = None, obs_len: int = 2, action: int = 1, t: float | None = None
) -> dict:
    return {
        "run": run,
        "incarnation": inc or f"actor-{uuid.uuid4().hex[:12]}",
        "seq": 0,
        "t_action": now if t is None else t,
        "episode": 0,
        "t_in_episode": 0,
        "obs": [0.0] * obs_len,
        "action": action,
        "reward": 0.0,
        "next_obs": [0.0] * obs_len,
        "terminated": False,
        "truncated": False,
        "weights_version": 0,
        "info": {},
    }


def _fb_obj(
    run: str, now: float, *, teacher: str = "oracle", seq: int = 0, value: int = 1, t: float | None = None
) -> dict:
    return {
        "run": run,
        "teacher_id": teacher,
        "seq": seq,
        "t_reaction": now if t is None else t,
        "value": value,
        "source": "oracle",
    }


def _js(obj: Any) -> bytes:
    return json.dumps(obj, allow_nan=True).encode()


def makers(
    run: str, obs_dim: int, spec: dict[str, tuple[int, ...]], rng: np.random.Generator
) -> dict[str, Callable[[float], tuple[str, bytes]]]:
    """kind -> (now -> (key, payload))."""
    from common.protocol import Weights

    step, fb, weights = f"hitl/{run}/step", f"hitl/{run}/feedback/oracle", f"hitl/{run}/weights"

    def weights_bytes(tensors, inc=None) -> bytes:
        import safetensors.numpy

        w = Weights(
            run=run,
            incarnation=inc or f"learner-{uuid.uuid4().hex[:12]}",
            version=10**6,
            t_published=time.time(),
            tensors=tensors,
        )
        try:
            return w.encode()
        except Exception:  # NaN: encode refuses, build the file by hand
            meta = {
                "format": "hitl.Weights",
                "protocol": "1",
                "run": run,
                "incarnation": w.incarnation,
                "version": "1000000",
                "t_published": f"{time.time():.3f}",
            }
            return safetensors.numpy.save(tensors, metadata=meta)

    def good_shapes(fill: float = 0.1):
        return {k: np.full(v, fill, np.float32) for k, v in spec.items()}

    def drop(obj, key):
        obj = dict(obj)
        obj.pop(key)
        return obj

    return {
        "malformed": lambda now: (step, rng.bytes(int(rng.integers(1, 200)))),
        "oversized": lambda now: (step, b'{"run":"' + b"x" * 70_000 + b'"}'),
        "wrong_type": lambda now: (step, _js({**_step_obj(run, now, obs_len=obs_dim), "seq": "zero"})),
        "missing_field": lambda now: (step, _js(drop(_step_obj(run, now, obs_len=obs_dim), "reward"))),
        "extra_field": lambda now: (step, _js({**_step_obj(run, now, obs_len=obs_dim), "evil": 1})),
        "nan": lambda now: (step, _js({**_step_obj(run, now, obs_len=obs_dim), "reward": float("nan")})),
        "wrong_run": lambda now: (step, _js({**_step_obj(run, now, obs_len=obs_dim), "run": "other"})),
        "future_step": lambda now: (step, _js(_step_obj(run, now, obs_len=obs_dim, t=now + 3600))),
        "stale_step": lambda now: (step, _js(_step_obj(run, now, obs_len=obs_dim, t=now - 86400))),
        "unknown_incarnation": lambda now: (step, _js(_step_obj(run, now, obs_len=obs_dim))),
        "obs_shape": lambda now: (step, _js(_step_obj(run, now, obs_len=obs_dim + 3))),
        "action_range": lambda now: (step, _js(_step_obj(run, now, obs_len=obs_dim, action=999))),
        "feedback_value": lambda now: (fb, _js(_fb_obj(run, now, value=int(rng.choice([0, 2, -2, 7]))))),
        "feedback_seq_jump": lambda now: (fb, _js(_fb_obj(run, now, seq=10**9 + int(rng.integers(10**6))))),
        "feedback_future": lambda now: (fb, _js(_fb_obj(run, now, t=now + 3600, seq=10**9))),
        "unknown_teacher": lambda now: (f"hitl/{run}/feedback/mallory", _js(_fb_obj(run, now, teacher="mallory"))),
        "teacher_mismatch": lambda now: (fb, _js(_fb_obj(run, now, teacher="mallory"))),
        "feedback_nan": lambda now: (fb, _js(_fb_obj(run, now, t=float("nan")))),
        "weights_garbage": lambda now: (weights, rng.bytes(int(rng.integers(8, 400)))),
        "weights_shape": lambda now: (weights, weights_bytes({"q.0.weight": np.zeros((3, 3), np.float32)})),
        "weights_nan": lambda now: (weights, weights_bytes(good_shapes(float("nan")))),
        "weights_unknown_learner": lambda now: (weights, weights_bytes(good_shapes(0.5))),
    }


@dataclass(frozen=True)
class FloodConfig:
    """Publish garbage on a run's step, feedback and weights keys, which every subscriber must drop, count and
    survive (a test tool, docs/faults.md)."""

    connect: str = option("", "router endpoint, e.g. tcp/127.0.0.1:7447")
    run_dir: str = option(
        "", "instead of --connect: a run's directory; wait for its record (config/run.json) and use its router"
    )
    wait: float = option(300.0, "with --run-dir: seconds to wait for the run's record")
    run: str = option("", "the run's name")
    env: str = option("maze", "environment (the shapes of the observations and weights sent)")
    rate: float = option(300.0, "garbage messages per second")
    duration: float = option(0.0, "seconds (0: until SIGTERM)")
    seed: int = option(0, "seed of the garbage")
    report: str | None = option(None, "write the counts sent per kind to this JSON file at the end")

    def __post_init__(self):
        if bool(self.connect) == bool(self.run_dir) or not self.run:
            raise ValueError("--run and one of --connect or --run-dir are required")
        if self.rate <= 0:
            raise ValueError("--rate must be positive")


def main(args: FloodConfig) -> int:
    from common.agents import TrialBatchAgent, agent_config
    from common.envs import make_env
    from common.wire.transport import client_config, open_session
    from services.launcher.rundir import recorded_router

    env, _ = make_env(args.env, 0)
    obs_dim, n_actions = int(env.observation_space.shape[0]), int(env.action_space.n)
    spec = {
        k: tuple(v.shape)
        for k, v in TrialBatchAgent([agent_config("dqn")], obs_dim, n_actions, [0]).policy_weights(0).items()
    }
    make = makers(args.run, obs_dim, spec, np.random.default_rng(args.seed))
    stop = {"now": False}
    signal.signal(signal.SIGTERM, lambda *_: stop.update(now=True))
    signal.signal(signal.SIGINT, lambda *_: stop.update(now=True))
    sent: dict[str, int] = {k: 0 for k in KINDS}
    import zenoh

    if not args.connect:
        print(f"waiting for {Path(args.run_dir) / 'config' / 'run.json'}", flush=True)
    try:
        endpoint = args.connect or recorded_router(Path(args.run_dir), lambda: stop["now"], args.wait)
    except TimeoutError as exc:
        raise SystemExit(f"flood: {exc}") from None
    if endpoint is None:
        print("stopped before the run's record was written: nothing sent", flush=True)
        return 1
    with open_session(client_config(endpoint, connect_timeout=30)) as session:
        pubs: dict[str, Any] = {}
        print(f"flooding hitl/{args.run}/{{step,feedback/*,weights}} at {args.rate:.0f} msg/s", flush=True)
        t0 = time.monotonic()
        i = 0
        while not stop["now"] and (not args.duration or time.monotonic() - t0 < args.duration):
            kind = KINDS[i % len(KINDS)]
            key, data = make[kind](time.time())
            if key not in pubs:
                pubs[key] = session.declare_publisher(key, congestion_control=zenoh.CongestionControl.DROP)
            pubs[key].put(data)
            sent[kind] += 1
            i += 1
            time.sleep(max(0.0, t0 + i / args.rate - time.monotonic()))
        for p in pubs.values():
            p.undeclare()
    if args.report:
        with open(args.report, "w") as f:
            json.dump(sent, f)
    print(f"sent {sum(sent.values())} garbage messages", flush=True)
    return 0


if __name__ == "__main__":
    from common.config import moved

    moved("python -m services flood")
