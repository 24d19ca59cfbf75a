"""The learner's history in seconds (`LearnerSettings.history_s`): a late press is credited while the steps its person
saw were shown less than `history_s` ago, whatever the actor's rate; at most `history_max_steps` are held; a
checkpoint taken with another history size still loads."""

from __future__ import annotations

import numpy as np

from common.agents.memory import BatchStepHistory
from common.protocol import Feedback, ShownStep
from services.learner import checkpoint
from services.learner.core import LearnerCore
from tests.services.test_cores import RUN, config, make_steps


def press(seq: int, first: int, period: float) -> Feedback:
    """A person's press on the 4 steps from `first` (shown at their action times), a second after the last."""
    shown = [ShownStep(k, 100.0 + k * period) for k in range(first, first + 4)]
    return Feedback(
        run=RUN,
        teacher_id="web-1",
        seq=seq,
        t_reaction=shown[-1].t + 1.0,
        value=1,
        source="key",
        actor="actor-1",
        shown=shown,
    )


def late_press(core: LearnerCore, steps: int, period: float) -> str:
    """Steps at `period` s, then a press on steps 100-103 arriving after all of them: its status."""
    for s in make_steps(steps, [100.0 + k * period for k in range(steps)]):
        core.on_step(s)
    [out] = core.on_feedback(press(0, 100, period))
    return out.status


def test_a_late_press_is_credited_while_its_steps_are_younger_than_history_s_whatever_the_rate():
    # 100 steps/s: the press comes 900 steps (9 s) after its steps; a history of 32 steps (history_s 0, the
    # agent's count) has lost them, one of 60 s holds them.
    assert late_press(LearnerCore(config()), 1000, 0.01) == "credited"
    counted = LearnerCore(config(history_s=0))
    assert late_press(counted, 1000, 0.01) == "too_old" and counted.counters["feedback_too_old"] == 1
    assert int(counted.agent.history.count[0]) == 32
    # 1 step/s: 30 steps (30 s) later, held; 70 s later, too old and counted by its reason.
    assert late_press(LearnerCore(config()), 134, 1.0) == "credited"
    old = LearnerCore(config())
    assert late_press(old, 174, 1.0) == "too_old" and old.counters["feedback_too_old"] == 1
    assert int(old.agent.history.count[0]) == 61  # the steps shown in the last 60 s, the newest's included
    shorter = LearnerCore(config(history_s=5.0))
    assert late_press(shorter, 1000, 0.01) == "too_old" and shorter.counters["feedback_too_old"] == 1


def test_the_history_is_bounded_by_history_max_steps():
    core = LearnerCore(config(history_max_steps=500))
    assert late_press(core, 1000, 0.01) == "too_old" and core.counters["feedback_too_old"] == 1
    assert core.agent.history.capacity == 500 and int(core.agent.history.count[0]) == 500
    assert len(core.screen.index) == 500


def test_a_checkpoint_of_a_history_in_steps_loads_into_one_in_seconds_and_back(tmp_path):
    """A checkpoint written with the old fixed history (32 steps) restores into a learner holding 60 s: its held
    steps come along and a press on them is credited; a bigger history into a smaller one keeps its newest."""
    steps = make_steps(60, [100.0 + k for k in range(60)])
    old = LearnerCore(config(history_s=0))
    for s in steps[:40]:
        old.on_step(s)
    old.take_entries()
    checkpoint.save(tmp_path / "old.ckpt", *old.snapshot())
    loaded = checkpoint.load(tmp_path / "old.ckpt")
    assert loaded is not None
    new = LearnerCore(config())
    new.restore(*loaded)
    _, times = new.agent.history.held(np.array([0]))
    assert times[0][np.isfinite(times[0])].tolist() == [float(k) for k in range(8, 40)]
    for s in steps[40:]:
        new.on_step(s)
    [out] = new.on_feedback(press(0, 10, 1.0))  # steps 10-13: held in the old ring, still held in the new one
    assert out.status == "credited" and {q for q, _ in out.credited} <= {10, 11, 12, 13} and out.credited
    new.take_entries()
    back = LearnerCore(config(history_s=0))
    back.restore(*new.snapshot())
    _, times = back.agent.history.held(np.array([0]))
    assert times[0].tolist() == [float(k) for k in range(28, 60)]


def test_a_ring_resized_on_load_keeps_each_trials_newest_steps_in_order():
    small = BatchStepHistory(2, 4, 1)
    for k in range(6):  # trial 0 wraps around (6 steps), trial 1 holds 2
        trials = np.array([0, 1]) if k < 2 else np.array([0])
        n = len(trials)
        small.push(trials, np.full(n, float(k)), np.full((n, 1), k), np.full(n, k), np.zeros(n, np.int64), np.zeros(n))
    big = BatchStepHistory(2, 8, 1)
    big.load_state_dict(small.state_dict())
    assert big.held(np.array([0, 1]))[1].tolist() == [[2, 3, 4, 5] + [np.inf] * 4, [0, 1] + [np.inf] * 6]
    assert big.obs[0, :4, 0].tolist() == [2, 3, 4, 5] and big.action[1, :2].tolist() == [0, 1]
    tiny = BatchStepHistory(2, 3, 1)
    tiny.load_state_dict(small.state_dict())
    assert tiny.held(np.array([0, 1]))[1].tolist() == [[3, 4, 5], [0, 1, np.inf]]
