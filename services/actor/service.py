"""`python -m services.actor`: steps the environment and publishes every Step.

The actor holds its own `TrialBatchAgent` (B = 1, the run's seed) only to act: epsilon-greedy on
alpha_q Q + alpha_h H with the schedules at its step count, exactly as the in-process runner's agent acts.
Its networks are the newest Weights it has received (never older ones after newer: newer in (version,
revision), so weights changed between two steps by a feedback's H update or an idle update are taken too, and
the next action uses them); before the first Weights arrive they are the seed's initial networks, which are the
learner's too (version 0).

A Weights version is the number of steps the learner has learned from. With `max_ahead` = m the actor
acts at step k only once it holds a version >= k - m (m = 0 is the runner's lockstep: every action sees the
update of the step before it).

Restarts (docs/faults.md): with `state_file`, the number of finished episodes is saved (in place, whole after a
kill: services/common/progress.py) before each episode's last step is published. An actor started on an existing
state file is a new incarnation that continues the run: it starts the next episode (the broken one is closed by
the learner), waits for the current weights of an announced learner first and counts its schedules and lockstep
from that version on. Weights are accepted only from a learner incarnation that a ServiceStatus announced, with a
plausible timestamp and the right tensor names and shapes; everything else is dropped and counted. Steps of the last
`resend_window` s are published again when a learner or recorder (re)starts. The weights are followed by
`services.common.gate.WeightsFollower`, the console's too.

Pace: `rate` steps per second (a fixed period, for a human watching) or as fast as possible (0). Each Step
carries the actor's incarnation, a contiguous seq, the wall time of the action (strictly increasing), the
episode, the weights version it acted with, and the env's `info` whole (numbers; a key a Step cannot carry stops the
run with an error naming it) for the simulated teacher's rule.
"""

from __future__ import annotations

import time

import numpy as np

from common.agents import make_agent
from common.envs import make_env, n_actions, obs_shape
from common.pathtrace import traced
from common.protocol import InfoError, Step, control_key, status_key, step_info, step_key, weights_key
from services.actor.control import RunControl
from services.actor.render import FramePublisher, enable_rgb
from common.core.seeding import derive_seed
from services.common.config import ActorConfig
from common.wire.delivery import ResendRing, publish_kept
from services.common.watches import AliveWatch
from services.common.gate import IncarnationWatch, WeightsFollower
from services.common.progress import ProgressFile
from services.common.runtime import ServiceRuntime, TerminalError, apply_torch_threads, service_main, wait_alive

RECORDER_WAIT = 20.0  # s to wait at the end for a recorder that is restarting (it must get what it missed)

CONTROL_LOOK = 0.25  # s between two looks at the controls (pause, rate, end) while waiting for a tick


