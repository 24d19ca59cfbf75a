"""`python -m services.learner`: the learner as a service.

One inbox receives both the actor's steps and every teacher's feedback, in arrival order; the learner
consumes it in that order through `LearnerCore` (credit by timestamp, Q and H updates) and records the order
in Ingest messages (`hitl/<run>/ingest`, first one carrying its config). It publishes Weights (version =
steps learned; revision = Q and H updates made) at least every `weights_every` steps and when it has caught up
and they changed (a press's H update between two steps too), and an EpisodeSummary per episode.

Every input passes the `InputGate` first (docs/faults.md): undecodable bytes, wrong shapes, timestamps far
off, unannounced actor incarnations, unknown teachers, seq jumps are dropped and counted
(`rejected_<reason>`); inputs already consumed (re-sent after a restart) are dropped as duplicates.

Recovery: with `checkpoint`, the whole learning state is saved atomically (`CheckpointSchedule`); a
learner started on an existing checkpoint restores it, then consumes from `catchup_log` (the recorder's
MCAP log, segments and a live file included) every step and feedback beyond it, then what the actor and
teachers re-send on seeing it alive (their last `resend_window` s), then the live inputs; duplicates are
dropped by (incarnation, seq) / (teacher, seq). Its Ingest record continues the old one (`resumed_from`).

End: once the actor has reported 'stopped' with its step count and all those steps are learned, the learner
waits (up to `end_grace` s) until every known teacher has reported 'stopped' and all its feedback has
arrived, then ends the core (held feedback -> after_end), publishes its final weights (version = steps
learned + 1: the state after the last input) and stops. SIGTERM ends at once.

Everything that affects learning depends only on the consumed order; wall-clock decisions here (when to
publish weights, flush Ingest, checkpoint, stop waiting) never touch the learner's state.
"""

from __future__ import annotations

import time

from common.pathtrace import traced
from common.protocol import (
    MAX_INGEST_CREDITS,
    kind_of,
    Credit,
    Feedback,
    Ingest,
    ProtocolError,
    ServiceStatus,
    Step,
    Weights,
)
from services.common.config import LearnerConfig
from services.common.gate import DEDUP_REASON, InputGate, first_time_logger
from common.wire.delivery import ResendRing, publish_kept
from services.common.watches import decoded_statuses
from services.common.runtime import ServiceRuntime
from services.learner.checkpoint import CheckpointSchedule
from services.learner.catchup import StepReorder, catch_up
from services.learner import books
from services.learner.books import Snapshots, credit_message, delay_message, episode_message, publish_credit
from services.learner.core import LearnerCore
from services.learner.end_rule import EndRule
from services.learner.results import PublishedWeights

REVISION_QUIET = 0.02  # s since the last step before weights changed without a new step go out on their own
IDLE_AFTER = 0.05  # s without an input before the learner counts itself idle (idle updates, held weights go out)
QUIET_WAIT = 0.25  # s the learner waits for an input at most when nothing is pending
SLOW_STEPS = 0.2  # s between steps from which the weights of a step wait for the idle burst after it


