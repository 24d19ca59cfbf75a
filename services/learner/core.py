"""The learner's input handling, without transport: what the live learner does with each Step and Feedback,
and exactly what `replay retrain` does with the recorded ones.

It wraps the core's `TrialBatchAgent` (B = 1) the way the in-process runner does: steps are recorded with
their step number as time (the runner's virtual clock) and their wall-clock time in seconds, with the task
rule's polarity of each (from its `info`: the model of the rated event a learned delay is fitted on). A
teacher's feedback goes through the agent's one door (`StepLoop.credit`, as in the runner), stamped both at its
step-clock time (`StepClock`: its wall-clock stamp placed between the two actions around it) and in seconds, with
the screen its person saw (`shown`, if any). The agent's registry of its teachers' delays decides the rule: the
step clock's assumed lags (`oracle_delay` steps, the paper's), or a delay in seconds (`common.core.delay_model`,
made for each teacher when first heard by `new_delay`, from this config), over the held steps' wall-clock times
or the times the person's screen showed them. Its candidates are the steps shown before it, whatever their
episode.

Per input, in consumption order:

- Step k+1 of the current actor incarnation: place it on the step clock; credit every held feedback now
  placeable (stamped before this action), oldest stamp first; record the step; run the every-b-steps update.
- Feedback: if a step newer than its stamp has arrived, credit it now; otherwise hold it until one does (so it
  is not credited to an older step just because newer steps are still in flight).
- End: held feedback can no longer be placed and is rejected (`after_end`).

Every decision depends only on the ordered inputs (no wall clock, no queue lengths), so the same inputs in
the same order give the same weights bit for bit. The consumption order is written as `IngestEntry`s.
"""

from __future__ import annotations

import collections
import dataclasses
import heapq
from typing import Any

import gymnasium as gym
import numpy as np

from common.agents import make_agent
from common.agents.agent import STATUS_NAMES, StepLoop
from common.agents.config import AgentConfig
from common.config import config_record
from common.envs import make_env, obs_shape
from common.protocol import Feedback, IngestEntry, Step
from common.core.delay_model import FixedDelay, LearnedDelay, delay_estimate, estimate_from_state
from services.common.config import LearnerConfig
from services.learner.books import ScreenCredit, StepClock, decode_feedback, listed_steps
from services.learner.teacher_delays import Profiles
from services.learner.results import FeedbackResult, EpisodeRecord

REJECT_REASONS = ("stale", "too_old", "ignored", "after_end", "actor_restarted")
ROW = np.zeros(1, np.int64)  # the core's one trial, as the step loop's rows


