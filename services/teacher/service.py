"""`python -m services.teacher`: the simulated teacher as a service.

Subscribes to the actor's steps, lets `OracleTeacher` (the core's SimulatedObserver on the chosen clock)
react, and publishes each reaction as a Feedback on `hitl/<run>/feedback/<teacher_id>` (source `oracle`,
own contiguous seq). Stops when the actor has stopped and every step it published has been seen (or on
SIGTERM); its final status carries `feedback_published`, which the learner waits for.

Faults (docs/faults.md): steps pass the `InputGate` (announced actor incarnation, shapes, timestamps, dedup);
with `state_file` the next seq survives a restart (so `feedback_published` counts every incarnation and no
seq is used twice); the feedback of the last `resend_window` s is re-sent when a learner or recorder
(re)starts. A teacher that crashes is simply silent meanwhile (the paper's unsustainability). A teacher rule that
fails (raises, or answers other than +1/-1) stops the run with the rule's name and its error (exit code
`TERMINAL_EXIT`: the launcher does not restart a service that would fail the same way).
"""

from __future__ import annotations

import sys
import time

import numpy as np

from common.envs import make_env, n_actions, obs_shape
from common.envs.rules import RuleError
from common.protocol import Feedback, ProtocolError, Step, feedback_key, status_key, step_key
from services.common.config import TeacherConfig
from services.common.gate import DEDUP_REASON, IncarnationWatch, InputGate, first_time_logger
from common.wire.delivery import ResendRing, publish_kept
from services.common.watches import AliveWatch, decoded_statuses
from services.common.progress import ProgressFile
from services.common.runtime import ServiceRuntime, TerminalError, service_main
from services.teacher.oracle import OracleTeacher

STEPS_AFTER_STOP_TIMEOUT = 5.0  # s to wait for steps still in flight once the actor reported 'stopped'


