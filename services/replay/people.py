"""Per person at the console (summary.json `people`): what became of their presses, from the console's counts
(carried by each person's ServiceStatus, kept across a console restart by its ledger) and the log."""

from __future__ import annotations

from typing import Any

DROPPED_PREFIX = "presses_dropped_"


def people_report(
    statuses: dict, feedback: dict[str, list[int]], outcome: dict[tuple[str, int], str], teacher_of
) -> dict[str, dict[str, Any]]:
    """{teacher id: received, published, resent, logged, credited, dropped {reason: n}} for each console person.

    `received`: presses the console got from the person's pages; `published`: distinct feedback seqs it sent;
    `logged`: distinct seqs in the log; `credited`: those the learner credited; `dropped`: the console's refusals
    (flood, absurd_timestamp, ...), sent but not logged (`not_logged`), and the learner's other outcomes
    (stale, ignored, after_end, unresolved, ...).
    """
    out = {}
    for service, st in sorted(statuses.items()):
        tid = teacher_of(service)
        if tid is None or "presses_received" not in st.counters:
            continue
        counters = {k: int(v) for k, v in st.counters.items()}
        seqs = sorted(set(feedback.get(tid, [])))
        dropped = {k[len(DROPPED_PREFIX) :]: v for k, v in counters.items() if k.startswith(DROPPED_PREFIX) and v}
        published = counters.get("feedback_published", 0)
        if published > len(seqs):
            dropped["not_logged"] = published - len(seqs)
        credited = 0
        for q in seqs:
            status = outcome.get((tid, q), "unresolved")
            if status == "credited":
                credited += 1
            else:
                dropped[status] = dropped.get(status, 0) + 1
        out[tid] = {
            "received": counters["presses_received"],
            "published": published,
            "resent": counters.get("presses_resent", 0),
            "logged": len(seqs),
            "credited": credited,
            "dropped": dict(sorted(dropped.items())),
        }
    return out
