"""What a session log says: counts, losses, what became of every feedback, per-episode returns.

Used by `python -m services.replay summary LOG` and by the launcher for `summary.json`.
"""

from __future__ import annotations

import collections
import os
import warnings
from dataclasses import dataclass, field
from typing import Any

from common.logs.mcap_log import LogRecoveryWarning, read_log
from services.replay.people import people_report
from common.protocol import (
    kind_of,
    teacher_id_of,
    EpisodeSummary,
    Feedback,
    Ingest,
    ObserverReaction,
    ServiceStatus,
    Step,
    Weights,
    WeightsSnapshot,
)
from services.replay.counts import status_counter, counts_sent_and_learned, effective_ingest, rejected_inputs


def _contiguous(seqs: list[int]) -> bool:
    return seqs == list(range(seqs[0], seqs[0] + len(seqs))) if seqs else True


@dataclass
class LogContents:
    """The messages of a session log that the summary reads, sorted by kind."""

    steps: dict[str, list[Step]] = field(default_factory=lambda: collections.defaultdict(list))  # by actor, in order
    feedback_msgs: list[Feedback] = field(default_factory=list)
    reactions: list[ObserverReaction] = field(default_factory=list)  # a face-video observer's diagnostics
    ingest: dict[str, list[Ingest]] = field(default_factory=lambda: collections.defaultdict(list))
    episodes: list[EpisodeSummary] = field(default_factory=list)
    statuses: dict[str, ServiceStatus] = field(default_factory=dict)  # the latest of each service
    by_pid: dict[tuple[str, int], ServiceStatus] = field(
        default_factory=dict
    )  # the latest of each process (restarts are new pids)
    weights: dict[str, list[int]] = field(default_factory=lambda: collections.defaultdict(list))
    kinds: collections.Counter = field(default_factory=collections.Counter)


def read_contents(reader) -> LogContents:
    """Sort every record of the reader by kind (the reader recovers a truncated log, warning as it goes)."""
    c = LogContents()
    for rec in reader:
        m = rec.message
        c.kinds[kind_of(rec.key) or rec.key] += 1
        if isinstance(m, Step):
            c.steps[m.incarnation].append(m)
        elif isinstance(m, Feedback):
            c.feedback_msgs.append(m)
        elif isinstance(m, ObserverReaction):
            c.reactions.append(m)
        elif isinstance(m, Ingest):
            c.ingest[m.learner].append(m)
        elif isinstance(m, EpisodeSummary):
            c.episodes.append(m)
        elif isinstance(m, ServiceStatus):
            c.statuses[m.service] = m
            c.by_pid[(m.service, m.pid)] = m
        elif isinstance(m, (Weights, WeightsSnapshot)):  # logs since the snapshots: snapshots only
            c.weights[m.incarnation].append(m.version)
    return c


def drop_not_from_run(c: LogContents) -> collections.Counter:
    """Leave out valid messages from nobody in the run; returns their count by kind (`log.not_from_run`).

    Forged or garbage messages: the recorder keeps whatever decodes. Left out are steps of actor
    incarnations no actor status announced, weights of learner incarnations no learner status announced, and
    feedback of teachers without a status or with a seq beyond the teacher's final count by more than the
    learner's gate admits (`MAX_FEEDBACK_JUMP`: a forged jump, refused there as `bad_seq`).
    """
    from services.common.gate import MAX_FEEDBACK_JUMP

    actor_incs = {st.incarnation for (svc, _), st in c.by_pid.items() if svc == "actor" and st.incarnation}
    not_from_run = collections.Counter()
    if actor_incs:
        for inc in [i for i in c.steps if i not in actor_incs]:
            not_from_run["step"] += len(c.steps.pop(inc))
    learner_incs = {st.incarnation for (svc, _), st in c.by_pid.items() if svc == "learner" and st.incarnation}
    if learner_incs:
        for inc in [i for i in c.weights if i not in learner_incs]:
            not_from_run["weights"] += len(c.weights.pop(inc))
    teacher_count: dict[str, int] = {}
    for (svc, _), st in c.by_pid.items():
        if teacher_id_of(svc):
            tid = teacher_id_of(svc)
            teacher_count[tid] = max(teacher_count.get(tid, 0), int(st.counters.get("feedback_published", 0)))
    kept = []
    for m in c.feedback_msgs:
        if teacher_count and (
            m.teacher_id not in teacher_count or m.seq > teacher_count[m.teacher_id] + MAX_FEEDBACK_JUMP
        ):
            not_from_run["feedback"] += 1
            continue
        kept.append(m)
    c.feedback_msgs = kept
    return not_from_run


