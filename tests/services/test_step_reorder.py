"""A restored learner hears live steps before the actor's re-sent ones: the ahead steps wait (StepReorder) so the
re-sent ones fill the hole instead of being dropped as old behind a gap. Real gate, real learner core."""

from __future__ import annotations

import time

from common.core.task import Task
from services.common.config import LearnerConfig
from services.common.gate import InputGate
from services.learner.catchup import StepReorder
from services.learner.core import LearnerCore

from .test_cores import make_steps


def _learner(wait_s: float):
    core = LearnerCore(LearnerConfig(run="t", task=Task(env="maze")))
    gate = InputGate(core.obs_dim, core.n_actions)
    gate.announce("actor-1")
    return core, gate, StepReorder(wait_s, 64)


def _consume(core, gate, reorder, step, t_recv):
    """What `Learner.consume_step` does with a live step: wait if ahead, else admit it and those that follow."""
    if reorder.waits(step, t_recv, gate):
        return
    if gate.admit_step(step, t_recv) is None:
        core.on_step(step)
    for s, t in reorder.following(gate):
        assert gate.admit_step(s, t) is None
        core.on_step(s)


def _statuses(core):
    return [(e.seq, e.status) for e in core.take_entries()]


def test_live_steps_ahead_wait_for_the_resent_ones_and_all_are_learned_in_order():
    steps = make_steps(20, [100.0 + 0.1 * k for k in range(20)])
    core, gate, reorder = _learner(wait_s=60.0)
    arrival = steps[:8] + steps[12:16] + steps[8:12] + steps[8:10] + steps[16:]  # live overtakes re-sent; dupes
    for s in arrival:
        _consume(core, gate, reorder, s, 101.0)
    assert _statuses(core) == [(k, "learned") for k in range(20)]
    assert not reorder.held and reorder.due_in() == float("inf")
    assert gate.counters["duplicate"] == 2 and core.counters["steps_lost"] == 0


def test_a_hole_that_never_fills_is_a_gap_once_the_wait_is_over():
    steps = make_steps(10, [100.0 + 0.1 * k for k in range(10)])
    core, gate, reorder = _learner(wait_s=0.05)
    for s in steps[:3] + steps[5:]:
        _consume(core, gate, reorder, s, 101.0)
    assert [k for k, _ in _statuses(core)] == [0, 1, 2] and len(reorder.held) == 5
    assert 0 < reorder.due_in() <= 0.05
    time.sleep(0.06)
    assert reorder.due_in() == 0.0
    for s, t in reorder.take_all():
        assert gate.admit_step(s, t) is None
        core.on_step(s)
    assert _statuses(core) == [(5, "gap")] + [(k, "learned") for k in range(6, 10)]
    assert core.counters["steps_lost"] == 2
    late = steps[3]  # the lost one, re-sent after the gap: old now
    assert not reorder.waits(late, 101.0, gate) and gate.admit_step(late, 101.0) == "duplicate"


def test_only_the_current_actors_admissible_steps_wait():
    steps = make_steps(6, [100.0 + 0.1 * k for k in range(6)])
    core, gate, reorder = _learner(wait_s=60.0)
    assert not reorder.waits(steps[3], 101.0, gate)  # no actor yet: the first step is taken as it comes
    _consume(core, gate, reorder, steps[0], 101.0)
    other = make_steps(6, [100.0 + 0.1 * k for k in range(6)], incarnation="actor-2")
    assert not reorder.waits(other[4], 101.0, gate)  # another incarnation: the gate decides (a restart)
    assert not reorder.waits(steps[5], 101.0 + 10_000, gate)  # stamped far in the past: rejected, not held
    assert reorder.waits(steps[5], 101.0, gate) and reorder.waits(steps[5], 101.0, gate) and len(reorder.held) == 1
    full = StepReorder(60.0, 1)
    assert full.waits(steps[5], 101.0, gate) and full.due_in() == 0.0  # as many as it may hold: due at once
