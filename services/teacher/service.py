"""`python -m services.teacher`: the simulated teacher as a service.

Subscribes to the actor's steps, lets `OracleTeacher` (the core's SimulatedObserver on the chosen clock)
react, and publishes each reaction as a Feedback on `hitl/<run>/feedback/<teacher_id>` (source `oracle`,
own contiguous seq). Stops when the actor has stopped and every step it published has been seen (or on
SIGTERM); its final status carries `feedback_published`, which the learner waits for.

Faults (docs/faults.md): steps pass the `InputGate` (announced actor incarnation, shapes, timestamps, dedup);
with `state_file` the next seq survives a restart (so `feedback_published` counts every incarnation and no
seq is used twice); the feedback of the last `resend_window` s is re-sent when a learner or recorder
(re)starts. A teacher that crashes is simply silent meanwhile (the paper's unsustainability).
"""
from __future__ import annotations

import sys
import time

from common.envs import make_env
from common.protocol import Feedback, ProtocolError, Step, feedback_key, status_key, step_key
from services.common.config import TeacherConfig
from services.common.faults import (DEDUP_REASON, AliveWatch, IncarnationWatch, InputGate, ResendRing,
                                    atomic_write_json, first_time_logger, publish_kept, read_json)
from services.common.runtime import ServiceRuntime, service_main
from services.teacher.oracle import OracleTeacher

STEPS_AFTER_STOP_TIMEOUT = 5.0  # s to wait for steps still in flight once the actor reported 'stopped'


def main(config: TeacherConfig) -> int:
    from common.transport import MessagePublisher, subscription

    rt = ServiceRuntime(config.service_name, config)
    core = OracleTeacher(config)
    state = read_json(config.state_file) if config.state_file else None
    published = {"n": int(state["next_seq"]) if state else 0}
    ring = ResendRing(config.resend_window)
    env, _ = make_env(config.env, config.layout)
    gate = InputGate(int(env.observation_space.shape[0]), int(env.action_space.n), max_future=config.max_future,
                     max_past=config.max_past)
    env.close()
    note_rejected = first_time_logger(rt.event, "step")
    rt.set_counters_source(lambda: {**core.counters, "feedback_published": published["n"], "resent": ring.resent})

    with rt.session() as session:
        with subscription(session, step_key(config.run), maxsize=1 << 16, policy="block",
                          block_timeout=3600) as steps, \
                subscription(session, status_key(config.run, "actor"), maxsize=64, policy="drop_oldest") as status, \
                MessagePublisher(session, feedback_key(config.run, config.teacher_id)) as pub:

            def send(reactions) -> None:
                for r in reactions:
                    seq = published["n"]
                    if config.state_file:  # first: a crash right after must not reuse this seq
                        atomic_write_json(config.state_file, {"next_seq": seq + 1})
                    publish_kept(pub, Feedback(run=config.run, teacher_id=config.teacher_id, seq=seq,
                                               t_reaction=r.t_reaction, value=r.value, source="oracle",
                                               ref_seq=r.ref_seq, intended=r.intended), ring)
                    published["n"] += 1
                    rt.samples["send_delay_s"].append(time.time() - r.t_reaction)

            def admitted(got) -> Step | None:
                """The next step if it passes the gate (else counted and dropped)."""
                received = got
                try:
                    msg = received.decode()
                except ProtocolError as e:
                    rt.counters[f"rejected_{e.reason}"] += 1
                    note_rejected(e.reason)
                    return None
                for inc in actors.take():
                    gate.announce(inc)
                reason = gate.admit_step(msg, received.t_recv)
                if reason == DEDUP_REASON:
                    rt.counters["duplicates_step"] += 1
                elif reason:
                    rt.counters[f"rejected_{reason}"] += 1
                    note_rejected(reason)
                return None if reason else msg

            actors = IncarnationWatch(session, config.run, "actor")
            watch = AliveWatch(session, config.run, ("learner", "recorder"))
            if state is not None:
                rt.event(f"teacher restarted: continuing at feedback seq {published['n']}", 3)
            rt.ready()
            actor_final: int | None = None
            stopped_at = 0.0
            while not rt.stop.is_set():
                timeout = 0.05
                nd = core.next_due()
                if nd is not None:
                    timeout = min(timeout, max(0.0, nd - time.time()))
                got = steps.get(timeout=timeout)
                if got is not None:
                    step = admitted(got)
                    if step is not None:
                        rt.samples["step_transit_s"].append(got.t_recv - step.t_action)
                        rt.samples["step_queued_s"].append(time.time() - got.t_recv)
                        send(core.on_step(step))
                send(core.due(time.time()))
                for item in status.drain():
                    try:
                        st = item.decode()
                    except ProtocolError as e:
                        rt.counters[f"rejected_status_{e.reason}"] += 1
                        continue
                    gate.on_status(st)
                    if st.state == "stopped" and actor_final is None and st.incarnation in (None, gate.actor):
                        actor_final = int(st.counters.get("steps_published", 0))
                        stopped_at = time.monotonic()
                if watch.take() and len(ring):
                    rt.log(f"learner or recorder (re)started: re-sending the last {len(ring)} feedback")
                    ring.resend()
                if actor_final is not None and len(steps) == 0:
                    seen = core.next_seq if core.actor == gate.actor else 0  # this actor's steps seen (or lost)
                    if seen >= actor_final or time.monotonic() - stopped_at > STEPS_AFTER_STOP_TIMEOUT:
                        if seen < actor_final:
                            rt.log(f"actor reported {actor_final} steps, saw {seen}")
                        break
                rt.tick()
            send(core.finish(time.time()))
            watch.before_exit(ring, 20.0, rt.log)
            rt.counters.update({f"inbox_{k}": v for k, v in steps.snapshot().items()})
            actors.close()
            watch.close()
    rt.write_stats()
    rt.log(f"stopped: {published['n']} feedback sent for {core.counters['steps_seen']} steps")
    return 0


def cli(argv: list[str] | None = None) -> int:
    return service_main(TeacherConfig, main, argv, "python -m services.teacher")


if __name__ == "__main__":
    sys.exit(cli())