class Learner:
    """The service around `LearnerCore`: inputs through the gate into the core, Ingest / Weights / EpisodeSummary
    out, checkpoints, and the end rule. Wall-clock decisions here never touch the learner's state."""

    def __init__(
        self,
        config: LearnerConfig,
        rt: ServiceRuntime,
        core: LearnerCore,
        gate: InputGate,
        resumed: dict | None,
        session,
        inbox,
        status,
        publishers: dict,
        watch,
        actors,
        requests,
    ):
        self.config, self.rt, self.core, self.gate, self.resumed = config, rt, core, gate, resumed
        self.session = session
        self.credit_pubs: dict = {}  # per person (console teacher): where their Credit messages go
        self.ingest_credits: list = []  # Credits for the next Ingest message (config.credits_in_ingest)
        self.ingest_listed = 0  # the steps they list
        self.inbox, self.status, self.watch, self.actors, self.requests = inbox, status, watch, actors, requests
        self.idle_left = 0  # extra minibatch steps still allowed before the next step arrives
        self.wpub, self.epub, self.ipub = publishers["weights"], publishers["episode"], publishers["ingest"]
        self.ingest_seq = 0
        self.last_ingest = time.monotonic()  # when Ingest was last flushed
        self.sent_at: dict[int, tuple] = {}  # ingest position of a held feedback -> (when sent, when it arrived)
        self.ring = ResendRing(config.resend_window)
        self.reorder = StepReorder(config.reorder_wait, gate.max_seq_jump)
        spub = publishers["snapshot"]
        self.snaps = Snapshots(
            config.run, rt.incarnation, config.snapshot_every, lambda m: publish_kept(spub, m, self.ring)
        )
        self.note_rejected = first_time_logger(rt.event, "input")
        self.last_weights = PublishedWeights(0 if resumed is None else -1, core.revision)
        self.ckpt = CheckpointSchedule(config, core.steps_learned if resumed else 0, rt)
        self.end = EndRule(config.wait_teachers, config.end_grace, rt)
        self.last_step_at = 0.0  # (monotonic) when the last step arrived
        self.step_gap = 0.0  # s between the last two steps' arrivals

    # -- outputs ---------------------------------------------------------------------------------------------
    def flush_ingest(self) -> None:
        core = self.core
        self.last_ingest = time.monotonic()
        while core.entries or self.ingest_credits:
            index = core.position - len(core.entries)
            entries = core.take_entries(self.config.ingest_batch)
            credits, listed = books.take_credits(self.ingest_credits)
            self.ingest_listed -= listed
            cfg = None
            if self.ingest_seq == 0:
                cfg = core.config_record()
                if self.resumed is not None:
                    cfg["resumed_from"] = {"learner": self.resumed["learner"], "position": self.resumed["position"]}
            publish_kept(
                self.ipub,
                Ingest(
                    run=self.config.run,
                    learner=self.rt.incarnation,
                    seq=self.ingest_seq,
                    index=index,
                    entries=entries,
                    config=cfg,
                    credits=credits or None,
                ),
                self.ring,
            )
            self.ingest_seq += 1

    def current_weights(self, version: int) -> tuple[dict, bytes]:
        tensors = self.core.policy_weights()
        return tensors, Weights(
            run=self.config.run,
            incarnation=self.rt.incarnation,
            version=version,
            revision=self.core.revision,
            t_published=time.time(),
            tensors=tensors,
        ).encode()

    def publish_weights(self, version: int, final: bool = False) -> None:
        t0 = time.perf_counter()
        tensors, data = self.current_weights(version)
        self.wpub.put(data)
        self.last_weights = PublishedWeights(version, self.core.revision, data)
        # The log gets snapshots at a bounded rate, not every version (docs/logs.md).
        (self.snaps.final if final else self.snaps.on_weights)(version, tensors, data)
        self.rt.samples["weights_publish_cost_s"].append(time.perf_counter() - t0)

    def save_checkpoint(self) -> None:
        self.flush_ingest()  # position = entries handed out
        self.ckpt.save(self.core, self.gate)

    def note_latency(self, results, t_sent: float | None = None) -> None:
        """Latency samples: send -> H updated, and how much of it was the wait for a newer step."""
        done = time.time()
        for r in results:
            if r.feedback is not None:  # what became of it: consoles and the log's scene show it
                screen = r.feedback.shown is not None  # a person's screen: their delay estimate goes along
                model = self.core.delays.get(r.feedback.teacher_id) if screen else None
                delay = (
                    None
                    if model is None
                    else delay_message(model, r.feedback.teacher_id in self.core.profiles.returning)
                )
                credit = credit_message(self.config.run, r, self.core.actor, done, delay)
                if credit.teacher_id in self.config.credits_in_ingest:
                    self.ingest_credits.append(credit)
                    self.ingest_listed += len(credit.steps)
                else:
                    publish_credit(self.session, self.credit_pubs, credit)
            t0, t_held = t_sent, None
            if r.received_at in self.sent_at:
                t0, t_held = self.sent_at.pop(r.received_at)
            if r.status == "credited" and t0 is not None:
                self.rt.samples["feedback_to_h_s"].append(done - t0)
                self.rt.samples["feedback_hold_s"].append(0.0 if t_held is None else done - t_held)

    # -- inputs ----------------------------------------------------------------------------------------------
    def reject(self, reason: str, what: str, count: bool = True) -> None:
        if not count:  # catching up: counted by the learner that saw it live (or its checkpoint)
            return
        if reason == DEDUP_REASON:
            self.rt.counters[f"duplicates_{what}"] += 1
        else:
            self.rt.counters[f"rejected_{reason}"] += 1
            self.note_rejected(reason, what)

    def consume(self, msg, now: float, t_recv: float, t_sent: float | None, live: bool = True) -> bool:
        """One decoded input through the gate into the core. True if consumed."""
        if isinstance(msg, Step):
            return self.consume_step(msg, now, t_recv, live)
        if isinstance(msg, Feedback):
            return self.consume_feedback(msg, now, t_recv, t_sent, live)
        return False

    def consume_step(self, msg: Step, now: float, t_recv: float, live: bool) -> bool:
        for inc in self.actors.take():
            self.gate.announce(inc)
        # Ahead of the next seq, it may have overtaken re-sent steps: live, or in the log's order while catching up
        ahead = msg.incarnation == self.gate.actor and msg.seq > (self.gate.next_step or 0)
        if ahead and self.reorder.waits(msg, t_recv, self.gate):
            self.rt.counters["steps_waited"] += 1
            return True
        learned = self.learn_step(msg, now, t_recv, live)
        for step, t_step in self.reorder.following(self.gate) if self.reorder.held else ():
            self.learn_step(step, now, t_step, live)
        return learned

    def release_waiting(self) -> None:
        """The steps that waited too long for those before them: consumed in seq order, gaps and all."""
        for step, t_recv in self.reorder.take_all():
            self.learn_step(step, time.time(), t_recv, True)

    def learn_step(self, msg: Step, now: float, t_recv: float, live: bool) -> bool:
        # (TEST ONLY: --debug-drop-steps drops the first steps as if their actor's announcement came late)
        dropping = live and self.rt.counters["rejected_unknown_incarnation"] < self.config.debug_drop_steps
        reason = "unknown_incarnation" if dropping else self.gate.admit_step(msg, t_recv)
        if reason == "unknown_incarnation" and live and not dropping:
            self.drain_status()  # its announcement may be waiting in the other queue
            reason = self.gate.admit_step(msg, t_recv)
        if reason:
            self.reject(reason, "step", count=live)
            return False
        results, ep = self.core.on_step(msg, now)
        self.note_latency(results)
        if ep is not None:
            publish_kept(self.epub, episode_message(self.config.run, ep), self.ring)
            self.snaps.on_episode(self.core.steps_learned, self.core.policy_weights())
        if self.config.debug_update_sleep:
            time.sleep(self.config.debug_update_sleep)
        return True

    def consume_feedback(self, msg: Feedback, now: float, t_recv: float, t_sent: float | None, live: bool) -> bool:
        reason = self.gate.admit_feedback(msg, t_recv)
        if reason == "unknown_teacher" and live:
            self.drain_status()
            reason = self.gate.admit_feedback(msg, t_recv)
        if reason:
            self.reject(reason, "feedback", count=live)
            if reason == DEDUP_REASON and live and msg.teacher_id not in self.config.credits_in_ingest:
                publish_credit(
                    self.session,
                    self.credit_pubs,
                    Credit(  # acknowledges a page's re-sent press
                        run=self.config.run,
                        teacher_id=msg.teacher_id,
                        seq=msg.seq,
                        value=msg.value,
                        status="duplicate",
                        t_reaction=msg.t_reaction,
                        t_credited=time.time(),
                        actor=msg.actor,
                        steps=[],
                        lost_mass=0.0,
                    ),
                )
            return False
        self.end.teachers_known.add(msg.teacher_id)
        results = self.core.on_feedback(msg, now)
        if not results:  # held: remember when it was sent and when it arrived
            self.sent_at[self.core.position - 1] = (t_sent, now)
        self.note_latency(results, t_sent=t_sent)
        return True

    def on_status(self, st: ServiceStatus) -> None:
        self.gate.on_status(st)
        self.end.on_status(st, self.gate.actor)

    def drain_status(self) -> None:
        for st in decoded_statuses(self.status, self.rt.counters):
            self.on_status(st)

    # -- the loop --------------------------------------------------------------------------------------------
    @traced("learner.input")
    def take_input(self) -> None:
        """One input from the inbox (if any) into the core; publish weights and flush Ingest when due."""
        if self.reorder.held and self.reorder.due_in() == 0:
            self.release_waiting()
        got = self.inbox.get(timeout=min(self.wait_s(), self.reorder.due_in() if self.reorder.held else QUIET_WAIT))
        if got is None:  # nothing for 50 ms: a paced run's idle time, for up to idle-updates extra steps
            if self.idle_left > 0 and self.core.idle(time.time()):
                self.idle_left -= 1
                if self.idle_left > 0:  # a burst under way: its weights and Ingest go out once, at its end
                    return
            else:
                self.idle_left = 0  # (no update applies: before the first step, after the end)
            self.publish_weights_if_due(idle=True)  # (the burst's end, or a press held back as steps streamed)
            if self.ingest_due_in() == 0:
                self.flush_ingest()
            return
        if got.key.endswith("/step"):  # a new step: a new budget of idle-time updates before the next one
            self.idle_left = self.config.idle_updates
            self.step_gap = time.monotonic() - self.last_step_at
            self.last_step_at = time.monotonic()
        now = time.time()
        t_sent = got.t_zenoh if got.t_zenoh is not None else got.t_recv
        try:
            msg = got.decode()
        except ProtocolError as e:
            self.reject(e.reason, kind_of(got.key))
        else:
            self.consume(msg, now, got.t_recv, t_sent)
        # At a person's pace the weights wait for the idle burst due 50 ms on (one Weights a step, not two); the
        # actor's next step, in lockstep, needs them only SLOW_STEPS from now.
        burst_soon = self.idle_left == self.config.idle_updates > 0 and self.step_gap >= SLOW_STEPS
        self.publish_weights_if_due(idle=len(self.inbox) == 0 and not burst_soon)
        if (
            len(self.core.entries) >= self.config.ingest_batch
            or len(self.ingest_credits) >= MAX_INGEST_CREDITS
            or self.ingest_listed >= books.INGEST_LISTED_STEPS
            or self.ingest_due_in() == 0
        ):
            self.flush_ingest()

    def ingest_due_in(self) -> float:
        return max(0.0, self.last_ingest + self.config.ingest_period - time.monotonic())

    def wait_s(self) -> float:
        """How long to wait for an input: between two updates of an idle burst, only a look; 50 ms with something
        pending (a burst to start, weights to send); else until Ingest, a status or a checkpoint is due."""
        if 0 < self.idle_left < self.config.idle_updates:
            return 0.0
        last = self.last_weights
        if self.idle_left or self.core.steps_learned != last.version or self.core.revision != last.revision:
            return IDLE_AFTER
        if self.core.entries or self.ingest_credits:  # (a status or checkpoint waits for it: at most QUIET_WAIT)
            return min(QUIET_WAIT, self.ingest_due_in())
        return max(0.0, min(QUIET_WAIT, self.rt.status_due_in(), self.ckpt.due_in(self.core.steps_learned)))

    def publish_weights_if_due(self, idle: bool) -> None:
        """New weights go out when they changed and nothing else is waiting, or after `weights_every` steps while
        catching up; a change without a new step (a press, an idle update) waits while steps stream in."""
        v, last = self.core.steps_learned, self.last_weights
        if v != last.version:
            if idle or v - last.version >= self.config.weights_every:
                self.publish_weights(v)
        elif self.core.revision != last.revision and idle and time.monotonic() - self.last_step_at >= REVISION_QUIET:
            self.publish_weights(v)

    def on_restarts(self) -> None:
        """A (re)started recorder gets the recent outputs again; a restarted actor gets the current policy."""
        for name in self.watch.take():
            if name == "recorder" and len(self.ring):
                self.rt.event(f"recorder (re)started: re-sending {len(self.ring)} recent ingest/episode messages")
                self.ring.resend()
                if self.last_weights.data is not None:
                    self.wpub.put(self.last_weights.data)
            elif name == "actor":  # (even before any step is learned: a restarted actor waits for weights)
                self.publish_weights(self.core.steps_learned)

    def finished(self) -> bool:
        return self.end.finished(self.core, len(self.inbox), self.gate.actor)

    def run(self) -> None:
        """Catch up (after a restart), then consume live inputs until the end rule or SIGTERM; then end."""
        config, core = self.config, self.core
        self.rt.ready()  # subscribed: actor and teachers re-send their recent messages to a restarted learner
        if self.resumed is not None or config.catchup_log:
            catch_up(config, self.rt, core, self.consume, self.on_status, self.resumed)
        if self.resumed is not None:
            self.flush_ingest()
            self.publish_weights(core.steps_learned)
        while not self.rt.stop.is_set():
            self.take_input()
            self.drain_status()
            if len(self.requests):
                self.snaps.on_requests(
                    self.requests.drain(), core.steps_learned, lambda: self.current_weights(core.steps_learned)
                )
            self.on_restarts()
            if self.ckpt.due(core.steps_learned):
                self.save_checkpoint()
            self.core.profiles.save(self.core.delays)  # returning people's profiles, every 10 s while they move
            if self.finished():
                break
            self.rt.tick()
        self.ckpt.close()
        self.release_waiting()
        self.note_latency(core.end(time.time()))
        self.rt.counters["profiles_written"] += core.profiles.save(core.delays, force=True)
        self.rt.counters["profiles_damaged"] += core.profiles.damaged
        self.flush_ingest()
        self.publish_weights(core.steps_learned + 1, final=True)
        # the final weights too, if the recorder must get them again
        if self.last_weights.data is not None:
            self.ring.add(self.wpub, self.last_weights.data)
        self.watch.before_exit(self.ring, 20.0, self.rt.log)
        for pub in self.credit_pubs.values():
            pub.close()
        self.rt.counters.update({f"inbox_{k}": v for k, v in self.inbox.snapshot().items()})
        self.rt.counters["resent"] = self.ring.resent