def episode_rows(steps: dict[str, list[Step]], episodes: list[EpisodeSummary]) -> list[dict[str, Any]]:
    """One row per (actor incarnation, episode) from the actor's own steps, with the learner's episode summary.

    `steps` must be in seq order per incarnation.
    """
    ep_rows = []
    for inc, ss in steps.items():
        by_ep: dict[int, list[Step]] = collections.defaultdict(list)
        for s in ss:
            by_ep[s.episode].append(s)
        for ep, items in sorted(by_ep.items()):
            finished = items[-1].terminated or items[-1].truncated
            ep_rows.append(
                {
                    "actor": inc,
                    "episode": ep,
                    "return": float(sum(s.reward for s in items)),
                    "steps": len(items),
                    "finished": bool(finished),
                    "reached_goal": bool(items[-1].terminated),
                }
            )
    last_actor = list(steps)[-1] if steps else None
    for row in ep_rows:  # the episode a killed actor was in: closed by the learner, not a result
        row["aborted"] = not row["finished"] and row["actor"] != last_actor
        # the last actor's episode cut by Ctrl-C or --max-steps: marked, and not a return either
        row["unfinished"] = not row["finished"] and row["actor"] == last_actor
    learner_eps = {(e.incarnation, e.episode): e for e in episodes}
    for row in ep_rows:
        e = learner_eps.get((row["actor"], row["episode"]))
        if e is not None:
            row.update(
                feedback_received=e.feedback_received,
                feedback_credited=e.feedback_credited,
                weights_version=e.weights_version,
            )
    return ep_rows


@dataclass
class LearnerRecord:
    """What the learner's record of consumed inputs says (across restored learners)."""

    learners: dict[str, dict[str, Any]]  # per learner incarnation: its Ingest batches
    outcome: dict[tuple[str, int], str]  # (teacher, feedback seq) -> what became of it
    step_entries: collections.Counter  # step entries by status
    learned: dict[str, list[int]]  # actor incarnation -> seqs learned, in order
    consumed_feedback: set[tuple[str, int]]
    chain: list[str]
    gaps: int


def learner_record(ingest: dict[str, list[Ingest]]) -> LearnerRecord:
    """The outcome entries, steps learned and feedback consumed of the learner's record (sorts `ingest`)."""
    learners = {}
    for inc, batches in ingest.items():
        batches.sort(key=lambda b: b.seq)
        entries = [e for b in batches for e in b.entries]
        first = batches[0]
        learners[inc] = {
            "batches": len(batches),
            "batch_seq_contiguous": _contiguous([b.seq for b in batches]),
            "entries": len(entries),
            "ended": any(e.kind == "end" for e in entries),
            "first_index": first.index,
            "resumed_from": (first.config or {}).get("resumed_from") if first.seq == 0 else None,
        }
    record, chain, record_gaps = effective_ingest(ingest)
    out = LearnerRecord(learners, {}, collections.Counter(), collections.defaultdict(list), set(), chain, record_gaps)
    for e in record:
        if e.kind == "outcome":
            out.outcome[(e.source, e.seq)] = e.status
        elif e.kind == "step":
            out.step_entries[e.status] += 1
            if e.status in ("learned", "gap"):
                out.learned[e.source].append(e.seq)
        elif e.kind == "feedback":
            out.consumed_feedback.add((e.source, e.seq))
    return out


def actor_steps_sent(
    by_pid: dict[tuple[str, int], ServiceStatus], step_seqs: dict[str, list[int]]
) -> tuple[int, list[str | None]]:
    """Steps sent: each actor process's own count (a killed one's last status may be old: the log tells more).

    Returns the sum and the incarnations of the actors that did not report `stopped` (killed).
    """
    actor_sent, killed_actors = 0, []
    for (service, _pid), st in by_pid.items():
        if service != "actor":
            continue
        n = int(st.counters.get("steps_published", 0))
        if st.state != "stopped":
            killed_actors.append(st.incarnation)
            n = max(n, len(step_seqs.get(st.incarnation or "", [])))
        actor_sent += n
    return actor_sent, killed_actors


