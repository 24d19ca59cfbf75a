"""`python -m services.actor`: steps the environment and publishes every Step.

The actor holds its own `TrialBatchAgent` (B = 1, the run's seed) only to act: epsilon-greedy on
alpha_q Q + alpha_h H with the schedules at its step count, exactly as the in-process runner's agent acts.
Its networks are the newest Weights it has received (never an older version after a newer one); before the
first Weights arrive they are the seed's initial networks, which are the learner's too (version 0).

A Weights version is the number of steps the learner has learned from. With `max_ahead` = m the actor
acts at step k only once it holds a version >= k - m (m = 0 is the runner's lockstep: every action sees the
update of the step before it).

Restarts (docs/faults.md): with `state_file`, the number of finished episodes is saved (atomically) before
each episode's last step is published. An actor started on an existing state file is a new incarnation
that continues the run: it starts the next episode (the broken one is closed by the learner), waits for
the current weights of an announced learner first and counts its schedules and lockstep from that version
on. Weights are accepted only from a learner incarnation that a ServiceStatus announced, with a plausible
timestamp and the right tensor names and shapes; everything else is dropped and counted. Steps of the last
`resend_window` s are published again when a learner or recorder (re)starts.

Pace: `rate` steps per second (a fixed period, for a human watching) or as fast as possible (0). Each Step
carries the actor's incarnation, a contiguous seq, the wall time of the action (strictly increasing), the
episode, the weights version it acted with, and the env's info for the simulated teacher's rule.
"""
from __future__ import annotations

import sys
import time

import numpy as np

from common.agents import TrialBatchAgent, make_agent
from common.envs import make_env, obs_shape
from common.protocol import (ProtocolError, ServiceStatus, Step, Weights, control_key, status_key, step_key,
                             weights_key)
from services.actor.control import RunControl
from services.actor.render import FramePublisher, enable_rgb
from common.seeding import derive_seed
from services.common.config import ActorConfig
from services.common.faults import AliveWatch, IncarnationWatch, ResendRing, atomic_write_json, first_time_logger, publish_kept, read_json
from services.common.runtime import ServiceRuntime, apply_torch_threads, service_main, wait_alive

INFO_KEYS = ("target_distance_before", "target_distance_after", "subgoal_reached", "row", "col")
RECORDER_WAIT = 20.0  # s to wait at the end for a recorder that is restarting (it must get what it missed)