class Actor:
    """One incarnation of the actor: its environment, acting agent, weights slot and resend ring.

    `main` opens the session and its inboxes, hands them to `connect`, then calls `start` (wait for the
    services it needs; after a restart, for the learner's current weights) and `run` (the step loop).
    """

    def __init__(self, config: ActorConfig, rt: ServiceRuntime):
        self.config, self.rt = config, rt
        self.env, _ = make_env(config.env, config.layout)
        if config.episode_steps is not None:  # the registry's envs truncate at their `max_steps`
            if not hasattr(self.env, "max_steps"):
                raise ValueError(f"--episode-steps: {config.env} has no max_steps to set")
            self.env.max_steps = config.episode_steps
        self.agent = make_agent([config.agent], obs_shape(self.env), n_actions(self.env), [config.seed])
        spec = {k: tuple(v.shape) for k, v in self.agent.policy_weights(0).items()}
        self.slot = WeightsFollower(self.agent, spec, rt)
        self.seq = 0  # steps this incarnation published
        self.ring = ResendRing(config.resend_window)
        rt.set_counters_source(
            lambda: {"steps_published": self.seq, "weights_version": self.slot.version, "resent": self.ring.resent}
        )
        self.code = 0
        self.progress = ProgressFile(config.state_file) if config.state_file else None
        state = self.progress.read() if self.progress else None
        self.restart = state is not None
        self.episode = int(state["episodes_done"]) if state else 0  # episodes finished (by every incarnation)
        self.restarts = int(state.get("restarts", 0)) + 1 if state else 0
        self.base = 0  # steps the learner had learned before this incarnation's first step (its version then)

    def connect(self, session, weights_in, learner_status, control_in, pub) -> None:
        """Take the open inboxes and the step publisher; start the frames and the liveliness watches."""
        config = self.config
        self.weights_in, self.learner_status, self.control_in, self.pub = weights_in, learner_status, control_in, pub
        self.frames = (
            FramePublisher(session, config.run, self.env, self.rt.counters)
            if config.render_frames and enable_rgb(self.env)
            else None
        )
        self.watch = AliveWatch(session, config.run, ("learner", "recorder"))
        self.learner_watch = IncarnationWatch(session, config.run, "learner")
        self.slot.watch = self.learner_watch

    def save_state(self, episodes: int) -> None:
        if self.progress:
            self.progress.write(
                {"episodes_done": episodes, "restarts": self.restarts, "incarnation": self.rt.incarnation}
            )

    def give_up(self, code: int, why: str) -> None:
        self.rt.log(why)
        self.rt.stop.set()
        self.code = code

    @traced("actor.weights")
    def adopt_weights(self, timeout: float | None = None) -> bool:
        return self.slot.adopt(self.weights_in, timeout=timeout, status=self.learner_status)

    def start(self, session) -> None:
        """Announce readiness, wait for the services named in `wait_for`; a restart waits for weights too."""
        config, rt, slot = self.config, self.rt, self.slot
        self.save_state(self.episode)
        rt.ready()
        missing = wait_alive(session, config.run, config.wait_for, config.start_timeout, rt.stop)
        if missing and not rt.stop.is_set():
            self.give_up(3, f"gave up waiting for {sorted(missing)} after {config.start_timeout} s")
        if self.restart and not rt.stop.is_set():
            waited = time.monotonic()
            while slot.learner is None and not rt.stop.is_set():
                rt.tick()
                slot.on_status(self.learner_status)
                self.adopt_weights(timeout=0.05)
                if time.monotonic() - waited > config.weights_timeout:
                    self.give_up(4, f"restarted, but no weights after {config.weights_timeout} s; stopping")
            self.base = slot.version
            rt.event(
                f"actor restarted (restart {self.restarts}): continuing at episode {self.episode} with the "
                f"learner's weights version {self.base}",
                3,
            )

    def wait_for_version(self) -> None:
        """Lockstep: wait until the weights are at most `max_ahead` (capped by `max_lag`) steps behind."""
        config, rt, slot = self.config, self.rt, self.slot
        ahead = config.max_lag if config.max_ahead is None else min(config.max_ahead, config.max_lag)
        need = self.base + self.seq - ahead
        waited = resent = time.monotonic()
        while slot.version < need and not rt.stop.is_set():
            self.adopt_weights(timeout=0.05)
            rt.tick()  # waiting is progress too (the launcher kills a service whose statuses stop)
            if self.watch.take() and len(self.ring):
                self.ring.resend()
            if time.monotonic() - resent > config.stall_resend:
                self.resend_unlearned()
                resent = time.monotonic()
            if time.monotonic() - waited > config.weights_timeout:
                self.give_up(4, f"no weights >= {need} after {config.weights_timeout} s; stopping")
        if not rt.stop.is_set():
            rt.counters["weights_wait_us"] += int((time.monotonic() - waited) * 1e6)

    def resend_unlearned(self) -> None:
        """The steps the newest weights have not learned, again (the learner drops those it has: duplicates)."""
        unlearned = self.base + self.seq - self.slot.version
        if unlearned > 0 and len(self.ring):
            n = self.ring.resend(last=unlearned)
            self.rt.counters["stall_resends"] += 1
            self.rt.log(f"no fresh weights for {self.config.stall_resend} s: re-sent the last {n} steps")

    def wait_for_tick(self, control: RunControl, next_tick: float) -> tuple[float, bool]:
        """At a fixed pace, wait for the next tick, adopting weights as they arrive.

        Returns the new tick and whether to act now (False: paused or ended meanwhile).
        """
        period = control.period
        next_tick += period
        while (delay := next_tick - time.perf_counter()) > 0 and not self.rt.stop.is_set():
            self.adopt_weights(timeout=min(delay, CONTROL_LOOK))
            if control.take(self.control_in):
                if control.paused or control.end:
                    break
                next_tick = time.perf_counter() + control.period
        if control.paused or control.end:
            return next_tick, False
        if delay < -period:
            next_tick = time.perf_counter()  # fell behind: do not try to catch up with a burst
        return next_tick, True

    def act_and_publish(self, obs: np.ndarray, t_prev: float, t_in_episode: int):
        """Act on `obs`, step the environment, publish the Step. Returns (next obs, t_action, episode ended)."""
        action = self.next_action(obs)
        t_action = max(time.time(), t_prev + 1e-6)  # strictly increasing, even if the clock steps back
        return self.step_and_publish(obs, action, t_action, t_in_episode)

    @traced("actor.act")
    def next_action(self, obs: np.ndarray) -> int:
        """The action on `obs` with the newest weights: the end of a step's and of a press's path."""
        self.agent.steps[0] = self.base + self.seq  # the schedules (epsilon, alpha_h, exploration stream) now
        self.adopt_weights()  # what arrived since the wait (a press's H update just before this action)
        return int(self.agent.act(obs.reshape(1, -1))[0])

    @traced("actor.step")
    def step_and_publish(self, obs: np.ndarray, action: int, t_action: float, t_in_episode: int):
        """Step the environment with `action`, publish the Step. Returns (next obs, t_action, episode ended)."""
        config = self.config
        nxt, reward, terminated, truncated, info = self.env.step(action)
        try:
            info = step_info(info)  # whole: the teacher's rule reads what the in-process runner's rule reads
        except InfoError as exc:  # the env's own output: a restart would send it again
            self.rt.event(f"{config.env}: {exc}", 5)
            raise TerminalError(f"{config.env}: {exc}") from None
        if terminated or truncated:
            self.save_state(self.episode + 1)  # before the last step goes out: a restart never repeats an episode
        publish_kept(
            self.pub,
            Step(
                run=config.run,
                incarnation=self.rt.incarnation,
                seq=self.seq,
                t_action=t_action,
                episode=self.episode,
                t_in_episode=t_in_episode,
                obs=obs.tolist(),
                action=action,
                reward=float(reward),
                next_obs=np.asarray(nxt).tolist(),
                terminated=bool(terminated),
                truncated=bool(truncated),
                weights_version=self.slot.version,
                weights_revision=self.slot.revision,
                info=info,
            ),
            self.ring,
        )
        if self.frames is not None:
            self.frames.publish(self.seq)
        self.seq += 1
        return nxt, t_action, bool(terminated or truncated)

    def run(self) -> None:
        """Act, step and publish until the episodes (or `max_steps`) are done, a stop or the person's end."""
        config, rt, slot = self.config, self.rt, self.slot
        env_seed = derive_seed(config.seed, "env" if not self.restart else f"env-restart-{self.restarts}")
        obs = self.env.reset(seed=env_seed % (2**31))[0]
        control = RunControl(config.rate, rt.counters, rt.log, paused=config.start_paused and not self.restart)
        next_tick = time.perf_counter()
        t_prev = 0.0
        t_in_episode = 0
        limit = config.max_steps if config.max_steps is not None else float("inf")
        while self.episode < config.episodes and self.base + self.seq < limit and not rt.stop.is_set():
            slot.limit = self.base + self.seq + 1
            slot.on_status(self.learner_status)
            self.adopt_weights()
            if self.watch.take() and len(self.ring):
                rt.log(f"learner or recorder (re)started: re-sending the last {len(self.ring)} steps")
                self.ring.resend()
            self.wait_for_version()
            if rt.stop.is_set():
                break
            if pace(control, self.control_in, slot, self.weights_in, self.learner_status, rt):
                next_tick = time.perf_counter()  # paused, resumed or re-paced: the tick starts afresh
            if control.end or rt.stop.is_set():
                break
            if control.period:
                next_tick, act_now = self.wait_for_tick(control, next_tick)
                if not act_now:
                    continue  # back to the top: wait there while paused, or end
            obs, t_prev, ended = self.act_and_publish(obs, t_prev, t_in_episode)
            t_in_episode += 1
            if ended:
                self.episode += 1
                t_in_episode = 0
                obs = self.env.reset()[0]
            rt.tick()

    def close(self) -> None:
        """Report how the run ended, let a restarting recorder catch up, close the watches and frames."""
        self.rt.counters["episodes"] = self.episode
        self.rt.failed = self.code != 0  # gave up: not the end of the run (the launcher restarts it)
        self.watch.before_exit(self.ring, RECORDER_WAIT, self.rt.log)
        self.watch.close()
        self.learner_watch.close()
        if self.frames is not None:
            self.frames.close()


