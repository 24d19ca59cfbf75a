"""`replay LOG retrain`: feed a fresh learner the recorded inputs in the recorded order.

The live learner wrote its consumption order (Ingest messages: step / feedback / end entries, plus the
outcome of every feedback) and its config (first Ingest message). Replaying the referenced Step and Feedback
messages from the same log through a fresh `LearnerCore` in that order repeats every decision; on the same
machine (same torch build, one thread) the final weights are equal bit for bit to the live learner's last
Weights message (published after its `end` entry).
"""

from __future__ import annotations

import dataclasses
import os
import warnings

import numpy as np

from common.logs.mcap_log import LogRecoveryWarning, read_log
from common.protocol import Feedback, Ingest, IngestEntry, Step, Weights, WeightsSnapshot


@dataclasses.dataclass
class RetrainResult:
    learner: str
    inputs: int
    steps: int
    feedback: int
    ended: bool
    outcomes_match: bool
    entry_mismatch: str | None
    compared: bool  # the log holds the live learner's final weights
    identical: bool
    max_abs_diff: float | None
    live_version: int | None
    weights: dict[str, np.ndarray]
    missing_inputs: int
    warnings: list[str]
    live_revision: int | None = None  # the live final weights' revision (equal to the retrained one when identical)

    def report(self) -> str:
        lines = [
            f"learner {self.learner}: replayed {self.inputs} inputs ({self.steps} steps, {self.feedback} "
            f"feedback){'' if self.ended else ', log ends before the learner ended'}"
        ]
        if self.missing_inputs:
            lines.append(f"  {self.missing_inputs} recorded inputs are missing from the log")
        lines.append(
            f"  feedback outcomes and input statuses {'match' if self.outcomes_match else 'DIFFER'}"
            + (f" ({self.entry_mismatch})" if self.entry_mismatch else "")
        )
        if not self.compared:
            lines.append("  final weights: NOT COMPARED (the log has no Weights published after the learner's end)")
        elif self.identical:
            lines.append(
                f"  final weights: IDENTICAL bit for bit to the live learner's (version {self.live_version}"
                + ("" if self.live_revision is None else f", revision {self.live_revision}")
                + ")"
            )
        else:
            lines.append(
                f"  final weights: DIFFERENT from the live learner's (version {self.live_version}, "
                f"max |diff| {self.max_abs_diff:.3g})"
            )
        return "\n".join(lines)


def _bit_equal(a: np.ndarray, b: np.ndarray) -> bool:
    a, b = np.asarray(a), np.asarray(b)
    return a.shape == b.shape and a.dtype == b.dtype and a.tobytes() == b.tobytes()


@dataclasses.dataclass
class _Log:
    """What retrain needs from a log: inputs by identity, Ingest batches and Weights per learner."""

    steps: dict
    feedback: dict
    ingest: dict
    weights: dict
    warnings: list


def _read(path) -> _Log:
    log = _Log({}, {}, {}, {}, [])
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", LogRecoveryWarning)
        for rec in read_log(path):
            m = rec.message
            if isinstance(m, Step):
                log.steps[(m.incarnation, m.seq)] = m
            elif isinstance(m, Feedback):
                log.feedback[(m.teacher_id, m.seq)] = m
            elif isinstance(m, Ingest):
                log.ingest.setdefault(m.learner, []).append(m)
            elif isinstance(m, Weights):
                log.weights.setdefault(m.incarnation, []).append(m)
            elif isinstance(m, WeightsSnapshot) and m.weights is not None:  # logs keep snapshots, not every version
                log.weights.setdefault(m.incarnation, []).append(Weights.decode(m.weights))
    log.warnings = [str(w.message) for w in caught]
    return log


