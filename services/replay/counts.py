"""What a run's log says was sent, learned and refused: a service's last counters, steps and feedback sent and
learned, the learner's effective ingest record across restarts, and the inputs it rejected."""

from __future__ import annotations

import collections
from typing import TYPE_CHECKING, Any

from common.protocol import Ingest, ServiceStatus, teacher_id_of

if TYPE_CHECKING:  # (summary.py imports this module)
    from services.replay.summary import LearnerRecord, LogContents


def status_counter(c: LogContents, service: str, name: str) -> int | None:
    """A counter of the service's latest status (None without one)."""
    st = c.statuses.get(service)
    return None if st is None or name not in st.counters else int(st.counters[name])


def counts_sent_and_learned(
    c: LogContents, lr: LearnerRecord, feedback: dict[str, list[int]]
) -> tuple[list[int | None], int | None, list[str]]:
    """Feedback sent per teacher service, steps learned, and the services whose latest status is not 'stopped'.

    Counters come from each service's latest status (kept across restarts: state files, checkpoints). A service
    that never reported 'stopped' (killed, or its launcher was, and with it the router its final status needed)
    did more than its last status says: what the log shows it did is then the better lower bound."""
    stale = sorted(name for name, st in c.statuses.items() if st.state != "stopped" and name != "launcher")
    teacher_services = sorted(s for s in c.statuses if teacher_id_of(s))
    sent = [status_counter(c, svc, "feedback_published") for svc in teacher_services]
    sent = [
        x if svc not in stale else max(x or 0, len(feedback.get(teacher_id_of(svc) or "", [])))
        for svc, x in zip(teacher_services, sent)
    ]
    steps_learned = status_counter(c, "learner", "steps_learned")
    if "learner" in stale:
        steps_learned = max(steps_learned or 0, lr.step_entries.get("learned", 0))
    return sent, steps_learned, stale


def effective_ingest(ingest: dict[str, list[Ingest]]) -> tuple[list, list[str], int]:
    """The learner's record of consumed inputs across restarts: (entries in position order, the learner
    incarnations it comes from, positions missing from the log).

    A learner restored from a checkpoint names `resumed_from` (learner, position) in its first Ingest: its
    record continues the old one's at that position, the old one's entries from there on are superseded. A
    learner started without a checkpoint (it replayed the whole log) has a record of its own."""
    records: dict[str, dict[int, Any]] = {}
    links: dict[str, tuple[str, int] | None] = {}
    for learner, batches in ingest.items():
        rec: dict[int, Any] = {}
        link = None
        for b in sorted(batches, key=lambda b: b.seq):
            if b.seq == 0 and b.config and isinstance(b.config.get("resumed_from"), dict):
                r = b.config["resumed_from"]
                link = (str(r.get("learner")), int(r.get("position", 0)))
            for i, e in enumerate(b.entries):
                rec[b.index + i] = e
        records[learner], links[learner] = rec, link
    if not records:
        return [], [], 0
    last = list(records)[-1]
    chain, merged, seen = [], {}, set()
    inc: str | None = last
    upto: int | None = None
    while inc is not None and inc in records and inc not in seen:
        seen.add(inc)
        chain.append(inc)
        for pos, e in records[inc].items():
            if (upto is None or pos < upto) and pos not in merged:
                merged[pos] = e
        link = links[inc]
        inc, upto = (link[0], link[1]) if link else (None, None)
    positions = sorted(merged)
    gaps = (positions[-1] + 1 - len(positions)) if positions else 0
    return [merged[p] for p in positions], chain[::-1], gaps


def rejected_inputs(
    by_pid: dict[tuple[str, int], ServiceStatus], prefixes: tuple[str, ...] = ("rejected_", "weights_dropped_")
) -> dict[str, dict[str, int]]:
    """Inputs each service dropped, by reason: summed over its processes (a restarted learner carries its
    counts over in its checkpoint, so only its newest process counts)."""
    out: dict[str, collections.Counter] = collections.defaultdict(collections.Counter)
    newest_learner = max(
        (pid for (svc, pid) in by_pid if svc == "learner"), key=lambda pid: by_pid[("learner", pid)].t, default=None
    )
    for (service, pid), st in by_pid.items():
        if service == "learner" and pid != newest_learner:
            continue
        for k, v in st.counters.items():
            for p in prefixes:
                if k.startswith(p) and v:
                    out[service][k[len(p) :]] += int(v)
    return {svc: dict(sorted(c.items())) for svc, c in sorted(out.items()) if c}