def main(config: ActorConfig) -> int:
    from common.wire.transport import MessagePublisher, subscription

    apply_torch_threads()
    rt = ServiceRuntime("actor", config)
    actor = Actor(config, rt)
    with rt.session() as session:
        # Not maxsize 1: garbage flooding the weights key must not evict the real weights before they are read.
        with (
            subscription(session, weights_key(config.run), maxsize=64, policy="drop_oldest") as weights_in,
            subscription(
                session, status_key(config.run, "learner"), maxsize=16, policy="drop_oldest"
            ) as learner_status,
            subscription(session, control_key(config.run), maxsize=64, policy="drop_oldest") as control_in,
            MessagePublisher(session, step_key(config.run)) as pub,
        ):
            actor.connect(session, weights_in, learner_status, control_in, pub)
            actor.start(session)
            actor.run()
            actor.close()
    rt.write_stats()
    rt.log(f"stopped after {actor.seq} steps, {actor.episode} episodes")
    return actor.code


def pace(
    control: RunControl, control_in, slot: WeightsFollower, weights_in, learner_status, rt: ServiceRuntime
) -> bool:
    """Apply the person's controls; while paused, wait here (adopting weights). True if anything changed."""
    changed = control.take(control_in)
    while control.paused and not control.end and not rt.stop.is_set():
        # A look at the controls every CONTROL_LOOK s, as between two ticks (every 50 ms, a paused actor took
        # 0.39 % of a core doing nothing: 20 wake-ups a second); weights still land the moment they arrive.
        slot.adopt(weights_in, timeout=CONTROL_LOOK, status=learner_status)
        control.take(control_in)
        rt.tick()
    return changed


def cli(argv: list[str] | None = None) -> int:
    return service_main(ActorConfig, main, argv, "python -m services.actor")
