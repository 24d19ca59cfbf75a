"""`python -m services.learner`: the learner as a service.

One inbox receives both the actor's steps and every teacher's feedback, in arrival order; the learner
consumes it in that order through `LearnerCore` (credit by timestamp, Q and H updates) and records the order
in Ingest messages (`hitl/<run>/ingest`, first one carrying its config). It publishes Weights (version =
steps learned) at least every `weights_every` steps and whenever it has caught up, and an EpisodeSummary per
episode.

Every input passes the `InputGate` first (docs/faults.md): undecodable bytes, wrong shapes, timestamps far
off, unannounced actor incarnations, unknown teachers, seq jumps are dropped and counted
(`rejected_<reason>`); inputs already consumed (re-sent after a restart) are dropped as duplicates.

Recovery: with `checkpoint`, the whole learning state is saved atomically every `checkpoint_period` s; a
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

import sys
import time
import warnings
from pathlib import Path

from common.protocol import (KEYS, EpisodeSummary, Feedback, Ingest, ProtocolError, ServiceStatus, Step, Weights,
                             decode, episode_key, feedback_wildcard, ingest_key, step_key, weights_key)
from services.common.config import LearnerConfig
from services.common.faults import (DEDUP_REASON, AliveWatch, IncarnationWatch, InputGate, ResendRing,
                                    first_time_logger, publish_kept)
from services.common.runtime import ServiceRuntime, apply_torch_threads, service_main
from services.learner import checkpoint
from services.learner.snapshots import Snapshots
from services.learner.core import LearnerCore

TEACHER_PREFIX = "teacher."


def main(config: LearnerConfig) -> int:
    from common.transport import Inbox, MessagePublisher, subscription

    apply_torch_threads()
    rt = ServiceRuntime("learner", config)
    core = LearnerCore(config)
    gate = InputGate(core.obs_dim, core.n_actions, teachers=config.wait_teachers, max_future=config.max_future,
                     max_past=config.max_past)
    resumed: dict | None = None
    if config.checkpoint:
        ck = checkpoint.load(config.checkpoint)
        if ck is not None:
            tensors, meta = ck
            core.restore(tensors, meta["core"])
            gate.load(meta["gate"])
            rt.counters.update(meta["service"]["counters"])
            resumed = {"learner": meta["service"]["incarnation"], "position": core.position,
                       "steps_learned": core.steps_learned, "t_saved": meta["service"]["t_saved"]}
    rt.set_counters_source(lambda: {**core.counters, "steps_learned": core.steps_learned,
                                    "feedback_held_now": core.held, "inbox_now": len(inbox)})
    ingest_seq = 0
    sent_at: dict[int, tuple] = {}  # ingest position of a held feedback -> (when sent, when it arrived)
    ring = ResendRing(config.resend_window)
    note_rejected = first_time_logger(rt.event, "input")
    inbox = Inbox(config.inbox_size, "block", block_timeout=3600)

    with rt.session() as session:
        subs = [session.declare_subscriber(step_key(config.run), inbox.handler()),
                session.declare_subscriber(feedback_wildcard(config.run), inbox.handler())]
        watch = AliveWatch(session, config.run, ("recorder", "actor"))
        actors = IncarnationWatch(session, config.run, "actor")
        try:
            with subscription(session, KEYS["status"].wildcard(config.run), maxsize=256,
                              policy="drop_oldest") as status, \
                    MessagePublisher(session, weights_key(config.run)) as wpub, \
                    MessagePublisher(session, episode_key(config.run)) as epub, \
                    MessagePublisher(session, ingest_key(config.run)) as ipub, \
                    MessagePublisher(session, KEYS["snapshot"].key(config.run)) as spub, \
                    subscription(session, KEYS["request"].key(config.run), maxsize=4,
                                 policy="drop_oldest") as requests:
                snaps = Snapshots(config.run, rt.incarnation, config.snapshot_every,
                                  lambda m: publish_kept(spub, m, ring))

                def flush_ingest() -> None:
                    nonlocal ingest_seq
                    while core.entries:
                        index = core.position - len(core.entries)
                        entries = core.take_entries(config.ingest_batch)
                        cfg = None
                        if ingest_seq == 0:
                            cfg = core.config_record()
                            if resumed is not None:
                                cfg["resumed_from"] = {"learner": resumed["learner"], "position": resumed["position"]}
                        publish_kept(ipub, Ingest(run=config.run, learner=rt.incarnation, seq=ingest_seq, index=index,
                                                  entries=entries, config=cfg), ring)
                        ingest_seq += 1

                last_version = {"v": 0 if resumed is None else -1, "data": None}
                credit_pubs: dict[str, MessagePublisher] = {}

                def current_weights(version: int) -> tuple[dict, bytes]:
                    tensors = core.policy_weights()
                    return tensors, Weights(run=config.run, incarnation=rt.incarnation, version=version,
                                            t_published=time.time(), tensors=tensors).encode()

                def publish_weights(version: int, final: bool = False) -> None:
                    t0 = time.perf_counter()
                    tensors, data = current_weights(version)
                    wpub.put(data)
                    last_version.update(v=version, data=data)
                    # The log gets snapshots at a bounded rate, not every version (docs/logs.md).
                    (snaps.final if final else snaps.on_weights)(version, tensors, data)
                    rt.samples["weights_publish_cost_s"].append(time.perf_counter() - t0)

                last_ckpt = {"t": time.monotonic(), "steps": core.steps_learned if resumed else -1}

                def save_checkpoint() -> None:
                    flush_ingest()  # position = entries handed out
                    t0 = time.perf_counter()
                    tensors, meta = core.snapshot()
                    meta = {"core": meta, "gate": gate.state(),
                            "service": {"counters": dict(rt.counters), "incarnation": rt.incarnation,
                                        "t_saved": time.time()},
                            "config": core.config_record()}
                    checkpoint.save(config.checkpoint, tensors, meta)
                    rt.counters["checkpoints"] += 1
                    rt.samples["checkpoint_cost_s"].append(time.perf_counter() - t0)
                    last_ckpt.update(t=time.monotonic(), steps=core.steps_learned)

                def handle(results, t_sent: float | None = None) -> None:
                    """Latency samples: send -> H updated, and how much of it was the wait for a newer step."""
                    done = time.time()
                    for r in results:
                        if r.feedback is not None:  # what became of it: consoles and the log's scene show it
                            publish_credit(session, config.run, credit_pubs, r, core.actor, done)
                        t0, t_held = t_sent, None
                        if r.received_at in sent_at:
                            t0, t_held = sent_at.pop(r.received_at)
                        if r.status == "credited" and t0 is not None:
                            rt.samples["feedback_to_h_s"].append(done - t0)
                            rt.samples["feedback_hold_s"].append(0.0 if t_held is None else done - t_held)

                def reject(reason: str, what: str, count: bool = True) -> None:
                    if not count:  # catching up: counted by the learner that saw it live (or its checkpoint)
                        return
                    if reason == DEDUP_REASON:
                        rt.counters[f"duplicates_{what}"] += 1
                    else:
                        rt.counters[f"rejected_{reason}"] += 1
                        note_rejected(reason, what)

                def consume(msg, now: float, t_recv: float, t_sent: float | None, live: bool = True) -> bool:
                    """One decoded input through the gate into the core. True if consumed."""
                    if isinstance(msg, Step):
                        for inc in actors.take():
                            gate.announce(inc)
                        reason = gate.admit_step(msg, t_recv)
                        if reason == "unknown_incarnation" and live:
                            drain_status()  # its announcement may be waiting in the other queue
                            reason = gate.admit_step(msg, t_recv)
                        if reason:
                            reject(reason, "step", count=live)
                            return False
                        results, ep = core.on_step(msg, now)
                        handle(results)
                        if ep is not None:
                            publish_kept(epub, EpisodeSummary(
                                run=config.run, incarnation=ep.incarnation, episode=ep.episode, return_=ep.return_,
                                steps=ep.steps, feedback_received=ep.feedback_received,
                                feedback_credited=ep.feedback_credited, weights_version=ep.weights_version,
                                t_end=ep.t_end), ring)
                            snaps.on_episode(core.steps_learned, core.policy_weights())
                        if config.debug_update_sleep:
                            time.sleep(config.debug_update_sleep)
                        return True
                    if isinstance(msg, Feedback):
                        reason = gate.admit_feedback(msg, t_recv)
                        if reason == "unknown_teacher" and live:
                            drain_status()
                            reason = gate.admit_feedback(msg, t_recv)
                        if reason:
                            reject(reason, "feedback", count=live)
                            return False
                        teachers_known.add(msg.teacher_id)
                        results = core.on_feedback(msg, now)
                        if not results:  # held: remember when it was sent and when it arrived
                            sent_at[core.position - 1] = (t_sent, now)
                        handle(results, t_sent=t_sent)
                        return True
                    return False

                actor_final: int | None = None
                teachers_final: dict[str, int] = {}
                teachers_known: set[str] = set(config.wait_teachers)

                def on_status(st: ServiceStatus) -> None:
                    nonlocal actor_final
                    gate.on_status(st)
                    if st.state != "stopped":
                        if st.service.startswith(TEACHER_PREFIX):
                            teachers_known.add(st.service[len(TEACHER_PREFIX):])
                        return
                    if st.service == "actor" and (st.incarnation is None or st.incarnation == gate.actor):
                        actor_final = int(st.counters.get("steps_published", 0))
                    elif st.service.startswith(TEACHER_PREFIX):
                        tid = st.service[len(TEACHER_PREFIX):]
                        teachers_known.add(tid)
                        teachers_final[tid] = int(st.counters.get("feedback_published", 0))

                def drain_status() -> None:
                    for item in status.drain():
                        try:
                            st = item.decode()
                        except ProtocolError as e:
                            rt.counters[f"rejected_status_{e.reason}"] += 1
                            continue
                        on_status(st)

                # Subscribed: announce (actor and teachers re-send their recent messages to a restarted learner).
                rt.ready()
                if resumed is not None or config.catchup_log:
                    catch_up(config, rt, core, consume, on_status, resumed)
                if resumed is not None:
                    flush_ingest()
                    publish_weights(core.steps_learned)
                caught_up_at: float | None = None
                while not rt.stop.is_set():
                    got = inbox.get(timeout=0.05)
                    now = time.time()
                    if got is not None:
                        t_sent = got.t_zenoh if got.t_zenoh is not None else got.t_recv
                        try:
                            msg = got.decode()
                        except ProtocolError as e:
                            reject(e.reason, got.key.split("/")[2])
                        else:
                            consume(msg, now, got.t_recv, t_sent)
                        idle = len(inbox) == 0
                        v = core.steps_learned
                        if v != last_version["v"] and (idle or v - last_version["v"] >= config.weights_every):
                            publish_weights(v)
                        if idle or len(core.entries) >= config.ingest_batch:
                            flush_ingest()
                    drain_status()
                    if len(requests):
                        snaps.on_requests(requests.drain(), core.steps_learned,
                                          lambda: current_weights(core.steps_learned))
                    for name in watch.take():
                        if name == "recorder" and len(ring):
                            rt.event(f"recorder (re)started: re-sending {len(ring)} recent ingest/episode messages")
                            ring.resend()
                            if last_version["data"] is not None:
                                wpub.put(last_version["data"])
                        elif name == "actor" and (core.steps_learned > 0 or resumed is not None):
                            publish_weights(core.steps_learned)  # a restarted actor needs the current policy
                    if (config.checkpoint and core.steps_learned != last_ckpt["steps"]
                            and time.monotonic() - last_ckpt["t"] >= config.checkpoint_period):
                        save_checkpoint()
                    if actor_final is not None and len(inbox) == 0 and core.next_seq >= actor_final \
                            and core.actor == gate.actor:
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
                publish_weights(core.steps_learned + 1, final=True)
                ring.add(wpub, last_version["data"])  # the final weights too, if the recorder must get them again
                watch.before_exit(ring, 20.0, rt.log)
                for pub in credit_pubs.values():
                    pub.close()
                rt.counters.update({f"inbox_{k}": v for k, v in inbox.snapshot().items()})
                rt.counters["resent"] = ring.resent
        finally:
            inbox.close()
            watch.close()
            actors.close()
            for s in subs:
                s.undeclare()
    rt.write_stats(final_version=last_version["v"], resumed=resumed)
    rt.log(f"stopped: {core.steps_learned} steps learned, {core.counters['feedback_credited']} feedback credited")
    return 0


def publish_credit(session, run: str, pubs: dict, result, actor: str | None, t_done: float) -> None:
    """A `Credit` for one resolved feedback: the steps it was credited to, with their weights."""
    from common.protocol import Credit, CreditedStep, credit_key
    from common.transport import MessagePublisher

    fb = result.feedback
    pub = pubs.get(fb.teacher_id)
    if pub is None:
        pub = pubs[fb.teacher_id] = MessagePublisher(session, credit_key(run, fb.teacher_id))
    pub.put(Credit(run=run, teacher_id=fb.teacher_id, seq=fb.seq, value=fb.value, status=result.status,
                   t_reaction=fb.t_reaction, t_credited=t_done, actor=fb.actor or actor,
                   steps=[CreditedStep(int(q), min(1.0, float(w))) for q, w in result.credited[:256]],
                   lost_mass=min(1.0, max(0.0, float(result.lost_mass)))))


def catch_up(config: LearnerConfig, rt: ServiceRuntime, core: LearnerCore, consume, on_status,
             resumed: dict | None) -> None:
    """Consume from the recorder's log every step and feedback that the (restored) core has not seen, in log
    order; statuses in the log announce incarnations and final counts. The log may be cut or still being
    written (read up to its last complete chunk); what it lacks arrives re-sent or live (deduplicated)."""
    from common.mcap_log import LogRecoveryWarning, read_log

    t0 = time.monotonic()
    before = core.steps_learned, core.counters["feedback_received"]
    path = Path(config.catchup_log) if config.catchup_log else None
    records = 0
    if path is not None and path.exists():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", LogRecoveryWarning)
            for rec in read_log(path, decode=False):
                kind = rec.key.split("/")[2] if rec.key.count("/") >= 2 else ""
                if kind not in ("step", "feedback", "status"):
                    continue
                try:
                    msg = decode(rec.key, rec.data)
                except ProtocolError:
                    continue  # counted when it arrived live
                records += 1
                if isinstance(msg, ServiceStatus):
                    on_status(msg)
                else:
                    consume(msg, time.time(), rec.log_time / 1e9, None, live=False)
    steps, fbs = core.steps_learned - before[0], core.counters["feedback_received"] - before[1]
    took = time.monotonic() - t0
    rt.counters["catchup_steps"] += steps
    rt.counters["catchup_feedback"] += fbs
    rt.samples["catchup_s"].append(took)
    if resumed is not None:
        age = time.time() - resumed["t_saved"]
        rt.event(f"restored from checkpoint ({resumed['steps_learned']} steps learned, saved {age:.1f} s ago, "
                 f"ingest position {resumed['position']}); caught up {steps} steps and {fbs} feedback from the log "
                 f"({records} records) in {took:.2f} s", 3)
    elif steps or fbs:
        rt.event(f"started without a checkpoint; caught up {steps} steps and {fbs} feedback from the log in "
                 f"{took:.2f} s", 3)


def cli(argv: list[str] | None = None) -> int:
    return service_main(LearnerConfig, main, argv, "python -m services.learner")


if __name__ == "__main__":
    sys.exit(cli())