def logged_feedback(msgs: list[Feedback]) -> tuple[dict[str, list[int]], int]:
    """teacher -> its logged seqs, each once; and how many were logged again (a console page's re-sent press)."""
    feedback: dict[str, list[int]] = collections.defaultdict(list)
    seen: set[tuple[str, int]] = set()
    for m in msgs:
        if (m.teacher_id, m.seq) not in seen:
            seen.add((m.teacher_id, m.seq))
            feedback[m.teacher_id].append(m.seq)
    return feedback, len(msgs) - len(seen)


def log_section(path, status, c: LogContents, caught: list, not_from_run: collections.Counter) -> dict[str, Any]:
    """The summary's "log" part: the file(s), what was recovered or lost, the kinds, warnings, outsiders."""
    return {
        "path": str(path),
        "messages": status.messages,
        "complete": status.complete,
        "truncated_files": status.truncated,
        "recovery": status.summary(),
        "lost": status.losses(),
        "by_kind": dict(c.kinds),
        "warnings": [str(w.message) for w in caught],
        "not_from_run": dict(not_from_run),
    }


def summarize(path: str | os.PathLike) -> dict[str, Any]:
    """Read the log (also a truncated one: recovered up to its last complete chunk, with a warning)."""
    reader = read_log(path)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", LogRecoveryWarning)
        c = read_contents(reader)
    for w in caught:
        warnings.warn(w.message, w.category, stacklevel=2)
    status = reader.status
    not_from_run = drop_not_from_run(c)
    feedback, republished = logged_feedback(c.feedback_msgs)
    feedback_values = collections.Counter(m.value for m in c.feedback_msgs)

    # Steps: contiguous per incarnation (all seqs once; after a recorder restart the re-sent ones come later in
    # the log than newer live ones, so in seq order); episode returns from the actor's own steps.
    for ss in c.steps.values():
        ss.sort(key=lambda s: s.seq)
    step_seqs = {inc: [s.seq for s in ss] for inc, ss in c.steps.items()}
    ep_rows = episode_rows(c.steps, c.episodes)

    # What became of each feedback: the outcome entries of the learner's record (across restored learners).
    lr = learner_record(c.ingest)
    logged_fb = [(t, s) for t, seqs in feedback.items() for s in seqs]
    by_status = collections.Counter(lr.outcome.get(k, "unresolved") for k in logged_fb)
    rejected = {k: v for k, v in sorted(by_status.items()) if k != "credited"}
    learned_keys = {(inc, q) for inc, seqs in lr.learned.items() for q in seqs}
    steps_not_ingested = sum(1 for inc, seqs in step_seqs.items() for q in seqs if (inc, q) not in learned_keys)

    def counter(service: str, name: str) -> int | None:
        return status_counter(c, service, name)

    actor_sent, killed_actors = actor_steps_sent(c.by_pid, step_seqs)
    sent, steps_learned, stale = counts_sent_and_learned(c, lr, feedback)
    out = {
        "run": reader.run_config.run if reader.run_config else None,
        "log": log_section(path, status, c, caught, not_from_run),
        "steps_sent": actor_sent if any(k[0] == "actor" for k in c.by_pid) else None,
        "actor_incarnations_killed": killed_actors,
        "steps_logged": sum(len(v) for v in step_seqs.values()),
        "steps_seq_contiguous_in_log": all(_contiguous(v) for v in step_seqs.values()),
        "actor_incarnations": len(step_seqs),
        "steps_learned": steps_learned,
        "steps_lost_at_learner": counter("learner", "steps_lost"),
        "learner_step_entries": dict(lr.step_entries),
        "learner_chain": lr.chain,
        "learner_record_gaps": lr.gaps,
        "learner_seq_contiguous": all(_contiguous(v) for v in lr.learned.values()),
        "steps_not_ingested": steps_not_ingested,
        "feedback_not_ingested": sum(1 for k in logged_fb if k not in lr.consumed_feedback),
        "rejected_inputs": rejected_inputs(c.by_pid),
        "duplicates_dropped": rejected_inputs(c.by_pid, prefixes=("duplicates_",)),
        # dropped before anything else by the authentication check (common/wire/auth.py): reason_kind -> count
        "unauthenticated_inputs": rejected_inputs(c.by_pid, prefixes=("auth_",)),
        "feedback_sent": sum(x for x in sent if x is not None) if sent else None,
        "feedback_logged": len(logged_fb),
        "feedback_seq_contiguous_in_log": all(_contiguous(sorted(v)) for v in feedback.values()),
        "feedback_positive": feedback_values.get(1, 0),
        "feedback_negative": feedback_values.get(-1, 0),
        "feedback_credited": by_status.get("credited", 0),
        "feedback_rejected": rejected,
        "feedback_republished": republished,
        "people": people_report(c.statuses, feedback, lr.outcome, teacher_id_of),
        "weights_logged": sum(len(v) for v in c.weights.values()),  # snapshots (Weights in older logs)
        "learners": lr.learners,
        "episodes": ep_rows,
        "returns": [r["return"] for r in ep_rows if r["finished"]],
        "unfinished_episodes": [
            {"actor": r["actor"], "episode": r["episode"], "steps": r["steps"]} for r in ep_rows if r["unfinished"]
        ],
        "services": {
            name: {"state": st.state, "counters": dict(st.counters)} for name, st in sorted(c.statuses.items())
        },
        "services_not_stopped": stale,  # their counters are from an earlier status (see steps_learned)
    }
    if c.reactions:  # face-video: what the perception path did to the observer's reactions
        from services.teacher.face_metrics import face_metrics

        out["face"] = face_metrics(c.reactions, c.feedback_msgs)
    return out


