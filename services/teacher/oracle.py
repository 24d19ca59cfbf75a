"""The simulated teacher's timing, without transport: the core's `SimulatedObserver` reacting to Steps.

Two clocks (`TeacherConfig.clock`):

- ``steps`` (for an actor running as fast as possible): the observer reacts on the step clock exactly as in
  the in-process runner: to step k with true lag d at step time k + d + 0.5. The reaction is sent as soon as
  step k+d+1 has been seen, stamped at the wall time half-way between actions k+d and k+d+1. So a lag of d
  steps is d steps whatever the actor's speed, and the learner, placing the stamp back on its own step
  clock, finds k + d + 0.5 again.
- ``wall`` (for a fixed actor rate, e.g. a human watching): the reaction to step k with lag d is sent at
  wall time t_action(k) + (d + 0.5) * step_unit, stamped with that time: a real-time delay.

When the actor stops, reactions not yet due are dropped (never sent): the in-process runner, too, delivers
nothing after the last step's tick except reactions stamped before the next action, which no live learner
could place without a next action.
"""

from __future__ import annotations

import collections
import dataclasses
import heapq

from common.envs import make_env
from common.core.observer import FeedbackEvent, SimulatedObserver
from common.protocol import Step
from common.core.seeding import derive_seed
from services.common.config import TeacherConfig
from services.learner.books import StepClock
from services.teacher.follow import StepFollower


@dataclasses.dataclass(frozen=True)
class Reaction:
    t_reaction: float  # wall-clock stamp
    value: int
    intended: int
    ref_seq: int
    lag_steps: int


class OracleTeacher:
    def __init__(self, config: TeacherConfig):
        self.config = config
        _, rule = make_env(config.env, config.layout, config.teacher_rule)
        obs_cfg = config.observer
        unit = 1.0 if config.clock == "steps" else config.step_unit
        self.observer = SimulatedObserver(obs_cfg, rule, derive_seed(config.seed, "observer"), unit)
        self.clock = StepClock(len(obs_cfg.delay_probs) + 8)
        self._pending: list[tuple[float, int, FeedbackEvent, int]] = []  # (due key, counter, event, ref_seq)
        self._counter = 0
        self.counters: collections.Counter[str] = collections.Counter()
        self.follower = StepFollower(self.counters)

    @property
    def actor(self) -> str | None:
        return self.follower.actor

    @property
    def next_seq(self) -> int:
        return self.follower.next_seq

    def on_step(self, step: Step) -> list[Reaction]:
        """See one step; returns reactions due now on the step clock (always empty for the wall clock)."""
        restarted, news = self.follower.follow(step)
        if restarted:
            self.counters["reactions_dropped"] += len(self._pending)
            self._pending.clear()
            self.clock.reset()
        if not news:
            return []
        self.counters["steps_seen"] += 1
        self.clock.push(step.seq, step.t_action)
        t = float(step.seq) if self.config.clock == "steps" else step.t_action
        event = self.observer.react(t, step.info, step.episode, step.seq, step_ref=step.seq)
        if event is not None:
            self._counter += 1
            heapq.heappush(self._pending, (event.t_reaction, self._counter, event, step.seq))
            self.counters["reactions"] += 1
        if self.config.clock == "steps":
            return self._due_on_steps()
        return []

    def _due_on_steps(self) -> list[Reaction]:
        out = []
        while self._pending:
            tau = self._pending[0][0]
            t_wall = self.clock.to_wall(tau)
            if t_wall is None:
                oldest = self.clock.oldest_index
                if self.clock.newest_index is not None and oldest is not None and tau < oldest:
                    heapq.heappop(self._pending)  # its steps fell out of the clock (after a gap): lost
                    self.counters["reactions_dropped"] += 1
                    continue
                break
            _, _, ev, ref = heapq.heappop(self._pending)
            out.append(Reaction(t_wall, ev.value, ev.intended, ref, ev.lag_steps))
        return out

    def next_due(self) -> float | None:
        """Wall clock: the time of the next pending reaction (None when none is pending)."""
        if self.config.clock != "wall" or not self._pending:
            return None
        return self._pending[0][0]

    def due(self, now: float) -> list[Reaction]:
        """Wall clock: reactions whose time has come."""
        out: list[Reaction] = []
        if self.config.clock != "wall":
            return out
        while self._pending and self._pending[0][0] <= now:
            _, _, ev, ref = heapq.heappop(self._pending)
            out.append(Reaction(ev.t_reaction, ev.value, ev.intended, ref, ev.lag_steps))
        return out

    def finish(self, now: float) -> list[Reaction]:
        """The actor stopped: reactions stamped before its last action are returned, the rest dropped (counted):
        nothing after the last action could be placed by the learner."""
        newest = self.clock.newest_time
        out = self.due(min(now, newest) if newest is not None else now) if self.config.clock == "wall" else []
        self.counters["reactions_dropped_at_end"] += len(self._pending)
        self._pending.clear()
        return out
