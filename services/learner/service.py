"""`python -m services.learner`: the learner as a service.

One inbox receives both the actor's steps and every teacher's feedback, in arrival order; the learner
consumes it in that order through `LearnerCore` (credit by timestamp, Q and H updates) and records the order
in Ingest messages (`hitl/<run>/ingest`, first one carrying its config). It publishes Weights (version =
steps learned) at least every `weights_every` steps and whenever it has caught up, and an EpisodeSummary per
episode.

End: once the actor has reported 'stopped' with its step count and all those steps are learned, the learner
waits (up to `end_grace` s) until every known teacher has reported 'stopped' and all its feedback has
arrived, then ends the core (held feedback -> after_end), publishes its final weights (version = steps
learned + 1: the state after the last input) and stops. SIGTERM ends at once.

Everything that affects learning depends only on the consumed order; wall-clock decisions here (when to
publish weights, when to flush Ingest, when to stop waiting) never touch the learner's state.
"""
from __future__ import annotations

import sys
import time

from common.protocol import (EpisodeSummary, Feedback, Ingest, Step, Weights, episode_key, feedback_wildcard,
                             ingest_key, step_key, weights_key)
from common.protocol import KEYS
from services.common.config import LearnerConfig
from services.common.runtime import ServiceRuntime, apply_torch_threads, service_main
from services.learner.core import LearnerCore

TEACHER_PREFIX = "teacher."


def main(config: LearnerConfig) -> int:
    from common.transport import Inbox, MessagePublisher, subscription

    apply_torch_threads()
    rt = ServiceRuntime("learner", config)
    core = LearnerCore(config)
    rt.set_counters_source(lambda: {**core.counters, "steps_learned": core.steps_learned,
                                    "feedback_held_now": core.held})
    ingest_seq = 0
    sent_at: dict[int, tuple] = {}  # ingest position of a held feedback -> (when sent, when it arrived)

    with rt.session() as session:
        inbox = Inbox(1 << 16, "block", block_timeout=3600)
        subs = [session.declare_subscriber(step_key(config.run), inbox.callback),
                session.declare_subscriber(feedback_wildcard(config.run), inbox.callback)]
        try:
            with subscription(session, KEYS["status"].wildcard(config.run), maxsize=256,
                              policy="drop_oldest") as status, \
                    MessagePublisher(session, weights_key(config.run)) as wpub, \
                    MessagePublisher(session, episode_key(config.run)) as epub, \
                    MessagePublisher(session, ingest_key(config.run)) as ipub:

                def flush_ingest() -> None:
                    nonlocal ingest_seq
                    while core.entries:
                        index = core.position - len(core.entries)
                        entries = core.take_entries(config.ingest_batch)
                        ipub.put(Ingest(run=config.run, learner=rt.incarnation, seq=ingest_seq, index=index,
                                        entries=entries, config=core.config_record() if ingest_seq == 0 else None))
                        ingest_seq += 1

                last_version = {"v": 0}

                def publish_weights(version: int) -> None:
                    t0 = time.perf_counter()
                    wpub.put(Weights(run=config.run, incarnation=rt.incarnation, version=version,
                                     t_published=time.time(), tensors=core.policy_weights()))
                    last_version["v"] = version
                    rt.samples["weights_publish_cost_s"].append(time.perf_counter() - t0)

                def handle(results, t_sent: float | None = None) -> None:
                    """Latency samples: send -> H updated, and how much of it was the wait for a newer step."""
                    done = time.time()
                    for r in results:
                        t0, t_held = t_sent, None
                        if r.received_at in sent_at:
                            t0, t_held = sent_at.pop(r.received_at)
                        if r.status == "credited" and t0 is not None:
                            rt.samples["feedback_to_h_s"].append(done - t0)
                            rt.samples["feedback_hold_s"].append(0.0 if t_held is None else done - t_held)

                # The first Ingest (with the config) goes out with the first inputs: they only flow once the actor
                # has seen every awaited service alive, so the recorder is subscribed by then.
                rt.ready()
                actor_final: int | None = None
                teachers_final: dict[str, int] = {}
                teachers_known: set[str] = set(config.wait_teachers)
                caught_up_at: float | None = None
                while not rt.stop.is_set():
                    got = inbox.get_message(timeout=0.05)
                    now = time.time()
                    if got is not None:
                        received, msg = got
                        t_sent = received.t_zenoh if received.t_zenoh is not None else received.t_recv
                        if isinstance(msg, Step):
                            results, ep = core.on_step(msg, now)
                            handle(results)
                            if ep is not None:
                                epub.put(EpisodeSummary(run=config.run, incarnation=ep.incarnation,
                                                        episode=ep.episode, return_=ep.return_, steps=ep.steps,
                                                        feedback_received=ep.feedback_received,
                                                        feedback_credited=ep.feedback_credited,
                                                        weights_version=ep.weights_version, t_end=ep.t_end))
                        elif isinstance(msg, Feedback):
                            teachers_known.add(msg.teacher_id)
                            results = core.on_feedback(msg, now)
                            if not results:  # held: remember when it was sent and when it arrived
                                sent_at[core.position - 1] = (t_sent, now)
                            handle(results, t_sent=t_sent)
                        idle = len(inbox) == 0
                        v = core.steps_learned
                        if v != last_version["v"] and (idle or v - last_version["v"] >= config.weights_every):
                            publish_weights(v)
                        if idle or len(core.entries) >= config.ingest_batch:
                            flush_ingest()
                    for item in status.drain():
                        try:
                            st = item.decode()
                        except Exception:
                            continue
                        if st.state != "stopped":
                            if st.service.startswith(TEACHER_PREFIX):
                                teachers_known.add(st.service[len(TEACHER_PREFIX):])
                            continue
                        if st.service == "actor":
                            actor_final = int(st.counters.get("steps_published", 0))
                        elif st.service.startswith(TEACHER_PREFIX):
                            tid = st.service[len(TEACHER_PREFIX):]
                            teachers_known.add(tid)
                            teachers_final[tid] = int(st.counters.get("feedback_published", 0))
                    if actor_final is not None and len(inbox) == 0 and core.next_seq >= actor_final:
                        if caught_up_at is None:
                            caught_up_at = time.monotonic()
                        waiting = [t for t in sorted(teachers_known)
                                   if t not in teachers_final or core.teacher_next.get(t, 0) < teachers_final[t]]
                        if not waiting:
                            break
                        if time.monotonic() - caught_up_at > config.end_grace:
                            rt.log(f"end: stopped waiting for teacher(s) {waiting} after {config.end_grace} s")
                            rt.counters["end_grace_expired"] += 1
                            break
                    rt.tick()
                handle(core.end(time.time()))
                flush_ingest()
                publish_weights(core.steps_learned + 1)
                rt.counters.update({f"inbox_{k}": v for k, v in inbox.snapshot().items()})
        finally:
            inbox.close()
            for s in subs:
                s.undeclare()
    rt.write_stats(final_version=last_version["v"])
    rt.log(f"stopped: {core.steps_learned} steps learned, {core.counters['feedback_credited']} feedback credited")
    return 0


def cli(argv: list[str] | None = None) -> int:
    return service_main(LearnerConfig, main, argv, "python -m services.learner")


if __name__ == "__main__":
    sys.exit(cli())