def _entries(path, log: _Log, learner: str | None) -> tuple[str, list, dict]:
    """(the learner whose final weights to compare, its consumption order, its config record)."""
    if not log.ingest:
        raise ValueError(f"{path}: no Ingest messages (no learner recorded)")
    if learner is None:
        # The whole record: a learner restored from a checkpoint continues its predecessor's (resumed_from).
        from services.replay.counts import effective_ingest

        merged, chain, _ = effective_ingest(log.ingest)
        learner, origin = chain[-1], chain[0]
    else:
        if learner not in log.ingest:
            raise ValueError(f"{path}: no learner {learner!r}; found {', '.join(log.ingest)}")
        merged, origin = None, learner
    batches = sorted(log.ingest[origin], key=lambda b: b.seq)
    if batches[0].seq != 0 or batches[0].config is None or batches[0].index != 0:
        raise ValueError(f"{path}: the first Ingest message of {origin} (with its config) is missing")
    if merged is not None:
        return learner, merged, batches[0].config
    entries: list[IngestEntry] = []
    for b in batches:
        if b.index != len(entries):
            break  # a batch lost (truncated log): replay up to the gap
        entries.extend(b.entries)
    return learner, entries, batches[0].config


def _replay(core, log: _Log, entries: list, after_step=None) -> tuple[int, int, int, bool]:
    """Feed the core the recorded inputs in the recorded order: (steps, feedback, missing, ended).
    `after_step(step)` is called after each step is learned (the console's replay reads Q and H there)."""
    n_steps = n_fb = missing = 0
    ended = False
    for e in entries:
        if e.kind == "end":
            core.end()
            ended = True
            continue
        if e.kind == "idle":
            core.idle()
            continue
        store = log.steps if e.kind == "step" else log.feedback if e.kind == "feedback" else None
        if store is None:
            continue
        msg = store.get((e.source, e.seq))
        if msg is None:
            missing += 1
        elif e.kind == "step":
            core.on_step(msg)
            n_steps += 1
            if after_step is not None:
                after_step(msg)
        else:
            core.on_feedback(msg)
            n_fb += 1
    return n_steps, n_fb, missing, ended


def _first_mismatch(mine: list, entries: list) -> str | None:
    key = lambda e: (e.kind, e.source, e.seq, e.status)  # noqa: E731
    for i, (a, b) in enumerate(zip(mine, entries)):
        if key(a) != key(b):
            return f"entry {i}: recorded {key(b)}, retrained {key(a)}"
    if len(mine) != len(entries):
        return f"recorded {len(entries)} entries, retrained {len(mine)}"
    return None


def retrain(path: str | os.PathLike, learner: str | None = None) -> RetrainResult:
    from services.common.runtime import apply_torch_threads
    from services.common.config import learner_config_from_record
    from services.learner.core import LearnerCore

    log = _read(path)
    learner, entries, config = _entries(path, log, learner)
    apply_torch_threads()
    core = LearnerCore(learner_config_from_record(config["learner"]))
    n_steps, n_fb, missing, ended = _replay(core, log, entries)
    mismatch = _first_mismatch(core.take_entries(), entries)
    final = core.policy_weights()
    live = log.weights.get(learner, [])
    compared = ended and bool(live) and live[-1].version == core.steps_learned + 1
    identical, diff, version = False, None, None
    if compared:
        w = live[-1]
        version = w.version
        identical = (
            set(w.tensors) == set(final)
            and all(_bit_equal(w.tensors[k], final[k]) for k in final)
            and w.revision in (None, core.revision)
        )  # (older logs' weights have no revision)
        if set(w.tensors) == set(final):
            diff = max(
                float(np.max(np.abs(np.asarray(w.tensors[k], np.float64) - final[k]))) if final[k].size else 0.0
                for k in final
            )
    return RetrainResult(
        learner,
        n_steps + n_fb,
        n_steps,
        n_fb,
        ended,
        mismatch is None,
        mismatch,
        compared,
        identical,
        diff,
        version,
        final,
        missing,
        log.warnings,
        live[-1].revision if compared else None,
    )
