"""The learner service's process: `python -m services.learner` parses its config (`cli`) and `main` opens the
session, subscribes, restores a checkpoint and runs the `Learner`."""

from __future__ import annotations

from common.protocol import KEYS, episode_key, feedback_wildcard, ingest_key, step_key, weights_key
from services.common.config import LearnerConfig
from services.common.gate import IncarnationWatch, InputGate
from services.common.runtime import ServiceRuntime, apply_torch_threads, service_main
from services.common.watches import AliveWatch
from services.learner.core import LearnerCore
from services.learner.service import Learner
from services.learner import checkpoint


def restore(config: LearnerConfig, rt: ServiceRuntime, core: LearnerCore, gate: InputGate) -> dict | None:
    """Restore the core, the gate and the service counters from `config.checkpoint` if there is one;
    returns what the new Ingest record says it resumed from (None when starting afresh)."""
    ck = checkpoint.load(config.checkpoint) if config.checkpoint else None
    if ck is None:
        return None
    tensors, meta = ck
    core.restore(tensors, meta["core"])
    gate.load(meta["gate"])
    rt.counters.update(meta["service"]["counters"])
    return {
        "learner": meta["service"]["incarnation"],
        "position": core.position,
        "steps_learned": core.steps_learned,
        "t_saved": meta["service"]["t_saved"],
    }


def main(config: LearnerConfig) -> int:
    from common.wire.transport import Inbox, MessagePublisher, subscription

    apply_torch_threads()
    rt = ServiceRuntime("learner", config)
    core = LearnerCore(config)
    gate = InputGate(
        core.obs_dim,
        core.n_actions,
        teachers=config.wait_teachers,
        max_future=config.max_future,
        max_past=config.max_past,
    )
    resumed = restore(config, rt, core, gate)
    inbox = Inbox(config.inbox_size, "block", block_timeout=3600)
    rt.set_counters_source(
        lambda: {
            **core.counters,
            "steps_learned": core.steps_learned,
            "feedback_held_now": core.held,
            "inbox_now": len(inbox),
        }
    )
    learner = None
    with rt.session() as session:
        subs = [
            session.declare_subscriber(step_key(config.run), inbox.handler()),
            session.declare_subscriber(feedback_wildcard(config.run), inbox.handler()),
        ]
        watch = AliveWatch(session, config.run, ("recorder", "actor"))
        actors = IncarnationWatch(session, config.run, "actor")
        try:
            with (
                subscription(session, KEYS["status"].wildcard(config.run), maxsize=256, policy="drop_oldest") as status,
                MessagePublisher(session, weights_key(config.run)) as wpub,
                MessagePublisher(session, episode_key(config.run)) as epub,
                MessagePublisher(session, ingest_key(config.run)) as ipub,
                MessagePublisher(session, KEYS["snapshot"].key(config.run)) as spub,
                subscription(session, KEYS["request"].key(config.run), maxsize=4, policy="drop_oldest") as requests,
            ):
                learner = Learner(
                    config,
                    rt,
                    core,
                    gate,
                    resumed,
                    session,
                    inbox,
                    status,
                    {"weights": wpub, "episode": epub, "ingest": ipub, "snapshot": spub},
                    watch,
                    actors,
                    requests,
                )
                learner.run()
        finally:
            inbox.close()
            watch.close()
            actors.close()
            for s in subs:
                s.undeclare()
    rt.write_stats(
        final_version=learner.last_weights.version if learner else 0, resumed=resumed, delay=core.delay_summary()
    )
    rt.log(f"stopped: {core.steps_learned} steps learned, {core.counters['feedback_credited']} feedback credited")
    return 0


def cli(argv: list[str] | None = None) -> int:
    return service_main(LearnerConfig, main, argv, "python -m services.learner")
