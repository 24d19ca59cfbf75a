"""`python -m services.actor`: steps the environment and publishes every Step.

The actor holds its own `TrialBatchAgent` (B = 1, the run's seed) only to act: epsilon-greedy on
alpha_q Q + alpha_h H with the schedules at its step count, exactly as the in-process runner's agent acts.
Its networks are the newest Weights it has received (never an older version after a newer one); before the
first Weights arrive they are the seed's initial networks, which are the learner's too (version 0).

A Weights version is the number of steps the learner has learned from. With `max_ahead` = m the actor
acts at step k only once it holds a version >= k - m (m = 0 is the runner's lockstep: every action sees the
update of the step before it).

Pace: `rate` steps per second (a fixed period, for a human watching) or as fast as possible (0). Each Step
carries the actor's incarnation, a contiguous seq, the wall time of the action (strictly increasing), the
episode, the weights version it acted with, and the env's info for the simulated teacher's rule.
"""
from __future__ import annotations

import sys
import time

import numpy as np

from common.agents import TrialBatchAgent, agent_config
from common.envs import make_env
from common.protocol import ProtocolError, Step, Weights, step_key, weights_key
from common.seeding import derive_seed
from services.common.config import ActorConfig
from services.common.runtime import ServiceRuntime, apply_torch_threads, service_main, wait_alive

INFO_KEYS = ("target_distance_before", "target_distance_after", "subgoal_reached")


class WeightsSlot:
    """The newest weights received (a drop_oldest inbox of size 1 feeds it); never goes back in version."""

    def __init__(self, agent: TrialBatchAgent, spec: dict, rt: ServiceRuntime):
        self.agent, self.spec, self.rt = agent, spec, rt
        self.version = 0
        self.learner: str | None = None

    def adopt(self, inbox, timeout: float | None = None) -> bool:
        """Take the newest queued weights (waiting up to `timeout` s for one if given). True if adopted."""
        import torch

        item = inbox.get(timeout) if timeout is not None else None
        items = ([item] if item is not None else []) + inbox.drain()
        adopted = False
        for it in items:
            try:
                w = Weights.decode(it.data, expected=self.spec)
            except ProtocolError as e:
                self.rt.counters[f"weights_dropped_{e.reason}"] += 1
                continue
            if w.run != self.rt.config.run:
                self.rt.counters["weights_dropped_wrong_run"] += 1
                continue
            if w.incarnation == self.learner and w.version <= self.version:
                self.rt.counters["weights_not_newer"] += 1
                continue
            if w.incarnation != self.learner and self.learner is not None:
                self.rt.counters["learner_restarts"] += 1
            self.agent.load_policy_weights({k: torch.from_numpy(np.array(v)) for k, v in w.tensors.items()}, 0)
            now = time.time()
            self.learner, self.version = w.incarnation, int(w.version)
            self.rt.counters["weights_adopted"] += 1
            self.rt.samples["adopt_latency_s"].append(now - w.t_published)
            adopted = True
        return adopted


def main(config: ActorConfig) -> int:
    from common.transport import MessagePublisher, subscription

    apply_torch_threads()
    rt = ServiceRuntime("actor", config)
    env, _ = make_env(config.env, config.layout)
    obs_dim, n_actions = int(env.observation_space.shape[0]), int(env.action_space.n)
    agent = TrialBatchAgent([agent_config(config.algo)], obs_dim, n_actions, [config.seed])
    spec = {k: tuple(v.shape) for k, v in agent.policy_weights(0).items()}
    slot = WeightsSlot(agent, spec, rt)
    seq = 0
    rt.set_counters_source(lambda: {"steps_published": seq, "weights_version": slot.version})
    code = 0

    with rt.session() as session:
        with subscription(session, weights_key(config.run), maxsize=1, policy="drop_oldest") as weights_in, \
                MessagePublisher(session, step_key(config.run)) as pub:
            rt.ready()
            missing = wait_alive(session, config.run, config.wait_for, config.start_timeout, rt.stop)
            if missing and not rt.stop.is_set():
                rt.log(f"gave up waiting for {sorted(missing)} after {config.start_timeout} s")
                rt.stop.set()
                code = 3
            obs = env.reset(seed=derive_seed(config.seed, "env") % (2**31))[0]
            period = 1.0 / config.rate if config.rate > 0 else 0.0
            next_tick = time.perf_counter()
            t_prev = 0.0
            episode = t_in_episode = 0
            limit = config.max_steps if config.max_steps is not None else float("inf")
            while episode < config.episodes and seq < limit and not rt.stop.is_set():
                slot.adopt(weights_in)
                if config.max_ahead is not None:
                    need = seq - config.max_ahead
                    waited = time.monotonic()
                    while slot.version < need and not rt.stop.is_set():
                        slot.adopt(weights_in, timeout=0.05)
                        if time.monotonic() - waited > config.weights_timeout:
                            rt.log(f"no weights >= {need} after {config.weights_timeout} s; stopping")
                            rt.stop.set()
                            code = 4
                    if rt.stop.is_set():
                        break
                    rt.counters["weights_wait_us"] += int((time.monotonic() - waited) * 1e6)
                if period:
                    next_tick += period
                    # Wait for the next tick on the weights inbox: weights are adopted as they arrive.
                    while (delay := next_tick - time.perf_counter()) > 0 and not rt.stop.is_set():
                        slot.adopt(weights_in, timeout=delay)
                    if delay < -period:
                        next_tick = time.perf_counter()  # fell behind: do not try to catch up with a burst
                agent.steps[0] = seq  # the schedules (epsilon, alpha_h, exploration stream) at this step
                action = int(agent.act(obs.reshape(1, -1))[0])
                t_action = max(time.time(), t_prev + 1e-6)  # strictly increasing, even if the clock steps back
                t_prev = t_action
                nxt, reward, terminated, truncated, info = env.step(action)
                pub.put(Step(run=config.run, incarnation=rt.incarnation, seq=seq, t_action=t_action,
                             episode=episode, t_in_episode=t_in_episode, obs=obs.tolist(), action=action,
                             reward=float(reward), next_obs=np.asarray(nxt).tolist(), terminated=bool(terminated),
                             truncated=bool(truncated), weights_version=slot.version,
                             info={k: float(info[k]) for k in INFO_KEYS if k in info}))
                seq += 1
                t_in_episode += 1
                obs = nxt
                if terminated or truncated:
                    episode += 1
                    t_in_episode = 0
                    obs = env.reset()[0]
                rt.tick()
            rt.counters["episodes"] = episode
    rt.write_stats()
    rt.log(f"stopped after {seq} steps, {episode} episodes")
    return code


def cli(argv: list[str] | None = None) -> int:
    return service_main(ActorConfig, main, argv, "python -m services.actor")


if __name__ == "__main__":
    sys.exit(cli())