class Teacher:
    """The teacher service's state: the oracle, the step gate, the next feedback seq and the resend ring.

    `main` opens the session and its inboxes, hands them to `connect`, then calls `run` (take steps, send
    the reactions that fall due, follow the actor's statuses) until the actor's every step has been seen.
    """

    def __init__(self, config: TeacherConfig, rt: ServiceRuntime):
        self.config, self.rt = config, rt
        self.core = OracleTeacher(config)
        self.progress = ProgressFile(config.state_file) if config.state_file else None
        self.state = self.progress.read() if self.progress else None
        self.published = int(self.state["next_seq"]) if self.state else 0  # the next feedback seq
        self.ring = ResendRing(config.resend_window)
        env, _ = make_env(config.env, config.layout)
        self.gate = InputGate(
            int(np.prod(obs_shape(env))), n_actions(env), max_future=config.max_future, max_past=config.max_past
        )
        env.close()
        self.note_rejected = first_time_logger(rt.event, "step")
        rt.set_counters_source(
            lambda: {**self.core.counters, "feedback_published": self.published, "resent": self.ring.resent}
        )
        self.actor_final: int | None = None  # steps the actor reported when it stopped
        self.stopped_at = 0.0  # monotonic time of that report

    def connect(self, session, steps, status, pub) -> None:
        """Take the open inboxes and the feedback publisher; start the liveliness watches."""
        self.steps, self.status, self.pub = steps, status, pub
        self.actors = IncarnationWatch(session, self.config.run, "actor")
        self.watch = AliveWatch(session, self.config.run, ("learner", "recorder"))

    def send(self, reactions) -> None:
        config = self.config
        for r in reactions:
            seq = self.published
            if self.progress:  # first: a crash right after must not reuse this seq
                self.progress.write({"next_seq": seq + 1})
            publish_kept(
                self.pub,
                Feedback(
                    run=config.run,
                    teacher_id=config.teacher_id,
                    seq=seq,
                    t_reaction=r.t_reaction,
                    value=r.value,
                    source="oracle",
                    ref_seq=r.ref_seq,
                    intended=r.intended,
                ),
                self.ring,
            )
            self.published += 1
            self.rt.samples["send_delay_s"].append(time.time() - r.t_reaction)

    def admitted(self, received) -> Step | None:
        """The next step if it passes the gate (else counted and dropped)."""
        rt = self.rt
        try:
            msg = received.decode()
        except ProtocolError as e:
            rt.counters[f"rejected_{e.reason}"] += 1
            self.note_rejected(e.reason, "")
            return None
        for inc in self.actors.take():
            self.gate.announce(inc)
        reason = self.gate.admit_step(msg, received.t_recv)
        if reason == DEDUP_REASON:
            rt.counters["duplicates_step"] += 1
        elif reason:
            rt.counters[f"rejected_{reason}"] += 1
            self.note_rejected(reason, "")
        return None if reason else msg

    def take_step(self) -> None:
        """Wait for the next step (at most until the next reaction falls due) and let the oracle react."""
        timeout = 0.05
        nd = self.core.next_due()
        if nd is not None:
            timeout = min(timeout, max(0.0, nd - time.time()))
        got = self.steps.get(timeout=timeout)
        if got is not None:
            step = self.admitted(got)
            if step is not None:
                self.rt.samples["step_transit_s"].append(got.t_recv - step.t_action)
                self.rt.samples["step_queued_s"].append(time.time() - got.t_recv)
                self.send(self.react(step))

    def react(self, step: Step) -> list:
        """The oracle's reactions due now; a rule that fails stops the run (a restart would fail the same way)."""
        try:
            return self.core.on_step(step)
        except RuleError as exc:
            self.rt.event(str(exc), 5)
            raise TerminalError(str(exc)) from None

    def follow_actor(self) -> None:
        """Read the actor's statuses: announcements for the gate, and how many steps it sent once stopped."""
        for st in decoded_statuses(self.status, self.rt.counters):
            self.gate.on_status(st)
            if st.state == "stopped" and self.actor_final is None and st.incarnation in (None, self.gate.actor):
                self.actor_final = int(st.counters.get("steps_published", 0))
                self.stopped_at = time.monotonic()

    def all_steps_seen(self) -> bool:
        """The actor has stopped and its every step was seen (or the wait for steps in flight ran out)."""
        if self.actor_final is None or len(self.steps) != 0:
            return False
        seen = self.core.next_seq if self.core.actor == self.gate.actor else 0  # this actor's steps seen (or lost)
        if seen >= self.actor_final or time.monotonic() - self.stopped_at > STEPS_AFTER_STOP_TIMEOUT:
            if seen < self.actor_final:
                self.rt.log(f"actor reported {self.actor_final} steps, saw {seen}")
            return True
        return False

    def run(self) -> None:
        rt = self.rt
        if self.state is not None:
            rt.event(f"teacher restarted: continuing at feedback seq {self.published}", 3)
        rt.ready()
        while not rt.stop.is_set():
            self.take_step()
            self.send(self.core.due(time.time()))
            self.follow_actor()
            if self.watch.take() and len(self.ring):
                rt.log(f"learner or recorder (re)started: re-sending the last {len(self.ring)} feedback")
                self.ring.resend()
            if self.all_steps_seen():
                break
            rt.tick()
        self.send(self.core.finish(time.time()))
        self.watch.before_exit(self.ring, 20.0, rt.log)
        rt.counters.update({f"inbox_{k}": v for k, v in self.steps.snapshot().items()})
        self.actors.close()
        self.watch.close()


def main(config: TeacherConfig) -> int:
    from common.wire.transport import MessagePublisher, subscription

    rt = ServiceRuntime(config.service_name, config)
    teacher = Teacher(config, rt)
    with rt.session() as session:
        with (
            subscription(session, step_key(config.run), maxsize=1 << 16, policy="block", block_timeout=3600) as steps,
            subscription(session, status_key(config.run, "actor"), maxsize=64, policy="drop_oldest") as status,
            MessagePublisher(session, feedback_key(config.run, config.teacher_id)) as pub,
        ):
            teacher.connect(session, steps, status, pub)
            teacher.run()
    rt.write_stats()
    rt.log(f"stopped: {teacher.published} feedback sent for {teacher.core.counters['steps_seen']} steps")
    return 0


def cli(argv: list[str] | None = None) -> int:
    """`python -m services.teacher [face-video [measure]] --flags`: the simulated observer, or the observer shown
    to the perception service as face clips (services/teacher/face_video.py)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["face-video"]:
        from services.teacher.face_video import cli as face_video_cli

        return face_video_cli(argv[1:])
    return service_main(
        TeacherConfig,
        main,
        argv,
        "python -m services.teacher",
        also="Also: python -m services.teacher face-video [measure] --help.",
    )