class LearnerCore:
    def __init__(self, config: LearnerConfig):
        self.config = config
        env, self.rule = make_env(config.env, config.layout)
        shape, actions = env.observation_space.shape, env.action_space
        if not shape or not isinstance(actions, gym.spaces.Discrete):
            raise ValueError(f"{config.env}: the learner needs a shaped observation and discrete actions")
        self.obs_dim, self.n_actions = int(shape[0]), int(actions.n)
        env.close()
        if config.agent is None:  # (LearnerConfig's __post_init__ resolves it from the algo)
            raise ValueError("LearnerConfig.agent is not resolved")
        self.agent_config: AgentConfig = config.agent
        # Held steps: those shown in the last `history_s` seconds (the learner does not know the actor's rate), at
        # most `history_max_steps`; or, with history_s 0, the agent's count (the runner's).
        held = config.history_max_steps if config.history_s > 0 else self.agent_config.history_steps
        sized = dataclasses.replace(self.agent_config, history_steps=held)
        self.agent = make_agent([sized], obs_shape(env), self.n_actions, [config.seed])
        self.loop = StepLoop(self.agent)
        self.clock = StepClock(held + len(self.agent_config.assumed_delay_probs) + 2)
        self.screen = ScreenCredit(held)
        self.profiles = Profiles(config.profiles)  # returning people start from their last estimate
        self.agent.delays.new_delay = self.new_delay  # each teacher's delay, made when first heard
        # (made once now: it imports scipy, which at a person's first press stalled a loaded run for 8 s)
        delay_estimate(config.screen_delay, config.screen_credit)
        self.actor: str | None = None
        self.next_seq = 0
        self.teacher_next: dict[str, int] = {}
        self._held: list[tuple[float, int, Feedback, int]] = []  # (t_reaction, arrival, feedback, position)
        self._arrivals = 0
        self.entries: list[IngestEntry] = []  # not yet handed out (see take_entries)
        self.position = 0  # entries written so far
        self.counters: collections.Counter[str] = collections.Counter()
        self.episodes: collections.deque[EpisodeRecord] = collections.deque(maxlen=1000)  # the latest ones
        self.ended = False
        self._ep = self._new_episode_accumulator()

    # -- identity ----------------------------------------------------------------------------------------------
    def config_record(self) -> dict:
        """Everything needed to rebuild this learner (written in the first Ingest message)."""
        return {
            "learner": config_record(self.config),
            "agent": config_record(self.agent_config),
            "obs_dim": self.obs_dim,
            "n_actions": self.n_actions,
        }

    @property
    def steps_learned(self) -> int:
        return int(self.agent.steps[0])

    @property
    def revision(self) -> int:
        """The weights' revision: every Q or H update moves it (a credited feedback's H update too, between
        two steps), so an actor can tell weights that changed without a new step. Checkpointed with the agent."""
        return int(self.agent.q_updates[0] + self.agent.h_updates[0])

    def policy_weights(self) -> dict[str, np.ndarray]:
        return self.agent.policy_weights(0)

    # -- ingest record -----------------------------------------------------------------------------------------
    def _entry(self, kind: str, source: str, seq: int, status: str, t: float) -> int:
        self.entries.append(IngestEntry(kind, source, int(seq), status, max(0.0, float(t))))
        self.position += 1
        return self.position - 1

    def take_entries(self, limit: int | None = None) -> list[IngestEntry]:
        n = len(self.entries) if limit is None else min(limit, len(self.entries))
        out, self.entries = self.entries[:n], self.entries[n:]
        return out

    # -- inputs ------------------------------------------------------------------------------------------------
    def on_step(self, step: Step, t: float = 0.0) -> tuple[list[FeedbackResult], EpisodeRecord | None]:
        """Consume one Step. Returns the feedback resolved by it and the episode it ended (if any)."""
        results: list[FeedbackResult] = []
        if self.ended:
            self._entry("step", step.incarnation, step.seq, "after_end", t)
            self.counters["steps_after_end"] += 1
            return results, None
        if step.incarnation != self.actor:
            if self.actor is not None:
                self.counters["actor_restarts"] += 1
                results += self._reject_held("actor_restarted", t)
                self.agent.forget_history(0)
                self.clock.reset()
                self.screen.reset(retired_actor=self.actor)
                self._ep = self._new_episode_accumulator()
            elif step.seq > 0:
                self.counters["steps_missed_at_start"] += step.seq
            self.actor = step.incarnation
            self.next_seq = step.seq
        if step.seq < self.next_seq:
            self._entry("step", step.incarnation, step.seq, "old", t)
            self.counters["steps_old"] += 1
            return results, None
        status = "learned"
        if step.seq > self.next_seq:
            self.counters["steps_lost"] += step.seq - self.next_seq
            status = "gap"
            self.agent.forget_history(0)  # the steps in between are unknown: no credit across the gap
            self.clock.reset()
            self.screen.reset()
        self.next_seq = step.seq + 1
        self._entry("step", step.incarnation, step.seq, status, t)

        index = self.steps_learned  # this step's time on the step clock (the runner's virtual time)
        self.clock.push(index, step.t_action)
        while self._held and self.clock.placeable(self._held[0][0]):
            _, _, fb, pos = heapq.heappop(self._held)
            results.append(self._credit(fb, pos, t))
        self.loop.step(
            ROW,
            np.asarray(step.obs, np.float32)[None],
            np.array([step.action]),
            np.array([step.reward]),
            np.asarray(step.next_obs, np.float32)[None],
            np.array([float(step.terminated)]),
            np.array([float(index)]),
            np.array([step.episode]),
            np.array([step.t_action]),
            np.array([self.polarity(step)]),
        )
        self.screen.learned(step.seq, index)
        if self.config.history_s > 0:  # the steps shown longer ago than history_s leave the history
            self.agent.history.forget_shown_before(0, step.t_action - self.config.history_s)
            self.screen.forget_before(index + 1 - int(self.agent.history.count[0]))
        for fb, pos in self.screen.release(self.actor, self.next_seq):  # a person's feedback that waited for it
            results.append(self._credit(fb, pos, t))
        self.counters["steps_learned"] += 1

        ep = self._ep
        if ep["episode"] is None:
            ep["episode"] = step.episode
        ep["return"] += float(step.reward)
        ep["steps"] += 1
        ep["t_end"] = step.t_action
        done = None
        if step.terminated or step.truncated:
            done = EpisodeRecord(
                step.incarnation,
                int(ep["episode"]),
                float(ep["return"]),
                int(ep["steps"]),
                int(ep["received"]),
                int(ep["credited"]),
                self.steps_learned,
                float(ep["t_end"]),
            )
            self.episodes.append(done)
            self.counters["episodes"] += 1
            self._ep = self._new_episode_accumulator()
        return results, done

    def on_feedback(self, fb: Feedback, t: float = 0.0) -> list[FeedbackResult]:
        """Consume one Feedback. Returns it resolved, or nothing if it is held."""
        pos = self._entry("feedback", fb.teacher_id, fb.seq, "", t)
        self.counters["feedback_received"] += 1
        self._ep["received"] += 1
        expected = self.teacher_next.get(fb.teacher_id, 0)
        if fb.seq != expected:
            self.counters["feedback_seq_gaps"] += 1
            if fb.seq > expected:
                self.counters["feedback_lost"] += fb.seq - expected
        self.teacher_next[fb.teacher_id] = max(expected, fb.seq + 1)
        if self.ended:
            return [self._outcome(fb, pos, "after_end", t)]
        if fb.shown is not None:
            if self.screen.must_wait(fb, self.actor, self.next_seq):
                self.screen.held.append((fb, pos))
                self.counters["feedback_held"] += 1
                return []
            return [self._credit(fb, pos, t)]
        if self.clock.placeable(fb.t_reaction):
            return [self._credit(fb, pos, t)]
        self._arrivals += 1
        heapq.heappush(self._held, (fb.t_reaction, self._arrivals, fb, pos))
        self.counters["feedback_held"] += 1
        return []

    def idle(self, t: float = 0.0) -> bool:
        """An extra minibatch step between two steps (the service decides when, by the wall clock; the entry
        records it, so the same inputs in the same order still give the same weights). False if none applies."""
        if self.ended or self.steps_learned == 0:
            return False
        self.agent.idle_update()
        self._entry("idle", self.actor or "none", self.steps_learned, "", t)
        self.counters["idle_updates"] += 1
        return True

    def end(self, t: float = 0.0) -> list[FeedbackResult]:
        """No more inputs: held feedback is rejected (`after_end`)."""
        if self.ended:
            return []
        self._entry("end", self.actor or "none", 0, "", t)
        results = self._reject_held("after_end", t)
        self.ended = True
        return results

    def polarity(self, step: Step) -> int:
        """The task's teacher rule on this step (+-1), 0 where its info does not say (a rule that needs what the
        actor did not send)."""
        try:
            value = int(self.rule(step.info))
        except (KeyError, TypeError, ValueError, ArithmeticError):
            return 0
        return value if value in (-1, 1) else 0

    @property
    def delays(self) -> dict[str, LearnedDelay | FixedDelay]:
        """{teacher id: its delay in seconds}: the agent's registry (teachers on the step clock have none)."""
        return self.agent.delays.models[0]

    def new_delay(self, teacher: str, on_screen: bool) -> LearnedDelay | FixedDelay | None:
        """The delay a teacher heard for the first time is credited with (`TeacherDelays.new_delay`): in seconds,
        from `screen_delay` for a person's screen (a returning person's from their profile) or `oracle_delay`; None
        for the step clock's assumed lags (the paper's)."""
        c = self.config
        spec = c.screen_delay if on_screen else c.oracle_delay
        if spec == "steps" and self.agent_config.learn_delay:  # the agent's own setting, as in the runner
            spec = f"learned:{self.agent_config.delay_prior}"
        if spec == "steps":
            return None
        est = delay_estimate(spec, c.screen_credit if on_screen else "onset")
        return self.profiles.load(teacher, est) if on_screen else est

    def delay_summary(self) -> dict:
        """{teacher id: {"median_s", "p10_s", "p90_s", "feedbacks"}} of every teacher credited in seconds;
        those on the step clock say what they assume (`assumed`)."""
        out = {t: d.summary() for t, d in sorted(self.delays.items())}
        assumed = "steps:" + ",".join(f"{p:g}" for p in self.agent_config.assumed_delay_probs)
        for t in sorted(self.teacher_next):
            out.setdefault(t, dict.fromkeys(("median_s", "p10_s", "p90_s")) | {"assumed": assumed, "feedbacks": None})
        return out

    @property
    def held(self) -> int:
        return len(self._held) + len(self.screen.held)

    # -- checkpoint ------------------------------------------------------------------------------------------
    def snapshot(self) -> tuple[dict[str, Any], dict[str, Any]]:
        """Everything that changes while learning, as (tensors: the agent's state, nested; meta: plain JSON).

        Taken between two inputs, with every entry handed out (`take_entries`) so that `position` is the
        number of inputs and outcomes recorded. `restore` on a fresh core with the same config continues
        exactly as this core would (bit for bit)."""
        if self.entries:
            raise RuntimeError("snapshot with entries not yet handed out")
        held = [[t, arrival, fb.encode().decode(), pos] for t, arrival, fb, pos in sorted(self._held)]
        meta = {
            "steps_learned": self.steps_learned,
            "actor": self.actor,
            "next_seq": self.next_seq,
            "teacher_next": dict(self.teacher_next),
            "held": held,
            "arrivals": self._arrivals,
            "position": self.position,
            "counters": dict(self.counters),
            "ended": self.ended,
            "episode": dict(self._ep),
            "clock": [list(self.clock._index), list(self.clock._time)],
            "screen": self.screen.state(),
            "returning": sorted(self.profiles.returning),  # (their delays are the agent's, in its state)
        }
        return self.agent.state_dict(), meta

    def restore(self, tensors: dict[str, Any], meta: dict[str, Any]) -> None:
        self.agent.load_state_dict(tensors)
        if self.steps_learned != int(meta["steps_learned"]):
            raise ValueError("checkpoint: agent step count does not match its metadata")
        self.actor, self.next_seq = meta["actor"], int(meta["next_seq"])
        self.teacher_next = {str(k): int(v) for k, v in meta["teacher_next"].items()}
        self._held = [(float(t), int(a), decode_feedback(fb), int(pos)) for t, a, fb, pos in meta["held"]]
        heapq.heapify(self._held)
        self._arrivals = int(meta["arrivals"])
        self.position = int(meta["position"])
        self.counters = collections.Counter({str(k): int(v) for k, v in meta["counters"].items()})
        self.ended = bool(meta["ended"])
        self._ep = dict(meta["episode"])
        self.clock.reset()
        for i, t in zip(*meta["clock"]):
            self.clock.push(int(i), float(t))
        self.screen.load(meta["screen"])
        for teacher, state in meta.get("delays", {}).items():  # (written before the agent kept them)
            self.delays[str(teacher)] = estimate_from_state(state)
        self.profiles.returning = {str(t) for t in meta.get("returning", [])}  # (their models come from the checkpoint)
        self.entries = []

    # -- internals ---------------------------------------------------------------------------------------------
    def _credit(self, fb: Feedback, pos: int, t: float) -> FeedbackResult:
        before = self.revision
        result = self._credit_once(fb, pos, t)
        if self.revision != before:
            result.revision = self.revision
        return result

    def _credit_once(self, fb: Feedback, pos: int, t: float) -> FeedbackResult:
        """`fb` through the agent's one door, as the runner's feedback goes; what became of it, with the steps it
        went to (a Credit message; the log's scene draws it)."""
        if fb.shown is not None and fb.actor != self.actor:  # a screen of a replaced actor: its steps are gone
            result = self._outcome(fb, pos, "actor_restarted", t, 0, 1.0)
            result.feedback = fb
            return result
        screen = self.screen.of(fb) if fb.shown is not None else None
        # (a press on a screen may come after the newest action: on the step clock it is nowhere, in seconds exact)
        tau = self.clock.to_steps(fb.t_reaction) if self.clock.placeable(fb.t_reaction) else np.nan
        out = self.loop.credit(
            ROW, np.array([tau]), np.array([fb.value]), None, np.array([fb.t_reaction]), [fb.teacher_id], [screen]
        )
        status = STATUS_NAMES[out.status[0]]
        if screen is not None and status == "stale" and np.isnan(screen.step_times).all():
            status = "too_old"  # the reason: every step it was about has left the history
        result = self._outcome(fb, pos, status, t, int(out.steps[0]), float(out.lost[0]))
        result.feedback = fb
        if result.status == "credited":
            positions, weights = self.agent.credited(0)
            times = self.agent.history.times_at(0, positions)
            result.credited = listed_steps(self.screen.seq_of, times, weights)  # (seq_of: recent steps only)
        return result

    def _reject_held(self, reason: str, t: float) -> list[FeedbackResult]:
        results = []
        for fb, pos in self.screen.held:
            results.append(self._outcome(fb, pos, reason, t))
            results[-1].feedback = fb
        self.screen.held = []
        while self._held:
            _, _, fb, pos = heapq.heappop(self._held)
            results.append(self._outcome(fb, pos, reason, t))
        return results

    def _outcome(
        self, fb: Feedback, pos: int, status: str, t: float, steps: int = 0, lost: float = 0.0
    ) -> FeedbackResult:
        self._entry("outcome", fb.teacher_id, fb.seq, status, t)
        self.counters[f"feedback_{status}"] += 1
        if status == "credited":
            self._ep["credited"] += 1
        return FeedbackResult(fb.teacher_id, fb.seq, status, steps, lost, pos)

    @staticmethod
    def _new_episode_accumulator() -> dict[str, Any]:
        return {"episode": None, "return": 0.0, "steps": 0, "received": 0, "credited": 0, "t_end": 0.0}
