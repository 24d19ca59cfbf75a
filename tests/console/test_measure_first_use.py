"""`services.console.measure`'s press -> first action that used it, on hand-made messages: the first action after
the credit whose weights revision covers the press, for a person's Credits and for those riding in Ingest."""

from __future__ import annotations

from common.protocol import Credit, Ingest, Step
from services.console.measure import FirstUse

RUN = "m"


def step(seq: int, t: float, revision: int | None, actor: str = "actor-1") -> Step:
    return Step(
        run=RUN,
        incarnation=actor,
        seq=seq,
        t_action=t,
        episode=0,
        t_in_episode=seq,
        obs=[0.0],
        action=0,
        reward=0.0,
        next_obs=[0.0],
        terminated=False,
        truncated=False,
        weights_version=seq,
        info={},
        weights_revision=revision,
    )


def credit(seq: int, t_reaction: float, t_credited: float, revision: int | None, teacher: str = "web-1") -> Credit:
    return Credit(
        run=RUN,
        teacher_id=teacher,
        seq=seq,
        value=1,
        status="credited",
        t_reaction=t_reaction,
        t_credited=t_credited,
        actor="actor-1",
        steps=[],
        lost_mass=0.0,
        revision=revision,
    )


def test_the_first_action_after_the_credit_whose_revision_covers_it():
    used = FirstUse()
    # actions at 10, 11, 12, 13 s acting with revisions None, 2, 4, 9
    for k, rev in enumerate([None, 2, 4, 9]):
        used.add(step(k, 10.0 + k, rev))
    used.add(credit(0, 10.2, 10.3, 2))  # credited before action 1 (revision 2): the very next action
    used.add(credit(1, 11.1, 11.2, 5))  # the next action (12 s) had revision 4 < 5: action 3, one later
    used.add(credit(2, 12.5, 12.6, 10))  # no later action covers it
    used.add(credit(3, 12.5, 12.6, None))  # shaping: nothing updated at once, not counted
    used.add(
        Ingest(
            run=RUN,
            learner="learner-1",
            seq=0,
            index=0,
            entries=[],
            credits=[credit(0, 10.4, 10.5, 1, teacher="oracle")],
        )
    )  # a simulated teacher's, in Ingest
    figures = used.figures()
    assert figures["press_to_first_action_using_it_ms"]["n"] == 3
    assert sorted(round(s.t_action - c.t_reaction, 3) for c, s, _ in used.pairs) == [0.6, 0.8, 1.9]
    assert sorted(n for _, _, n in used.pairs) == [0, 0, 1]
    assert figures["credited_never_used"] == 1
    assert figures["actions_between_credit_and_first_use"]["max"] == 1.0
