"""`python -m services.teacher`: the simulated teacher as a service.

Subscribes to the actor's steps, lets `OracleTeacher` (the core's SimulatedObserver on the chosen clock)
react, and publishes each reaction as a Feedback on `hitl/<run>/feedback/<teacher_id>` (source `oracle`,
own contiguous seq). Stops when the actor has stopped and every step it published has been seen (or on
SIGTERM); its final status carries `feedback_published`, which the learner waits for.
"""
from __future__ import annotations

import sys
import time

from common.protocol import Feedback, feedback_key, status_key, step_key
from services.common.config import TeacherConfig
from services.common.runtime import ServiceRuntime, service_main
from services.teacher.oracle import OracleTeacher

STEPS_AFTER_STOP_TIMEOUT = 5.0  # s to wait for steps still in flight once the actor reported 'stopped'


def main(config: TeacherConfig) -> int:
    from common.transport import MessagePublisher, subscription

    rt = ServiceRuntime(config.service_name, config)
    core = OracleTeacher(config)
    published = {"n": 0}
    rt.set_counters_source(lambda: {**core.counters, "feedback_published": published["n"]})

    with rt.session() as session:
        with subscription(session, step_key(config.run), maxsize=1 << 16, policy="block",
                          block_timeout=3600) as steps, \
                subscription(session, status_key(config.run, "actor"), maxsize=64, policy="drop_oldest") as status, \
                MessagePublisher(session, feedback_key(config.run, config.teacher_id)) as pub:

            def send(reactions) -> None:
                for r in reactions:
                    pub.put(Feedback(run=config.run, teacher_id=config.teacher_id, seq=published["n"],
                                     t_reaction=r.t_reaction, value=r.value, source="oracle", ref_seq=r.ref_seq,
                                     intended=r.intended))
                    published["n"] += 1
                    rt.samples["send_delay_s"].append(time.time() - r.t_reaction)

            rt.ready()
            actor_final: int | None = None
            stopped_at = 0.0
            while not rt.stop.is_set():
                timeout = 0.05
                nd = core.next_due()
                if nd is not None:
                    timeout = min(timeout, max(0.0, nd - time.time()))
                got = steps.get_message(timeout=timeout)
                if got is not None:
                    send(core.on_step(got[1]))
                send(core.due(time.time()))
                for item in status.drain():
                    try:
                        st = item.decode()
                    except Exception:
                        continue
                    if st.state == "stopped" and actor_final is None:
                        actor_final = int(st.counters.get("steps_published", 0))
                        stopped_at = time.monotonic()
                if actor_final is not None and len(steps) == 0:
                    seen = core.counters["steps_seen"] + core.counters["steps_lost"]
                    if seen >= actor_final or time.monotonic() - stopped_at > STEPS_AFTER_STOP_TIMEOUT:
                        if seen < actor_final:
                            rt.log(f"actor reported {actor_final} steps, saw {seen}")
                        break
                rt.tick()
            send(core.finish(time.time()))
            rt.counters.update({f"inbox_{k}": v for k, v in steps.snapshot().items()})
    rt.write_stats()
    rt.log(f"stopped: {published['n']} feedback sent for {core.counters['steps_seen']} steps")
    return 0


def cli(argv: list[str] | None = None) -> int:
    return service_main(TeacherConfig, main, argv, "python -m services.teacher")


if __name__ == "__main__":
    sys.exit(cli())