class WeightsSlot:
    """The newest weights received (a drop_oldest inbox of size 1 feeds it); never goes back in version."""

    def __init__(self, agent: TrialBatchAgent, spec: dict, rt: ServiceRuntime):
        self.agent, self.spec, self.rt = agent, spec, rt
        self.version = 0
        self.limit: int | None = None  # no version above this (steps published + 1); None: any (a restart's wait)
        self.learner: str | None = None
        self.announced: list[str] = []  # learner incarnations announced by their ServiceStatus (newest last)
        self.watch = None  # an IncarnationWatch of the learner (liveliness), set once the session is open
        self._note = first_time_logger(rt.event, "weights")

    def on_status(self, inbox) -> None:
        for it in inbox.drain():
            try:
                st = it.decode()
            except ProtocolError:
                self.rt.counters["rejected_status"] += 1
                continue
            if isinstance(st, ServiceStatus) and st.incarnation and st.incarnation not in self.announced:
                self.announced = (self.announced + [st.incarnation])[-16:]

    def known(self, incarnation: str) -> bool:
        return (incarnation == self.learner or incarnation in self.announced
                or (self.watch is not None and self.watch.known(incarnation)))

    def _reject(self, reason: str) -> None:
        self.rt.counters[f"weights_dropped_{reason}"] += 1
        self._note(reason, "")

    def adopt(self, inbox, timeout: float | None = None, status=None) -> bool:
        """Take the newest queued weights (waiting up to `timeout` s for one if given). True if adopted."""
        item = inbox.get(timeout) if timeout is not None else None
        items = ([item] if item is not None else []) + inbox.drain()
        adopted = False
        cfg = self.rt.config
        for it in items:
            try:
                w = Weights.decode(it.data, expected=self.spec)
            except ProtocolError as e:
                self._reject(e.reason)
                continue
            if w.run != cfg.run:
                self._reject("wrong_run")
                continue
            if w.t_published > it.t_recv + cfg.max_future:
                self._reject("future_timestamp")
                continue
            if w.t_published < it.t_recv - cfg.max_past:
                self._reject("stale_timestamp")
                continue
            if not self.known(w.incarnation) and status is not None:
                self.on_status(status)  # its announcement may be waiting in the status queue
            if not self.known(w.incarnation):
                self._reject("unknown_incarnation")
                continue
            if self.limit is not None and w.version > self.limit:
                self._reject("version_ahead")  # a learner cannot have learned steps this actor never sent
                continue
            if w.incarnation == self.learner and w.version <= self.version:
                self.rt.counters["weights_not_newer"] += 1
                continue
            if w.incarnation != self.learner and self.learner is not None:
                self.rt.counters["learner_restarts"] += 1
            self.agent.load_policy_weights(w.tensors, 0)
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
    if config.episode_steps is not None:  # the registry's envs truncate at their `max_steps`
        if not hasattr(env, "max_steps"):
            raise ValueError(f"--episode-steps: {config.env} has no max_steps to set")
        env.max_steps = config.episode_steps
    obs_dim, n_actions = int(env.observation_space.shape[0]), int(env.action_space.n)
    agent = make_agent([config.agent], obs_shape(env), n_actions, [config.seed])
    spec = {k: tuple(v.shape) for k, v in agent.policy_weights(0).items()}
    slot = WeightsSlot(agent, spec, rt)
    seq = 0
    rt.set_counters_source(lambda: {"steps_published": seq, "weights_version": slot.version, "resent": ring.resent})
    code = 0
    state = read_json(config.state_file) if config.state_file else None
    restart = state is not None
    episodes_done = int(state["episodes_done"]) if state else 0
    restarts = int(state.get("restarts", 0)) + 1 if state else 0
    ring = ResendRing(config.resend_window)

    def save_state(episodes: int) -> None:
        if config.state_file:
            atomic_write_json(config.state_file, {"episodes_done": episodes, "restarts": restarts,
                                                  "incarnation": rt.incarnation})

    with rt.session() as session:
        # Not maxsize 1: garbage flooding the weights key must not evict the real weights before they are read.
        with subscription(session, weights_key(config.run), maxsize=64, policy="drop_oldest") as weights_in, \
                subscription(session, status_key(config.run, "learner"), maxsize=16,
                             policy="drop_oldest") as learner_status, \
                subscription(session, control_key(config.run), maxsize=64, policy="drop_oldest") as control_in, \
                MessagePublisher(session, step_key(config.run)) as pub:
            frames = FramePublisher(session, config.run, env, rt.counters) \
                if config.render_frames and enable_rgb(env) else None
            watch = AliveWatch(session, config.run, ("learner", "recorder"))
            slot.watch = IncarnationWatch(session, config.run, "learner")
            save_state(episodes_done)
            rt.ready()
            missing = wait_alive(session, config.run, config.wait_for, config.start_timeout, rt.stop)
            if missing and not rt.stop.is_set():
                rt.log(f"gave up waiting for {sorted(missing)} after {config.start_timeout} s")
                rt.stop.set()
                code = 3
            base = 0  # steps the learner had learned before this incarnation's first step (its version then)
            if restart and not rt.stop.is_set():
                waited = time.monotonic()
                while slot.learner is None and not rt.stop.is_set():
                    rt.tick()
                    slot.on_status(learner_status)
                    slot.adopt(weights_in, timeout=0.05, status=learner_status)
                    if time.monotonic() - waited > config.weights_timeout:
                        rt.log(f"restarted, but no weights after {config.weights_timeout} s; stopping")
                        rt.stop.set()
                        code = 4
                base = slot.version
                rt.event(f"actor restarted (restart {restarts}): continuing at episode {episodes_done} with the "
                         f"learner's weights version {base}", 3)
            env_seed = derive_seed(config.seed, "env" if not restart else f"env-restart-{restarts}")
            obs = env.reset(seed=env_seed % (2**31))[0]
            control = RunControl(config.rate, rt.counters, rt.log)
            next_tick = time.perf_counter()
            t_prev = 0.0
            episode, t_in_episode = episodes_done, 0
            limit = config.max_steps if config.max_steps is not None else float("inf")
            while episode < config.episodes and base + seq < limit and not rt.stop.is_set():
                slot.limit = base + seq + 1
                slot.on_status(learner_status)
                slot.adopt(weights_in, status=learner_status)
                if watch.take() and len(ring):
                    rt.log(f"learner or recorder (re)started: re-sending the last {len(ring)} steps")
                    ring.resend()
                ahead = config.max_lag if config.max_ahead is None else min(config.max_ahead, config.max_lag)
                need = base + seq - ahead
                waited = time.monotonic()
                while slot.version < need and not rt.stop.is_set():
                    slot.adopt(weights_in, timeout=0.05, status=learner_status)
                    rt.tick()  # waiting is progress too (the launcher kills a service whose statuses stop)
                    if watch.take() and len(ring):
                        ring.resend()
                    if time.monotonic() - waited > config.weights_timeout:
                        rt.log(f"no weights >= {need} after {config.weights_timeout} s; stopping")
                        rt.stop.set()
                        code = 4
                if rt.stop.is_set():
                    break
                rt.counters["weights_wait_us"] += int((time.monotonic() - waited) * 1e6)
                if pace(control, control_in, slot, weights_in, learner_status, rt):
                    next_tick = time.perf_counter()  # paused, resumed or re-paced: the tick starts afresh
                if control.end or rt.stop.is_set():
                    break
                if control.period:
                    period = control.period
                    next_tick += period
                    # Wait for the next tick on the weights inbox: weights are adopted as they arrive.
                    while (delay := next_tick - time.perf_counter()) > 0 and not rt.stop.is_set():
                        slot.adopt(weights_in, timeout=min(delay, 0.05), status=learner_status)
                        if control.take(control_in):
                            if control.paused or control.end:
                                break
                            next_tick = time.perf_counter() + control.period
                    if control.paused or control.end:
                        continue  # back to the top: wait there while paused, or end
                    if delay < -period:
                        next_tick = time.perf_counter()  # fell behind: do not try to catch up with a burst
                agent.steps[0] = base + seq  # the schedules (epsilon, alpha_h, exploration stream) at this step
                action = int(agent.act(obs.reshape(1, -1))[0])
                t_action = max(time.time(), t_prev + 1e-6)  # strictly increasing, even if the clock steps back
                t_prev = t_action
                nxt, reward, terminated, truncated, info = env.step(action)
                if terminated or truncated:
                    save_state(episode + 1)  # before the last step goes out: a restart never repeats an episode
                publish_kept(pub, Step(run=config.run, incarnation=rt.incarnation, seq=seq, t_action=t_action,
                                       episode=episode, t_in_episode=t_in_episode, obs=obs.tolist(), action=action,
                                       reward=float(reward), next_obs=np.asarray(nxt).tolist(),
                                       terminated=bool(terminated), truncated=bool(truncated),
                                       weights_version=slot.version,
                                       info={k: float(info[k]) for k in INFO_KEYS if k in info}), ring)
                if frames is not None:
                    frames.publish(seq)
                seq += 1
                t_in_episode += 1
                obs = nxt
                if terminated or truncated:
                    episode += 1
                    t_in_episode = 0
                    obs = env.reset()[0]
                rt.tick()
            rt.counters["episodes"] = episode
            rt.failed = code != 0  # gave up: not the end of the run (the launcher restarts it)
            watch.before_exit(ring, RECORDER_WAIT, rt.log)
            watch.close()
            slot.watch.close()
            if frames is not None:
                frames.close()
    rt.write_stats()
    rt.log(f"stopped after {seq} steps, {episode} episodes")
    return code


def pace(control: RunControl, control_in, slot: WeightsSlot, weights_in, learner_status, rt: ServiceRuntime) -> bool:
    """Apply the person's controls; while paused, wait here (adopting weights). True if anything changed."""
    changed = control.take(control_in)
    while control.paused and not control.end and not rt.stop.is_set():
        slot.adopt(weights_in, timeout=0.05, status=learner_status)
        control.take(control_in)
        rt.tick()
    return changed


def cli(argv: list[str] | None = None) -> int:
    return service_main(ActorConfig, main, argv, "python -m services.actor")


if __name__ == "__main__":
    sys.exit(cli())
