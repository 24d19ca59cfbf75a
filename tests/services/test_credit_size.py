"""A Credit stays within its size limit however many steps a feedback spread over, and one that cannot stand
alone is counted and dropped by the log, never a crash (a recorder once died on one: 10,333 bytes > 10,240)."""

from __future__ import annotations

import collections

from common.logs.scene import derived_records
from common.protocol import Credit, CreditedStep, Feedback, Ingest
from services.learner.core import FeedbackResult
from services.learner.books import MAX_LISTED_STEPS, credit_message

RUN = "t"


def spread_result(n: int) -> FeedbackResult:
    """A feedback credited in seconds over `n` held steps, with weights that have long decimal expansions."""
    feedback = Feedback(run=RUN, teacher_id="oracle", seq=0, t_reaction=50.0, value=1, source="oracle")
    weights = [(k % 7 + 1) / (7.0 * n) + 1e-9 * k for k in range(n)]
    result = FeedbackResult("oracle", 0, "credited", n, 0.0, 0, feedback=feedback)
    result.credited = list(zip(range(100, 100 + n), weights, strict=True))
    return result


def test_a_credit_over_hundreds_of_steps_lists_the_heaviest_oldest_first_and_encodes():
    result = spread_result(400)
    credit = credit_message(RUN, result, "actor-1", 51.0)
    assert len(credit.steps) == MAX_LISTED_STEPS
    seqs = [s.seq for s in credit.steps]
    assert seqs == sorted(seqs)
    smallest_kept = min(s.weight for s in credit.steps)
    assert all(w <= smallest_kept for q, w in result.credited if q not in set(seqs))
    assert len(credit.encode()) <= Credit.MAX_BYTES
    few = credit_message(RUN, spread_result(10), "actor-1", 51.0)
    assert [s.seq for s in few.steps] == list(range(100, 110))


def test_a_carried_credit_too_big_to_stand_alone_is_counted_and_dropped():
    big = Credit(
        run=RUN,
        teacher_id="oracle",
        seq=0,
        value=1,
        status="credited",
        t_reaction=1.0,
        t_credited=2.0,
        actor="actor-1",
        steps=[CreditedStep(100_000 + k, 1 / 3) for k in range(256)],
        lost_mass=0.0,
    )
    small = Credit(
        run=RUN,
        teacher_id="oracle",
        seq=1,
        value=1,
        status="credited",
        t_reaction=1.5,
        t_credited=2.0,
        actor="actor-1",
        steps=[CreditedStep(3, 1.0)],
        lost_mass=0.0,
    )
    ingest = Ingest(run=RUN, learner="learner-1", seq=0, index=0, entries=[], credits=[big, small])
    dropped: collections.Counter[str] = collections.Counter()
    out = derived_records(RUN, ingest, None, dropped)
    assert [key for key, _ in out] == [f"hitl/{RUN}/credit/oracle"]
    alone = Credit.decode(out[0][1])
    assert isinstance(alone, Credit) and alone.seq == 1
    assert dropped == {"derived_dropped_oversized": 1}


def test_the_listed_steps_are_heaviest_of_the_known_ones_chosen_in_numpy():
    """`listed_steps` (numpy, for a feedback over a thousand steps) lists what `heaviest` lists from all the pairs:
    ties of equal weights (a uniform delay's) resolved to the newer, steps the learner no longer knows left out."""
    import numpy as np

    from services.learner.books import heaviest, listed_steps

    rng = np.random.default_rng(3)
    for n in (0, 5, 128, 129, 1500):
        index = np.arange(1000, 1000 + n)
        weights = rng.choice([0.25, 0.5, 0.125, 1e-3], size=n) * rng.choice([1.0, 1.0 + 1e-12], size=n)
        seq_of = {int(i): int(i) + 7 for i in index if i % 11}  # some steps forgotten
        everything = [(seq_of[int(i)], float(w)) for i, w in zip(index, weights) if int(i) in seq_of]
        assert listed_steps(seq_of, index.astype(np.float64), weights) == heaviest(everything)


def test_waiting_credits_go_out_in_ingests_that_list_about_the_budget_oldest_first():
    """An Ingest carries Credits until they list INGEST_LISTED_STEPS (at least one, at most MAX_INGEST_CREDITS):
    encoding one Ingest of thirteen 128-step Credits stalled the learner's loop for 10-18 ms at 250 steps/s."""
    from common.protocol import MAX_INGEST_CREDITS
    from services.learner.books import INGEST_LISTED_STEPS, take_credits

    def credit(seq: int, listed: int) -> Credit:
        return Credit(
            run=RUN,
            teacher_id="oracle",
            seq=seq,
            value=1,
            status="credited" if listed else "stale",
            t_reaction=1.0,
            t_credited=2.0,
            actor="actor-1",
            steps=[CreditedStep(1000 + k, 1 / max(listed, 1)) for k in range(listed)],
            lost_mass=0.0,
        )

    assert INGEST_LISTED_STEPS == 256
    pending = [credit(seq, listed) for seq, listed in enumerate([128, 100, 128, 5, 0, 0, 200, 128, 7])]
    taken, listed = take_credits(pending)
    assert [c.seq for c in taken] == [0, 1, 2] and listed == 356
    taken, listed = take_credits(pending)
    assert [c.seq for c in taken] == [3, 4, 5, 6, 7] and listed == 333  # 5 + 0 + 0 + 200 < 256: one more
    assert [c.seq for c in pending] == [8]
    assert take_credits([credit(0, 400)])[1] == 400  # one Credit over the budget still goes
    many = [credit(seq, 0) for seq in range(MAX_INGEST_CREDITS + 3)]
    taken, listed = take_credits(many)
    assert len(taken) == MAX_INGEST_CREDITS and listed == 0 and len(many) == 3
    assert take_credits([]) == ([], 0)
