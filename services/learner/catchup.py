"""Catching up after a restart: the recorder's log holds the steps and feedback a restored learner missed."""

from __future__ import annotations

import time
import warnings
from pathlib import Path

from common.protocol import ProtocolError, ServiceStatus, decode, kind_of
from services.common.config import LearnerConfig
from services.common.runtime import ServiceRuntime
from services.learner.core import LearnerCore


def catch_up(
    config: LearnerConfig, rt: ServiceRuntime, core: LearnerCore, consume, on_status, resumed: dict | None
) -> None:
    """Consume from the recorder's log every step and feedback that the (restored) core has not seen, in log
    order; statuses in the log announce incarnations and final counts. The log may be cut or still being
    written (read up to its last complete chunk); what it lacks arrives re-sent or live (deduplicated)."""
    from common.logs.mcap_log import LogRecoveryWarning, read_log

    t0 = time.monotonic()
    before = core.steps_learned, core.counters["feedback_received"]
    path = Path(config.catchup_log) if config.catchup_log else None
    records = 0
    if path is not None and path.exists():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", LogRecoveryWarning)
            for rec in read_log(path, decode=False):
                kind = kind_of(rec.key)
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
        rt.event(
            f"restored from checkpoint ({resumed['steps_learned']} steps learned, saved {age:.1f} s ago, "
            f"ingest position {resumed['position']}); caught up {steps} steps and {fbs} feedback from the log "
            f"({records} records) in {took:.2f} s",
            3,
        )
    elif steps or fbs:
        rt.event(
            f"started without a checkpoint; caught up {steps} steps and {fbs} feedback from the log in {took:.2f} s", 3
        )
