"""Catching up after a restart: the recorder's log holds the steps and feedback a restored learner missed, and the
steps the actor re-sends may come after live ones (`StepReorder`)."""

from __future__ import annotations

import time
import warnings
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

from common.protocol import ProtocolError, ServiceStatus, Step, decode, kind_of
from services.common.config import LearnerConfig
from services.common.gate import InputGate
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


@dataclass
class StepReorder:
    """Live steps of the current actor that arrive ahead of the next expected seq, waiting for the ones before them.

    A restored learner subscribes, catches up from the log (which lags the actor by its flush period) and then
    hears the actor re-send its recent steps; a live step may overtake those re-sent ones. The log itself can hold
    that order: a restarted recorder writes the live steps that reach it before the actor's re-sent ones, and a
    learner catching up from it reads them so (a chaos run lost 25 steps that way). Consumed at once it would
    be a gap, and the re-sent steps behind it would be dropped as old. So it waits, up to `wait_s` (wall clock;
    the order finally consumed is what the Ingest record holds, so retrain repeats it) or until `max_held` wait, and
    then what waits is consumed in seq order, the first with its gap as before."""

    wait_s: float
    max_held: int
    held: dict[int, tuple[Step, float]] = field(default_factory=dict)  # seq -> (step, when it arrived)
    since: float | None = None  # (monotonic) when the oldest one began to wait

    def waits(self, step: Step, t_recv: float, gate: InputGate) -> bool:
        """Hold a step of the gate's actor that is ahead of its next seq and otherwise admissible; True if held."""
        if step.incarnation != gate.actor or step.seq <= (gate.next_step or 0) or gate.check_step(step, t_recv):
            return False
        self.held.setdefault(step.seq, (step, t_recv))  # (one re-sent again is the same step)
        if self.since is None:
            self.since = time.monotonic()
        return True

    def following(self, gate: InputGate) -> Iterator[tuple[Step, float]]:
        """The waiting steps that now follow in order, one at a time (the caller admits each before the next)."""
        while self.held and gate.next_step is not None and (got := self.held.pop(gate.next_step, None)) is not None:
            if not self.held:
                self.since = None
            yield got

    def due_in(self) -> float:
        """Seconds until what waits must be consumed anyway (inf with nothing waiting, 0 when overdue)."""
        if self.since is None:
            return float("inf")
        if len(self.held) >= self.max_held:
            return 0.0
        return max(0.0, self.since + self.wait_s - time.monotonic())

    def take_all(self) -> list[tuple[Step, float]]:
        """Everything waiting, in seq order (the wait is over)."""
        out = [self.held[k] for k in sorted(self.held)]
        self.held.clear()
        self.since = None
        return out
