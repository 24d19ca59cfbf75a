"""The learner's Credit messages: what became of each feedback (the steps it went to, their weights, the weights
revision that first held it), for the person's console and the log."""

from __future__ import annotations

import numpy as np

from common.protocol import Credit, CreditedStep, credit_key


def credit_message(run: str, result, actor: str | None, t_done: float, delay=None) -> Credit:
    """The `Credit` of one resolved feedback: the steps it was credited to, with their weights (and the teacher's
    delay estimate, `delay`, for a person's console)."""
    fb = result.feedback
    return Credit(
        run=run,
        teacher_id=fb.teacher_id,
        seq=fb.seq,
        value=fb.value,
        status=result.status,
        t_reaction=fb.t_reaction,
        t_credited=t_done,
        actor=fb.actor or actor,
        steps=[CreditedStep(int(q), min(1.0, float(w))) for q, w in heaviest(result.credited)],
        lost_mass=min(1.0, max(0.0, float(result.lost_mass))),
        delay=delay,
        revision=result.revision,
    )


# A Credit lists at most this many steps, so that it stays within its size limit (10 KB) with a delay estimate:
# a feedback credited in seconds over a long history (history_s) can spread over hundreds of steps.
MAX_LISTED_STEPS = 128


def heaviest(credited: list) -> list:
    """[(Step.seq, weight)]: the MAX_LISTED_STEPS of largest weight (ties: the newer), oldest first."""
    if len(credited) <= MAX_LISTED_STEPS:
        return list(credited)
    kept = sorted(credited, key=lambda qw: (-float(qw[1]), -int(qw[0])))[:MAX_LISTED_STEPS]
    return sorted(kept, key=lambda qw: int(qw[0]))


def listed_steps(seq_of: dict[int, int], times, weights) -> list[tuple[int, float]]:
    """[(Step.seq, weight)] of the credited steps (step-clock `times`, their `weights`) whose Step.seq the learner
    still knows (`seq_of`), as `heaviest` lists them: at 250 steps/s a feedback credited in seconds spreads over a
    thousand steps, and choosing in numpy first saves building and sorting a thousand pairs for each feedback."""
    index = np.asarray(times).astype(np.int64)
    w = np.asarray(weights, np.float64)
    kept = []
    for k in np.lexsort((-index, -w)).tolist():  # heaviest first, the newer on ties (Step.seq grows with the index)
        seq = seq_of.get(int(index[k]))
        if seq is not None:
            kept.append((seq, float(w[k])))
            if len(kept) == MAX_LISTED_STEPS:
                break
    return sorted(kept)


def publish_credit(session, pubs: dict, credit: Credit) -> None:
    """A Credit on its own key, `hitl/<run>/credit/<teacher_id>` (a publisher per teacher, made once)."""
    from common.wire.transport import MessagePublisher

    pub = pubs.get(credit.teacher_id)
    if pub is None:
        pub = pubs[credit.teacher_id] = MessagePublisher(session, credit_key(credit.run, credit.teacher_id))
    pub.put(credit)