def format_summary(s: dict[str, Any]) -> str:
    lost = s["log"].get("lost", [])
    state = "DATA LOST" if lost else "complete" if s["log"]["complete"] else "all data read, file summary missing"
    lines = [f"run {s['run']}: {s['log']['messages']} messages read ({state})"]
    lines += [f"  lost: {line}" for line in lost]
    lines.append(
        f"  steps: sent {s['steps_sent']}, logged {s['steps_logged']} "
        f"(contiguous: {s['steps_seq_contiguous_in_log']}), learned {s['steps_learned']}"
    )
    lines.append(
        f"  feedback: sent {s['feedback_sent']}, logged {s['feedback_logged']}, "
        f"credited {s['feedback_credited']}, rejected {s['feedback_rejected'] or {}}"
    )
    rets = s["returns"]
    if rets:
        k = min(5, len(rets))
        lines.append(
            f"  episodes: {len(rets)}; mean return first {k}: {sum(rets[:k]) / k:.3f}, "
            f"last {k}: {sum(rets[-k:]) / k:.3f}"
        )
    lines.append(f"  weights snapshots logged: {s['weights_logged']}")
    if s.get("steps_not_ingested") or s.get("feedback_not_ingested") or len(s.get("learner_chain", [])) > 1:
        lines.append(
            f"  learner record across {len(s['learner_chain'])} learner process(es): steps not ingested "
            f"{s['steps_not_ingested']}, feedback not ingested {s['feedback_not_ingested']}, seqs contiguous "
            f"{s['learner_seq_contiguous']}"
        )
    for r in s.get("restarts") or []:
        back = "not back" if r.get("recovered_s") is None else f"back after {r['recovered_s']:.2f} s"
        lines.append(f"  restart: {r['service']} died ({r['how']}), {back}")
    if s.get("rejected_inputs"):
        lines.append(f"  rejected inputs: {s['rejected_inputs']}")
    for tid, f in (s.get("face") or {}).items():
        rate = f["polarity_error_rate"]
        lag = (f["lag_s"] or {}).get("p50")
        lines.append(
            f"  face {tid}: {f['reactions_shown']} reactions shown, {f['reactions_read']} read "
            f"(missed {f['missed']}, extra {f['extra']}), polarity error rate "
            f"{'n/a' if rate is None else f'{100 * rate:.1f}%'}, lag p50 "
            f"{'n/a' if lag is None else f'{lag:.2f} s'}"
        )
    return "\n".join(lines)
